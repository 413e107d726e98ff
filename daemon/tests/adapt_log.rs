//! The MCAP adapters of `analysis` on synthetic logs written with the log writer: a run shaped
//! like the demo (ISO 230-2 on X with reversal poses, CapBall poses, a PSD segment along Z),
//! with values worked out here from known deviations and known machine errors.

mod cli_common;
use cli_common::outcome as metrolog;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use drivers::Instrument;
use geometry::capball::{CapballErrors, CapballSetup, TrajectorySpec};
use geometry::kinematics::Pose;
use metrolog_analysis::{self as analysis, PositioningOptions};
use metrolog_log::topics::{EnvironmentMsg, PoseMsg};
use metrolog_log::{LogOptions, LogWriter, RunMetadata};
use positioning::axis_model::Direction;
use types::PoseStatus;

const T0_NS: u64 = 1_795_305_600_000_000_000;
const TARGETS_MM: [f64; 5] = [2.312, 101.871, 198.544, 302.197, 399.050];
const SYS_UP_UM: [f64; 5] = [0.8, 2.1, 3.0, 2.2, 4.1];
const SYS_DOWN_UM: [f64; 5] = [-0.6, 0.9, 1.6, 0.7, 2.5];
/// Known link/setup errors of the CapBall part (order of `PARAM_NAMES`).
const CAPBALL_P: [f64; 14] = [
    12.0, -8.0, 5.0, 20.0, -15.0, 10.0, -6.0, 7.0, 3.0, -2.0, 1.5, -4.0, 2.5, 1.0,
];

/// Deviation of a visit, µm: systematic + a drift with the cycle + a deterministic wobble.
fn dev_um(i: usize, dir: Direction, cycle: usize) -> f64 {
    let w = 0.05 * ((i * 7 + cycle * 3) as f64 * 1.7).sin();
    match dir {
        Direction::Up => SYS_UP_UM[i] + 0.1 * cycle as f64 + w,
        Direction::Down => SYS_DOWN_UM[i] - 0.1 * cycle as f64 + w,
    }
}

/// One programmed pose and what the ISO part knows about it.
struct Row {
    p: Pose,
    /// (target index 0-based, direction, cycle) of an ISO visit; None for reversals and others.
    iso: Option<(usize, Direction, usize)>,
}

fn pose(x: f64, y: f64, z: f64, a: f64, c: f64) -> Pose {
    Pose {
        x_mm: x,
        y_mm: y,
        z_mm: z,
        a_deg: a,
        b_deg: 0.0,
        c_deg: c,
    }
}

/// The demo's layout: poses 1-36 ISO (3 cycles, reversals at 404.05 and -2.688), 40 CapBall
/// poses, then 9 PSD poses along Z.
// The target index `i` is data of the row (the ISO target number), not only an index.
#[allow(clippy::needless_range_loop)]
fn rows(setup: &CapballSetup) -> Vec<Row> {
    let mut v = Vec::new();
    for cycle in 1..=3 {
        for i in 0..5 {
            v.push(Row {
                p: pose(TARGETS_MM[i], 0.0, 0.0, 0.0, 0.0),
                iso: Some((i, Direction::Up, cycle)),
            });
        }
        v.push(Row {
            p: pose(404.05, 0.0, 0.0, 0.0, 0.0),
            iso: None,
        });
        for i in (0..5).rev() {
            v.push(Row {
                p: pose(TARGETS_MM[i], 0.0, 0.0, 0.0, 0.0),
                iso: Some((i, Direction::Down, cycle)),
            });
        }
        v.push(Row {
            p: pose(-2.688, 0.0, 0.0, 0.0, 0.0),
            iso: None,
        });
    }
    assert_eq!(v.len(), 36);
    let spec = TrajectorySpec {
        n_poses: 40,
        a_start_deg: 0.0,
        a_end_deg: -90.0,
        c_turns: 2.0,
    };
    for p in setup.trajectory(&spec) {
        v.push(Row { p, iso: None });
    }
    for k in 0..9 {
        v.push(Row {
            p: pose(200.0, 0.0, 50.0 * k as f64, 0.0, 0.0),
            iso: None,
        });
    }
    v
}

/// PSD readings along Z, µm: offset + slope + a bow of known range (4 µm in x, 0.8 µm in y).
fn psd_um(z_mm: f64) -> (f64, f64) {
    (
        5.0 + 0.02 * z_mm + 1e-4 * (z_mm - 200.0).powi(2),
        -3.0 - 0.01 * z_mm - 2e-5 * (z_mm - 200.0).powi(2),
    )
}

fn air_c_at(t_s: f64) -> f64 {
    20.0 + 0.01 * t_s
}

struct Spec {
    /// ISO visit (cycle, dir, target 0-based) whose interferometer value is not ok.
    missing: Option<(usize, Direction, usize)>,
    /// CapBall pose (1-based in the log) whose value is not ok.
    capball_bad_pose: Option<u32>,
    attach_trajectory: bool,
    /// Run metadata `time_scale`.
    time_scale: Option<f64>,
}

fn value(inst: Instrument, pose_no: u32, t_ns: u64, ch: &[(&str, f64)]) -> PoseMsg {
    PoseMsg {
        instrument: inst,
        pose: pose_no,
        status: PoseStatus::Ok,
        n: 150,
        mean: ch.iter().map(|(k, v)| (k.to_string(), *v)).collect(),
        std: ch.iter().map(|(k, _)| (k.to_string(), 0.01)).collect(),
        t_first_ns: t_ns,
        t_last_ns: t_ns + 150_000_000,
        datum_epoch: 0,
    }
}

fn no_value(inst: Instrument, pose_no: u32, t_ns: u64, st: PoseStatus) -> PoseMsg {
    PoseMsg {
        instrument: inst,
        pose: pose_no,
        status: st,
        n: 0,
        mean: BTreeMap::new(),
        std: BTreeMap::new(),
        t_first_ns: t_ns,
        t_last_ns: t_ns,
        datum_epoch: 0,
    }
}

fn trajectory_csv(rows: &[Row]) -> String {
    let mut s = String::from("pose,x_mm,y_mm,z_mm,a_deg,c_deg\n");
    for (k, r) in rows.iter().enumerate() {
        s += &format!(
            "{},{},{},{},{},{}\n",
            k + 1,
            r.p.x_mm,
            r.p.y_mm,
            r.p.z_mm,
            r.p.a_deg,
            r.p.c_deg
        );
    }
    s
}

/// Writes the log; pose k (1-based) is measured at T0 + k s.
fn write_log(dir: &Path, spec: &Spec) -> PathBuf {
    let setup = CapballSetup::paper_default();
    let errors = CapballErrors::from_slice(&CAPBALL_P);
    let rows = rows(&setup);
    let path = dir.join("run.mcap");
    let mut meta = RunMetadata {
        machine: "synthetic".into(),
        started_ns: T0_NS,
        ..Default::default()
    };
    if let Some(k) = spec.time_scale {
        meta.extra.insert("time_scale".into(), k.to_string());
    }
    let mut w = LogWriter::create(&path, &meta, LogOptions::default()).unwrap();
    w.attach(
        "metrolog.toml",
        "application/toml",
        b"[run]\nmachine = \"synthetic\"\n\n[interferometer]\nport = \"/dev/ttyUSB0\"\nalpha_um_per_m_k = 11.7\n",
        T0_NS,
    )
    .unwrap();
    // The identity the LI-80 answered to *IDN?, as the service records it on connect.
    w.write_metadata(
        metrolog_log::INSTRUMENT_METADATA,
        [
            ("instrument", "interferometer"),
            ("identity", "METROLOG,LI-80,0042,2.1"),
            ("port", "/dev/ttyUSB0"),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect(),
    )
    .unwrap();
    if spec.attach_trajectory {
        w.attach(
            "trajectory.csv",
            "text/csv",
            trajectory_csv(&rows).as_bytes(),
            T0_NS,
        )
        .unwrap();
    }
    // Environment every 0.5 s, material sensors 20.5 and 20.7 °C.
    for k in 0..2 * (rows.len() + 2) {
        let t_s = k as f64 * 0.5;
        let t_ns = T0_NS + (t_s * 1e9) as u64;
        let env = metrolog_log::topics::Decoded::Environment(EnvironmentMsg {
            seq: k as u64,
            device_t_us: 0,
            fitted_ns: t_ns,
            air_c: air_c_at(t_s),
            air_pa: 101325.0 + 10.0 * (k % 3) as f64,
            rh_pct: 45.0 + 0.5 * (k % 2) as f64,
            material_c: vec![20.5, 20.7],
            n_air: 1.00027,
            valid: true,
        });
        w.write_sample(&env.to_sample(t_ns).unwrap()).unwrap();
    }
    for (k, r) in rows.iter().enumerate() {
        let no = k as u32 + 1;
        let t_ns = T0_NS + no as u64 * 1_000_000_000;
        let log_ns = t_ns + 200_000_000;
        // Interferometer: position from the datum at home (x = 0).
        let li = match r.iso {
            Some((i, d, c)) if spec.missing == Some((c, d, i)) => no_value(
                Instrument::Interferometer,
                no,
                t_ns,
                PoseStatus::BeamInvalid,
            ),
            Some((i, d, c)) => value(
                Instrument::Interferometer,
                no,
                t_ns,
                &[("position_um", r.p.x_mm * 1000.0 + dev_um(i, d, c))],
            ),
            // The far reversal gets a value (a dwell of 0 may still settle), the near one not.
            None if r.p.x_mm > 400.0 => value(
                Instrument::Interferometer,
                no,
                t_ns,
                &[("position_um", r.p.x_mm * 1000.0 + 9.0)],
            ),
            None if k < 36 => no_value(
                Instrument::Interferometer,
                no,
                t_ns,
                PoseStatus::NeverSteady,
            ),
            None => value(
                Instrument::Interferometer,
                no,
                t_ns,
                &[("position_um", r.p.x_mm * 1000.0)],
            ),
        };
        w.write_pose(log_ns, &li).unwrap();
        // CapBall: the forward model on its poses, junk elsewhere.
        let e = if (37..=76).contains(&no) {
            let v = setup.volumetric_error_um(&errors, &r.p);
            [v.x, v.y, v.z]
        } else {
            [300.0, -200.0, 100.0]
        };
        let cb = if spec.capball_bad_pose == Some(no) {
            no_value(Instrument::Capball, no, t_ns, PoseStatus::NeverSteady)
        } else {
            value(
                Instrument::Capball,
                no,
                t_ns,
                &[("ex_um", e[0]), ("ey_um", e[1]), ("ez_um", e[2])],
            )
        };
        w.write_pose(log_ns, &cb).unwrap();
        // PSD: the bow on its segment, a tilted line elsewhere.
        let (x, y) = if no >= 77 {
            psd_um(r.p.z_mm)
        } else {
            (0.3 * k as f64, -0.2 * k as f64)
        };
        w.write_pose(
            log_ns,
            &value(Instrument::Psd, no, t_ns, &[("x_um", x), ("y_um", y)]),
        )
        .unwrap();
    }
    w.finish().unwrap();
    path
}

fn default_spec() -> Spec {
    Spec {
        missing: Some((2, Direction::Down, 2)),
        capball_bad_pose: Some(50),
        attach_trajectory: true,
        time_scale: None,
    }
}

/// Pose number (1-based) of an ISO visit in the demo layout.
fn pose_of(i: usize, d: Direction, cycle: usize) -> u32 {
    let base = (cycle - 1) * 12;
    (match d {
        Direction::Up => base + i + 1,
        Direction::Down => base + 6 + (4 - i) + 1,
    }) as u32
}

#[test]
fn positioning_from_log_gives_the_iso_run() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_log(dir.path(), &default_spec());
    let d = analysis::positioning_from_log(&path, &PositioningOptions::default()).unwrap();
    assert_eq!(d.n_targets(), 5);
    assert_eq!(d.n_cycles(), 3);
    assert_eq!(d.readings.len(), 29, "30 visits, one not ok");
    assert_eq!(d.missing(), vec![(2, Direction::Down, 3)]);
    assert_eq!(d.alpha_um_per_m_k, Some(11.7));
    assert!(d.material_compensation && d.has_times);
    assert_eq!(d.metadata.get("poses").map(String::as_str), Some("1-36"));
    for (k, t) in d.targets_mm().iter().enumerate() {
        assert!((t - TARGETS_MM[k]).abs() < 1e-9);
    }
    for r in &d.readings {
        let i = r.index - 1;
        let want = dev_um(i, r.direction, r.cycle);
        assert!((r.deviation_um - want).abs() < 1e-6, "{r:?}: want {want}");
        // Pose 1 is the run's first pose value, measured at T0 + 1 s.
        let no = pose_of(i, r.direction, r.cycle);
        assert!(
            (r.time_s - (no as f64 - 1.0)).abs() < 1e-9,
            "{r:?} pose {no}"
        );
        // Nearest environment record: mid-dwell at no + 0.075 s → the 0.5 s grid point no.
        let air = air_c_at(no as f64);
        assert!((r.air_c.unwrap() - air).abs() < 1e-9, "{r:?}");
        assert!((r.material_c.unwrap() - 20.6).abs() < 1e-9);
    }
}

#[test]
fn explicit_range_and_trajectory_override() {
    let dir = tempfile::tempdir().unwrap();
    let spec = Spec {
        missing: None,
        capball_bad_pose: None,
        attach_trajectory: false,
        time_scale: Some(120.0),
    };
    let path = write_log(dir.path(), &spec);
    let err = analysis::positioning_from_log(&path, &PositioningOptions::default()).unwrap_err();
    assert!(err.to_string().contains("--trajectory"), "{err}");
    let traj = dir.path().join("traj.csv");
    std::fs::write(&traj, trajectory_csv(&rows(&CapballSetup::paper_default()))).unwrap();
    // Only cycle 1 (poses 1-12).
    let opts = PositioningOptions {
        trajectory: Some(traj),
        poses: Some(analysis::parse_pose_range("1-12").unwrap()),
        datum_x_mm: None,
    };
    let d = analysis::positioning_from_log(&path, &opts).unwrap();
    assert_eq!((d.n_targets(), d.n_cycles(), d.readings.len()), (5, 1, 10));
    assert!(d.missing().is_empty());
    // Time scale 120: pose k at (k − 1)·120 s.
    for r in &d.readings {
        let no = pose_of(r.index - 1, r.direction, r.cycle);
        assert!((r.time_s - 120.0 * (no as f64 - 1.0)).abs() < 1e-6, "{r:?}");
    }
    assert!(analysis::parse_pose_range("12-1").is_err());
    assert!(analysis::parse_pose_range("x").is_err());
}

#[test]
fn analyze_and_diagnose_commands_read_the_log() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_log(dir.path(), &default_spec());
    let p = path.to_str().unwrap();
    let (ok, out, err) = metrolog(&["analyze", "positioning", p, "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["n_targets"], 5);
    assert_eq!(v["missing"].as_array().unwrap().len(), 1);
    // E↑ and B worked out from the known deviations (means over the cycles present).
    let mean = |i: usize, d: Direction| {
        let xs: Vec<f64> = (1..=3)
            .filter(|c| !(i == 2 && d == Direction::Down && *c == 2))
            .map(|c| dev_um(i, d, c))
            .collect();
        xs.iter().sum::<f64>() / xs.len() as f64
    };
    let up: Vec<f64> = (0..5).map(|i| mean(i, Direction::Up)).collect();
    let e_up =
        up.iter().cloned().fold(f64::MIN, f64::max) - up.iter().cloned().fold(f64::MAX, f64::min);
    let b = (0..5)
        .map(|i| (mean(i, Direction::Up) - mean(i, Direction::Down)).abs())
        .fold(0.0, f64::max);
    let got = &v["iso230_2"];
    assert!((got["E_up"].as_f64().unwrap() - e_up).abs() < 1e-6, "{got}");
    assert!((got["B"].as_f64().unwrap() - b).abs() < 1e-6, "{got}");

    let (ok, out, err) = metrolog(&["diagnose", p, "--json", "--check-seeds", "2"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert!(v["findings"].is_array(), "{v}");
}

#[test]
fn capball_from_log_selects_the_ball_poses_and_identify_recovers_the_errors() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_log(dir.path(), &default_spec());
    let cb = analysis::capball_from_log(&path).unwrap();
    assert_eq!(cb.records.len(), 39, "40 CapBall poses, pose 50 not ok");
    assert_eq!(cb.skipped, vec![(50, "never_steady".to_string())]);
    assert!(cb.records.iter().all(|r| (37..=76).contains(&r.pose_index)));
    let ball = CapballSetup::paper_default().ball_mm;
    assert!((cb.ball_mm - ball).norm() < 1e-6);

    let (ok, out, err) = metrolog(&["identify", "capball", path.to_str().unwrap(), "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let params = v["runs"][0]["identification"]["params"].as_array().unwrap();
    for (k, want) in CAPBALL_P.iter().enumerate() {
        let got = params[k].as_f64().unwrap();
        assert!((got - want).abs() < 1e-3, "param {k}: {got} vs {want}");
    }
    assert!(err.contains("pose 50 skipped"), "{err}");
}

#[test]
fn psd_segment_straightness() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_log(dir.path(), &default_spec());
    let s = analysis::psd_from_log(&path).unwrap();
    assert_eq!((s.axis, s.first_pose, s.last_pose), ('Z', 77, 85));
    assert_eq!(s.points.len(), 9);
    // A parabola symmetric about the segment's middle: its least-squares line is flat at the
    // mean, so the residual range is the parabola's own: 1e-4·200² = 4 µm, 2e-5·200² = 0.8 µm.
    assert!((s.straightness_x_um - 4.0).abs() < 1e-9, "{s:?}");
    assert!((s.straightness_y_um - 0.8).abs() < 1e-9, "{s:?}");
    assert!((s.slope_x_um_per_mm - 0.02).abs() < 1e-12);
    assert!((s.slope_y_um_per_mm + 0.01).abs() < 1e-12);
    assert_eq!(s.error_names(), ("EXZ".to_string(), "EYZ".to_string()));
}

/// The bytes of an MCAP file up to its DataEnd record: every chunk whole, the summary and
/// footer gone (a log torn after its last chunk was written).
fn torn_after_the_data(file: &[u8]) -> Vec<u8> {
    const DATA_END: u8 = 0x0F;
    let mut at = 8;
    while at + 9 <= file.len() {
        let len = u64::from_le_bytes(file[at + 1..at + 9].try_into().expect("8 bytes")) as usize;
        if file[at] == DATA_END {
            return file[..at].to_vec();
        }
        at += 9 + len;
    }
    panic!("the test log has no DataEnd record");
}

/// CapBall and PSD results from a damaged log say in their header that they are built on
/// part of the run (the positioning reports did; the CapBall ones said nothing on stdout).
#[test]
fn capball_and_psd_results_of_a_damaged_log_say_so() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_log(dir.path(), &default_spec());
    let torn = dir.path().join("torn.mcap");
    std::fs::write(&torn, torn_after_the_data(&std::fs::read(&path).unwrap())).unwrap();
    const NOTE: &str = "BUILT ON PART OF THE RUN: the log is damaged";
    let r = analysis::demo_report(&torn).unwrap();
    assert!(r.contains(NOTE), "{r}");
    assert!(r.contains("CapBall identification (39 poses"), "{r}");
    assert!(r.contains("PSD straightness along Z"), "{r}");
    let t = torn.to_str().unwrap();
    let (ok, out, err) = metrolog(&["identify", "capball", t]);
    assert!(ok, "{err}");
    assert!(out.starts_with(NOTE), "{out}");
    let (ok, out, err) = metrolog(&["identify", "capball", t, "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert!(v["log_damage"].is_string(), "{out}");
    // The intact log: no note, `log_damage` null.
    let (ok, out, err) = metrolog(&["identify", "capball", path.to_str().unwrap(), "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert!(v["log_damage"].is_null(), "{out}");
    assert!(!analysis::demo_report(&path).unwrap().contains(NOTE));
}

#[test]
fn demo_report_has_every_part() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_log(dir.path(), &default_spec());
    let r = analysis::demo_report(&path).unwrap();
    for needle in [
        "ISO 230-2, axis X (poses 1-36, 5 targets × 3 cycles, 1 missing)",
        "A↑",
        "B̄",
        "Diagnosis",
        "CapBall identification (39 poses, 1 skipped",
        "EC0Y_urad 12.00",
        "condition number",
        "residual RMS",
        "PSD straightness along Z (poses 77-85, 9 points",
        "EXZ 4.00 µm, EYZ 0.80 µm",
    ] {
        assert!(r.contains(needle), "missing `{needle}` in:\n{r}");
    }
}

/// Manual check on a real log: `ADAPT_DEMO_LOG=path.mcap cargo nextest run -p metrolog
/// --test adapt_log --no-capture print_demo_report_of_a_real_log` (skipped without it).
#[test]
fn print_demo_report_of_a_real_log() {
    let Ok(p) = std::env::var("ADAPT_DEMO_LOG") else {
        return;
    };
    let r = analysis::demo_report(Path::new(&p)).unwrap();
    println!("{r}");
}

/// The demo scenario's CapBall poses (sim/scenarios/demo.toml, ball at 100, 0, 50 mm) hold
/// the tool on one ball in the simulator-convention machine, not in paper 001's.
#[test]
fn simulator_convention_machine_fits_the_demo_poses() {
    let demo = [
        (100.0, 0.0, 50.0, 0.0, 0.0),
        (0.0, 100.0, 50.0, 0.0, 90.0),
        (100.0, 25.0, 43.301, -30.0, 0.0),
        (0.0, 111.603, -6.699, -30.0, 90.0),
        (-0.0, -6.699, 111.603, -60.0, 270.0),
        (-0.0, 50.0, 100.0, -90.0, 270.0),
    ];
    let m = analysis::capball::machine_candidates();
    for (x, y, z, a, c) in demo {
        let w = m[1].1.nominal_work_point_mm(&pose(x, y, z, a, c));
        assert!(
            (w - nalgebra::Vector3::new(100.0, 0.0, 50.0)).norm() < 2e-3,
            "{w:?}"
        );
    }
    let w0 = m[0]
        .1
        .nominal_work_point_mm(&pose(0.0, 100.0, 50.0, 0.0, 90.0));
    assert!((w0 - nalgebra::Vector3::new(100.0, 0.0, 50.0)).norm() > 1.0);
}

/// The report's header comes from the log's own records: the run's start time, the identity
/// and serial the instrument answered, the environment's min / mean / max (worked out here from
/// what write_log wrote), the material temperature, and the sensor's budget (no borrowed terms).
#[test]
fn report_header_is_read_from_the_logs_own_metadata() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_log(dir.path(), &default_spec());
    let html = dir.path().join("r.html");
    let (ok, _, err) = metrolog(&[
        "report",
        path.to_str().unwrap(),
        "-o",
        html.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let text = std::fs::read_to_string(&html).unwrap();
    // 1_795_305_600 s after the epoch = 20 779 days of 86 400 s: 2026-11-22, 00:00 UTC.
    assert!(
        text.contains("2026-11-22T00:00:00"),
        "run start not in the header"
    );
    assert!(text.contains("(run start, from the log)"));
    assert!(text.contains("s/n 0042"), "serial not in the header");
    // Environment records k = 0..n: pressure 101.325 + 0.010·(k mod 3) kPa, humidity
    // 45 + 0.5·(k mod 2) %RH.
    let n = 2 * (rows(&CapballSetup::paper_default()).len() + 2);
    let p: Vec<f64> = (0..n).map(|k| 101.325 + 0.010 * (k % 3) as f64).collect();
    let h: Vec<f64> = (0..n).map(|k| 45.0 + 0.5 * (k % 2) as f64).collect();
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let want_p = format!("101.325 / {:.3} / 101.345 kPa", mean(&p));
    let want_h = format!("45.0 / {:.1} / 45.5 %RH", mean(&h));
    assert!(text.contains(&want_p), "{want_p} not in the header");
    assert!(text.contains(&want_h), "{want_h} not in the header");
    // The material sensors read 20.5 and 20.7 °C at every record: each reading's material
    // temperature is their mean, 20.60 °C.
    assert!(
        text.contains("<th>Material temperature</th><td>20.60 / 20.60 / 20.60 °C"),
        "material temperature not shown"
    );
    assert!(text.contains("readings normalised to 20 °C from the material temperature"));
}
