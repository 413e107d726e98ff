//! The model commands end to end, on the example inputs and on broken inputs.

// Parallel arrays indexed together read more plainly with an index.
#![allow(clippy::needless_range_loop)]

use std::path::PathBuf;
use std::process::Command;

fn ex(name: &str) -> String {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../examples/models")
        .join(name)
        .to_string_lossy()
        .into_owned()
}

fn run(args: &[&str]) -> (bool, String, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_metrolog"))
        .args(args)
        .output()
        .expect("run metrolog");
    (
        o.status.success(),
        String::from_utf8_lossy(&o.stdout).into(),
        String::from_utf8_lossy(&o.stderr).into(),
    )
}

#[test]
fn parts_json_reports_the_reject_rates() {
    let (b, a) = (ex("parts_before.csv"), ex("parts_after.csv"));
    let (ok, out, err) = run(&["parts", &b, &a, "--tolerance", "-12,12", "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    // The example is built like paper 004: 10.6 % predicted reject before, about 0.5 % after.
    let before = v["before"]["predicted_reject_pct"].as_f64().unwrap();
    let after = v["after"]["predicted_reject_pct"].as_f64().unwrap();
    assert!((before - 10.6).abs() < 0.1, "{before}");
    assert!((after - 0.52).abs() < 0.05, "{after}");
    assert_eq!(v["significant"], true);
    let (ok, _, err) = run(&["parts", &b, &a, "--tolerance", "12"]);
    assert!(!ok && err.contains("LO,HI"), "{err}");
}

#[test]
fn volumetric_writes_tables() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("c.csv");
    let ini = dir.path().join("c.ini");
    let (m, e) = (ex("machine_3axis.toml"), ex("component_errors.csv"));
    let (ok, out, err) = run(&[
        "volumetric",
        "--machine",
        &m,
        "--errors",
        &e,
        "--grid",
        "0:500:6,0:400:5,0:300:4",
        "--out",
        csv.to_str().unwrap(),
        "--siemens",
        ini.to_str().unwrap(),
        "--json",
    ]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["summary"]["n_points"], 120);
    assert_eq!(std::fs::read_to_string(&csv).unwrap().lines().count(), 121);
    assert!(
        std::fs::read_to_string(&ini)
            .unwrap()
            .contains("$AN_CEC_OUTPUT_AXIS[8]=(AX3)")
    );
    let (ok, _, err) = run(&[
        "volumetric",
        "--machine",
        &m,
        "--errors",
        &e,
        "--grid",
        "0:500",
    ]);
    assert!(!ok && err.contains("min:max:count"), "{err}");
}

#[test]
fn identify_capball_recovers_the_example_truth() {
    let (ok, out, err) = run(&[
        "identify",
        "capball",
        &ex("capball_identification.csv"),
        "--validate",
        &ex("capball_validation.csv"),
        "--json",
    ]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(ex("capball_truth.json")).unwrap()).unwrap();
    let id = &v["runs"][0]["identification"];
    let p = id["params"].as_array().unwrap();
    let u = id["std_uncertainty"].as_array().unwrap();
    let t = [
        &truth["link"]["ec0y_urad"],
        &truth["link"]["eb0z_urad"],
        &truth["link"]["ea0z_urad"],
        &truth["link"]["eb0a_urad"],
        &truth["link"]["ec0a_urad"],
        &truth["link"]["ea0c_urad"],
        &truth["link"]["eb0c_urad"],
        &truth["link"]["ey0c_um"],
        &truth["setup"]["ball_x_um"],
        &truth["setup"]["ball_y_um"],
        &truth["setup"]["ball_z_um"],
        &truth["setup"]["tool_x_um"],
        &truth["setup"]["tool_y_um"],
        &truth["setup"]["tool_z_um"],
    ];
    for k in 0..14 {
        let z = (p[k].as_f64().unwrap() - t[k].as_f64().unwrap()) / u[k].as_f64().unwrap();
        assert!(z.abs() < 4.0, "parameter {k}: z = {z}");
    }
    let val = v["runs"][0]["validation_rms_um"].as_array().unwrap();
    assert!(val.iter().all(|x| (x.as_f64().unwrap() - 0.4).abs() < 0.05));
}

#[test]
fn identify_errors_are_clear() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("few.csv");
    let fs = f.to_str().unwrap();
    std::fs::write(&f, "run,pose,time_s,x_mm,y_mm,z_mm,a_deg,c_deg,ex_um,ey_um,ez_um\n1,1,0,120,80,100,0,0,1,2,3\n").unwrap();
    let (ok, _, err) = run(&["identify", "capball", fs]);
    assert!(!ok && err.contains("measure more poses"), "{err}");
    std::fs::write(
        &f,
        "run,pose,x_mm,y_mm,z_mm,a_deg,c_deg,ex_mm,ey_mm,ez_mm\n1,1,120,80,100,0,0,1,2,3\n",
    )
    .unwrap();
    let (ok, _, err) = run(&["identify", "capball", fs]);
    assert!(!ok && err.contains("µm"), "{err}");
    let (ok, _, err) = run(&["identify", "capball", "/nonexistent/x.mcap"]);
    assert!(!ok && err.contains("CSV"), "{err}");
    let (ok, _, err) = run(&[
        "identify",
        "psd",
        &ex("psd_readings.csv"),
        "--reference",
        "9",
    ]);
    assert!(!ok && err.contains("reference run 9"), "{err}");
}

#[test]
fn identify_psd_trajectory_and_sensor_frame() {
    let (ok, out, err) = run(&[
        "identify",
        "psd",
        &ex("psd_readings.csv"),
        "--reference",
        "0",
        "--json",
    ]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    // The example's warm run tilts Z by EB0Z = 6 µrad; with 0.15 µm reading noise,
    // u(EB0Z) ≈ 1.7 µrad.
    let eb0z = v["runs"][0]["errors"]["eb0z_urad"].as_f64().unwrap();
    assert!((eb0z - 6.0).abs() < 7.0, "{eb0z}");
    let dir = tempfile::tempdir().unwrap();
    let t = dir.path().join("t.csv");
    let (ok, out, err) = run(&[
        "identify",
        "trajectory",
        "--out",
        t.to_str().unwrap(),
        "--poses",
        "200",
    ]);
    assert!(ok, "{err}");
    assert!(out.contains("condition number"));
    assert_eq!(std::fs::read_to_string(&t).unwrap().lines().count(), 201);
    let (ok, out, err) = run(&[
        "identify",
        "sensor-frame",
        &ex("capball_cube.csv"),
        "--json",
    ]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert!((v["gains"][0].as_f64().unwrap() - 1.006).abs() < 0.001);
}
