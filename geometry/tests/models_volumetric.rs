//! Volumetric model tests: hand-worked cases, small-angle cross-check, tables, compensation.

// Parallel arrays indexed together read more plainly with an index.
#![allow(clippy::needless_range_loop)]

use geometry::kinematics::{Machine, MachineConfig, Pose};
use geometry::volumetric::*;
use nalgebra::Vector3;

fn errors_from(csv: &str) -> ComponentErrors {
    ComponentErrors::from_csv(csv).unwrap()
}

#[test]
fn squareness_hand_worked() {
    // EC0Y = 100 µrad: moving Y by 200 mm shifts the tool by −100e-6 · 200 mm = −20 µm in X.
    let m = Machine::from_chain("WYFXZT").unwrap();
    let e = errors_from("error,position_mm,value\nEC0Y,,100\n");
    let v = m.volumetric_error_um(&Pose::xyz(50.0, 200.0, 30.0), &e, None);
    assert!((v - Vector3::new(-20.0, 0.0, 0.0)).norm() < 1e-6, "{v}");
    // EB0Z = 50 µrad: Z travel 300 mm → +15 µm in X; EA0Z = 50 µrad → −15 µm in Y.
    let e = errors_from("error,position_mm,value\nEB0Z,,50\nEA0Z,,50\n");
    let v = m.volumetric_error_um(&Pose::xyz(0.0, 0.0, 300.0), &e, None);
    assert!((v - Vector3::new(15.0, -15.0, 0.0)).norm() < 1e-3, "{v}");
}

#[test]
fn abbe_offset_of_pitch_hand_worked() {
    // X carries Z carries the tool, tool 150 mm below the Z carriage: a constant X pitch
    // EBX = 50 µrad acts on the lever z − 150 mm; at z = 100 mm: 50e-6 · (−50 mm) = −2.5 µm in X.
    let cfg = MachineConfig {
        chain: "WYFXZT".into(),
        tool_offset_mm: [0.0, 0.0, -150.0],
        axes: Default::default(),
    };
    let m = Machine::from_config(&cfg).unwrap();
    let e = errors_from("error,position_mm,value\nEBX,0,50\nEBX,500,50\n");
    let v = m.volumetric_error_um(&Pose::xyz(250.0, 10.0, 100.0), &e, None);
    assert!((v - Vector3::new(-2.5, 0.0, 0.0)).norm() < 1e-4, "{v}");
    // Positioning and straightness add directly whichever side carries the axis.
    let e = errors_from("error,position_mm,value\nEXX,0,0\nEXX,500,10\nEZY,0,0\nEZY,400,-4\n");
    let v = m.volumetric_error_um(&Pose::xyz(250.0, 200.0, 0.0), &e, None);
    assert!((v - Vector3::new(5.0, 0.0, -2.0)).norm() < 1e-6, "{v}");
}

#[test]
fn small_angle_form_agrees_within_its_neglected_terms() {
    // Realistic errors: straightness/positioning up to 20 µm, angles up to 100 µrad, 1 m axes.
    let mut csv = String::from("error,position_mm,value\nEC0Y,,80\nEB0Z,,-60\nEA0Z,,40\n");
    let names = [
        "EXX", "EYX", "EZX", "EAX", "EBX", "ECX", "EXY", "EYY", "EZY", "EAY", "EBY", "ECY", "EXZ",
        "EYZ", "EZZ", "EAZ", "EBZ", "ECZ",
    ];
    for (n, name) in names.iter().enumerate() {
        let amp = if name.as_bytes()[1] >= b'X' {
            20.0
        } else {
            100.0
        };
        for i in 0..=10 {
            let q = i as f64 * 100.0;
            let v = amp * ((q / 300.0 + n as f64).sin());
            csv.push_str(&format!("{name},{q},{v}\n"));
        }
    }
    let e = errors_from(&csv);
    let cfg = MachineConfig {
        chain: "WYFXZT".into(),
        tool_offset_mm: [20.0, -10.0, -200.0],
        axes: Default::default(),
    };
    let m = Machine::from_config(&cfg).unwrap();
    let mut worst: f64 = 0.0;
    for &(x, y, z) in &[
        (0.0, 0.0, 0.0),
        (1000.0, 1000.0, 1000.0),
        (300.0, 700.0, 150.0),
        (900.0, 50.0, 600.0),
    ] {
        let p = Pose::xyz(x, y, z);
        let exact = m.volumetric_error_um(&p, &e, None);
        let lin = small_angle_error_um(&m, &e, &p);
        worst = worst.max((exact - lin).norm());
        // The first-order terms themselves are tens of µm: the comparison is not vacuous.
        assert!(exact.norm() > 5.0);
    }
    // Neglected: (Σ|ε|)²·L + Σ|ε|·Σ|δ| with Σ|ε| ≤ 9·100 + 180 µrad ≈ 1.1e-3, L ≈ 1.8 m,
    // Σ|δ| ≤ 180 µm: 1.1e-3² · 1.8e6 µm + 1.1e-3 · 180 µm ≈ 2.4 µm (a loose upper bound).
    assert!(worst < 2.4, "exact − small-angle = {worst} µm");
    assert!(
        worst > 1e-6,
        "the exact model should differ from the linear one at second order"
    );
}

#[test]
fn spline_tables_interpolate_and_hold_ends() {
    let c = ErrorCurve::table(
        "EXX",
        vec![(0.0, 0.0), (100.0, 1.0), (200.0, 2.0), (300.0, 3.0)],
    )
    .unwrap();
    // A natural spline reproduces a straight line exactly.
    assert!((c.eval(150.0) - 1.5).abs() < 1e-12);
    assert_eq!(c.eval(-10.0), 0.0);
    assert_eq!(c.eval(400.0), 3.0);
    let c = ErrorCurve::table("EXX", vec![(0.0, 0.0), (100.0, 4.0), (200.0, 0.0)]).unwrap();
    assert!((c.eval(100.0) - 4.0).abs() < 1e-12);
    // Natural spline through (0,0),(100,4),(200,0): M1 = −6·8/(4·100²)·… hand-worked value at 50:
    // M1 = 3·(−8/100)/(200) ⇒ s(50) = 2 − (0.375 · M1 · 100²)/6 = 2.75.
    assert!((c.eval(50.0) - 2.75).abs() < 1e-9, "{}", c.eval(50.0));
    assert!(ErrorCurve::table("EXX", vec![(0.0, 1.0)]).is_err());
    assert!(ErrorCurve::table("EXX", vec![(0.0, 1.0), (0.0, 2.0)]).is_err());
}

#[test]
fn csv_errors_are_clear() {
    let e = ComponentErrors::from_csv("error,position_mm,value\nEQX,0,1\n").unwrap_err();
    assert!(matches!(e, VolumetricError::BadName { row: 2, .. }), "{e}");
    let e = ComponentErrors::from_csv("error,position_mm,value\nEXX,0,abc\n").unwrap_err();
    assert!(e.to_string().contains("row 2"), "{e}");
    let e = ComponentErrors::from_csv("error,position_mm,value\nEXX,,1\nEXX,2,1\n").unwrap_err();
    assert!(e.to_string().contains("position_mm"), "{e}");
    assert!(ComponentErrors::from_csv("error,pos,value\n").is_err());
    // Finite but beyond any machine (issue 27: 1e300 overflowed to an infinite table).
    let e =
        ComponentErrors::from_csv("error,position_mm,value\nEXX,0,0\nEXX,500,1e300\n").unwrap_err();
    assert!(
        e.to_string().contains("row 3") && e.to_string().contains("beyond"),
        "{e}"
    );
    let e =
        ComponentErrors::from_csv("error,position_mm,value\nEXX,-2e5,0\nEXX,0,1\n").unwrap_err();
    assert!(
        e.to_string().contains("row 2") && e.to_string().contains("position_mm"),
        "{e}"
    );
    let e = GridSpec::parse("0:1e308:3,0:1:2,0:1:2").unwrap_err();
    assert!(matches!(e, VolumetricError::GridRange(_)), "{e}");
    assert!(GridSpec::parse("-100000:100000:3,0:1:2,0:1:2").is_ok());
    assert!(GridSpec::parse("0:100:11,0:100:11").is_err());
    assert!(GridSpec::parse("0:100:11,0:100:0,0:1:2").is_err());
    assert_eq!(
        GridSpec::parse("0:100:11,0:50:6,0:10:2").unwrap().len(),
        132
    );
}

#[test]
fn grid_and_compensation_tables() {
    let m = Machine::from_chain("WYFXZT").unwrap();
    // Separable errors only (positioning, straightness): the nine CEC tables are exact.
    let e = errors_from(
        "error,position_mm,value\nEXX,0,0\nEXX,400,8\nEYX,0,0\nEYX,200,3\nEYX,400,0\nEZY,0,0\nEZY,300,-5\nEXZ,0,1\nEXZ,200,-1\n",
    );
    let g = GridSpec::parse("0:400:5,0:300:4,0:200:3").unwrap();
    let pts = volumetric_grid(&m, &e, &g).unwrap();
    assert_eq!(pts.len(), 60);
    // x = 200, y = 100, z = 100 → index (2·4 + 1)·3 + 1; EXX(200) = 4, EXZ(100) = 0 (linear
    // between 1 and −1), EYX(200) = 3, EZY(100): spline through (0,0),(300,−5) = −5/3.
    let p = pts[(2 * 4 + 1) * 3 + 1];
    assert_eq!(p.pos_mm, [200.0, 100.0, 100.0]);
    assert!((p.error_um[0] - 4.0).abs() < 1e-6 && (p.error_um[1] - 3.0).abs() < 1e-6);
    assert!((p.error_um[2] + 5.0 / 3.0).abs() < 1e-6);
    let cec = siemens_cec(&pts, &g, ["AX1", "AX2", "AX3"]).expect("CEC tables");
    assert!(
        cec.max_separation_residual_um < 1e-6,
        "{}",
        cec.max_separation_residual_um
    );
    assert_eq!(cec.ini.matches("$AN_CEC_INPUT_AXIS[").count(), 9);
    assert!(cec.ini.starts_with("%_N_NC_CEC_INI\n"));
    // Table 0 (X → X) at point 2 (x = 200, y = z = 0): −(EXX(200) + EXZ(0)) = −5 µm.
    assert!(cec.ini.contains("$AN_CEC[0,2]=-0.005000"));
    // A roll of X with a Y lever is not separable: the tables report what they miss.
    let e = errors_from("error,position_mm,value\nEAX,0,0\nEAX,400,100\n");
    let cfg = MachineConfig {
        chain: "WFXYZT".into(),
        tool_offset_mm: [0.0; 3],
        axes: Default::default(),
    };
    let m2 = Machine::from_config(&cfg).unwrap();
    let pts = volumetric_grid(&m2, &e, &g).unwrap();
    let cec = siemens_cec(&pts, &g, ["X1", "Y1", "Z1"]).expect("CEC tables");
    assert!(
        cec.max_separation_residual_um > 1.0,
        "{} {:?}",
        cec.max_separation_residual_um,
        summarize(&pts)
    );
    let csv = compensation_csv(&pts);
    assert_eq!(csv.lines().count(), 61);
    let s = summarize(&pts);
    assert_eq!(s.n_points, 60);
}

#[test]
fn grid_fast_path_matches_the_general_model() {
    let mut csv = String::from("error,position_mm,value\nEC0Y,,20\nEB0Z,,-10\nEA0Z,,5\n");
    for (n, name) in [
        "EXX", "EYX", "EZX", "EAX", "EBX", "ECX", "EXY", "EYY", "EZY", "EAY", "EBY", "ECY", "EXZ",
        "EYZ", "EZZ", "EAZ", "EBZ", "ECZ",
    ]
    .iter()
    .enumerate()
    {
        for i in 0..=8 {
            let q = i as f64 * 60.0;
            csv.push_str(&format!(
                "{name},{q},{}\n",
                (q / 90.0 + n as f64).sin() * 30.0
            ));
        }
    }
    let e = errors_from(&csv);
    for chain in ["WYFXZT", "WFXYZT", "WXYFZT"] {
        let cfg = MachineConfig {
            chain: chain.into(),
            tool_offset_mm: [5.0, -3.0, -100.0],
            axes: Default::default(),
        };
        let m = Machine::from_config(&cfg).unwrap();
        let g = GridSpec::parse("0:480:4,10:400:3,0:300:5").unwrap();
        for p in volumetric_grid(&m, &e, &g).unwrap() {
            let v =
                m.volumetric_error_um(&Pose::xyz(p.pos_mm[0], p.pos_mm[1], p.pos_mm[2]), &e, None);
            assert!(
                (v - Vector3::from(p.error_um)).norm() < 1e-9,
                "{chain} {:?}",
                p.pos_mm
            );
        }
    }
}
