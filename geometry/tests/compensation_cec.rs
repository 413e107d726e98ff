//! SINUMERIK CEC tables from a volumetric grid: enabled by SD41300, within the 828D's eight
//! tables, and stating the tool offset they are valid for (`docs/methods.md`
//! "Pitch-error compensation").

use geometry::kinematics::Machine;
use geometry::volumetric::*;

/// A separable grid (positioning and straightness only): X→X, X→Y, Y→Z and Z→X carry
/// corrections, the five other tables are zero.
fn grid() -> (Vec<GridPoint>, GridSpec) {
    let m = Machine::from_chain("WYFXZT").unwrap();
    let e = ComponentErrors::from_csv(
        "error,position_mm,value\nEXX,0,0\nEXX,400,8\nEYX,0,0\nEYX,200,3\nEYX,400,0\nEZY,0,0\nEZY,300,-5\nEXZ,0,1\nEXZ,200,-1\n",
    )
    .unwrap();
    let g = GridSpec::parse("0:400:5,0:300:4,0:200:3").unwrap();
    (volumetric_grid(&m, &e, &g).unwrap(), g)
}

/// The table numbers each `$AN_CEC_INPUT_AXIS[t]` / `$SN_CEC_TABLE_ENABLE[t]=1` line names.
fn numbers(ini: &str, prefix: &str) -> Vec<usize> {
    ini.lines()
        .filter_map(|l| l.strip_prefix(prefix))
        .map(|r| r[..r.find(']').unwrap()].parse().unwrap())
        .collect()
}

#[test]
fn every_table_written_is_enabled() {
    let (pts, g) = grid();
    let cec = siemens_cec(&pts, &g, ["AX1", "AX2", "AX3"]).expect("CEC tables");
    let tables = numbers(&cec.ini, "$AN_CEC_INPUT_AXIS[");
    assert_eq!(tables, (0..9).collect::<Vec<_>>());
    let enabled: Vec<usize> = cec
        .ini
        .lines()
        .filter(|l| l.starts_with("$SN_CEC_TABLE_ENABLE[") && l.ends_with("]=1"))
        .map(|l| l[21..l.find(']').unwrap()].parse().unwrap())
        .collect();
    assert_eq!(enabled, tables);
    assert!(cec.ini.contains("tool offset not stated"));
    assert!(cec.omitted.is_empty());
}

#[test]
fn sinumerik_828d_gets_at_most_eight_tables_and_the_cost_is_reported() {
    let (pts, g) = grid();
    let o = CecOptions {
        axis_names: ["X1", "Y1", "Z1"],
        max_tables: CEC_TABLES_828D,
        tool_offset_mm: Some([0.0, 0.0, -150.0]),
    };
    let cec = siemens_cec_for(&pts, &g, &o).expect("CEC tables");
    let tables = numbers(&cec.ini, "$AN_CEC_INPUT_AXIS[");
    assert_eq!(tables, (0..8).collect::<Vec<_>>());
    assert_eq!(numbers(&cec.ini, "$SN_CEC_TABLE_ENABLE[").len(), 8);
    // The table left out is one of the zero tables: nothing is lost.
    assert_eq!(cec.omitted.len(), 1);
    assert!(cec.omitted[0].contains("0.00 µm"), "{:?}", cec.omitted);
    assert!(cec.max_separation_residual_um < 1e-6);
    assert!(
        cec.ini
            .contains("valid for the tool offset (0.000, 0.000, -150.000) mm")
    );
    // Only four tables carry corrections: keeping three loses the smallest, and says so.
    let o3 = CecOptions { max_tables: 3, ..o };
    let cec3 = siemens_cec_for(&pts, &g, &o3).expect("CEC tables");
    assert_eq!(numbers(&cec3.ini, "$AN_CEC_INPUT_AXIS[").len(), 3);
    assert!(
        cec3.max_separation_residual_um > 0.5,
        "{}",
        cec3.max_separation_residual_um
    );
    let lost = cec3
        .omitted
        .iter()
        .map(|s| {
            s.split("up to ")
                .nth(1)
                .unwrap()
                .trim_end_matches(" µm)")
                .parse::<f64>()
                .unwrap()
        })
        .fold(0.0f64, f64::max);
    assert!(
        (cec3.max_separation_residual_um - lost).abs() < 0.01,
        "{:?}",
        cec3.omitted
    );
}

/// The machine axis names go into `$AN_CEC_INPUT_AXIS[t]=(AX1)`: only letters with optional
/// digits are written; a name that would change the file's syntax is refused, and so is a grid
/// holding a non-finite error (no NaN or inf in a controller file).
#[test]
fn cec_refuses_names_outside_the_syntax_and_non_finite_values() {
    let (pts, g) = grid();
    for bad in [
        "AX1)",
        "X]",
        "X=1",
        "X;",
        "X\nM30",
        "../x",
        "",
        "1X",
        "ABCDEFGH1",
    ] {
        let e = siemens_cec(&pts, &g, [bad, "AX2", "AX3"]).expect_err(bad);
        assert_eq!(e, VolumetricError::BadAxisName(bad.into()), "{bad:?}");
        assert!(e.to_string().contains("--axis-names"), "{e}");
    }
    for bad in [f64::NAN, f64::INFINITY] {
        let mut p = pts.clone();
        p[3].error_um[1] = bad;
        let e = siemens_cec(&p, &g, ["AX1", "AX2", "AX3"]).expect_err("non-finite");
        assert!(matches!(e, VolumetricError::NotFinite(_)), "{e}");
    }
}

/// The corrections a control reads from a CEC file at a point: for each output axis, the sum
/// over its tables of the table's value interpolated linearly at the input axis' position
/// (K3 §4.4), written here from the file's text alone. Positions in mm, corrections in µm.
fn control_correction(ini: &str, names: [&str; 3], q_mm: [f64; 3]) -> [f64; 3] {
    let value = |key: &str, t: usize| -> &str {
        let pre = format!("{key}[{t}]=");
        ini.lines()
            .find_map(|l| l.strip_prefix(pre.as_str()))
            .unwrap_or_else(|| panic!("no {pre} in the file"))
    };
    let axis = |s: &str| names.iter().position(|n| s == format!("({n})")).unwrap();
    let mut out = [0.0; 3];
    for t in numbers(ini, "$AN_CEC_INPUT_AXIS[") {
        let (input, output) = (
            axis(value("$AN_CEC_INPUT_AXIS", t)),
            axis(value("$AN_CEC_OUTPUT_AXIS", t)),
        );
        let step: f64 = value("$AN_CEC_STEP", t).parse().unwrap();
        let min: f64 = value("$AN_CEC_MIN", t).parse().unwrap();
        assert!(step > 0.0, "table {t}: step {step}");
        let points: Vec<f64> = (0..)
            .map_while(|p| {
                let pre = format!("$AN_CEC[{t},{p}]=");
                ini.lines()
                    .find_map(|l| l.strip_prefix(pre.as_str()))
                    .map(|v| v.parse::<f64>().unwrap())
            })
            .collect();
        let s = ((q_mm[input] - min) / step).clamp(0.0, (points.len() - 1) as f64);
        let (i, f) = (s.floor() as usize, s - s.floor());
        let v = if i + 1 < points.len() {
            points[i] * (1.0 - f) + points[i + 1] * f
        } else {
            points[i]
        };
        out[output] += v * 1e3;
    }
    out
}

/// A grid with one point along an axis (a plane of a 3D machine): that axis has no table (a
/// step of 0 is no table), and the file still gives every grid point its correction, as read
/// by the interpolation a control does. One point on every axis is refused.
#[test]
fn a_grid_with_one_point_along_an_axis_writes_no_table_for_it() {
    let m = Machine::from_chain("WYFXZT").unwrap();
    let e = ComponentErrors::from_csv(
        "error,position_mm,value\nEXX,0,2\nEXX,400,8\nEYX,0,0\nEYX,200,3\nEYX,400,0\nEZY,0,4\nEZY,300,-5\nEXZ,0,1\nEXZ,200,-1\n",
    )
    .unwrap();
    let names = ["AX1", "AX2", "AX3"];
    for spec in ["0:400:5,150:150:1,0:200:3", "250:250:1,150:150:1,0:200:3"] {
        let g = GridSpec::parse(spec).unwrap();
        let pts = volumetric_grid(&m, &e, &g).unwrap();
        let cec = siemens_cec(&pts, &g, names).expect("CEC tables");
        assert!(!cec.ini.contains("_STEP[0]=0.000000"), "{}", cec.ini);
        assert!(
            !cec.ini.contains("=(AX2)\n$AN_CEC_OUTPUT"),
            "no table along Y: {}",
            cec.ini
        );
        for p in &pts {
            let c = control_correction(&cec.ini, names, p.pos_mm);
            for k in 0..3 {
                assert!(
                    (c[k] + p.error_um[k]).abs() < 2e-3,
                    "{spec} at {:?}: correction {c:?}, error {:?}",
                    p.pos_mm,
                    p.error_um
                );
            }
        }
    }
    let g = GridSpec::parse("0:0:1,150:150:1,10:10:1").unwrap();
    let pts = volumetric_grid(&m, &e, &g).unwrap();
    let err = siemens_cec(&pts, &g, names).expect_err("one point");
    assert!(
        err.to_string().contains("two points along an axis"),
        "{err}"
    );
}
