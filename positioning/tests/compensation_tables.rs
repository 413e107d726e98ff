//! Pitch-error compensation tables (`docs/methods.md` "Pitch-error compensation"): each
//! dialect's file is read back with a syntax-level reader written here from the dialect's
//! documented conventions (not from the writer), and the error curve it encodes is compared
//! with the simulated axis' known error; the predicted ISO 230-2 result after compensation
//! is recomputed here from the file's own numbers.

use positioning::axis_model::{AxisModel, Direction, Effect};
use positioning::compensation::{
    CompensationError, CompensationTable, Dialect, Mode, Options, build, interpolate, verify,
};
use positioning::iso230::evaluate;
use positioning::positioning_data::{PositioningData, simulate, standard_schedule};

/// A 0…500 mm axis: scale error 20 µm/m, a 6 µm screw wave, a 5 µm backlash (down
/// approaches read 5 µm higher), little noise.
fn run(seed: u64) -> (AxisModel, PositioningData) {
    let targets: Vec<f64> = (0..11)
        .map(|i| i as f64 * 50.0 + if i % 2 == 1 { 1.7 } else { 0.0 })
        .collect();
    let sys = |x: f64| 0.02 * x + 6.0 * (x / 80.0).sin();
    let model = AxisModel {
        axis: "X".into(),
        systematic_up_um: targets.iter().map(|&x| sys(x)).collect(),
        systematic_down_um: targets.iter().map(|&x| sys(x) + 5.0).collect(),
        targets_mm: targets,
        noise_um: 0.2,
        effects: vec![Effect::LinearDrift { rate_um_per_h: 0.0 }],
    };
    let d = simulate(&model, &standard_schedule(11, 5, 6.0), seed);
    (model, d)
}

fn opts(dialect: Dialect, mode: Mode) -> Options {
    Options {
        dialect,
        mode,
        spacing_mm: Some(25.0),
        reference_mm: Some(0.0),
        axis_name: Some("X".into()),
        axis_number: 1,
    }
}

fn file<'a>(t: &'a CompensationTable, suffix: &str) -> &'a str {
    &t.files
        .iter()
        .find(|(n, _)| n.ends_with(suffix))
        .unwrap_or_else(|| {
            panic!(
                "no *{suffix} in {:?}",
                t.files.iter().map(|f| &f.0).collect::<Vec<_>>()
            )
        })
        .1
}

/// SINUMERIK `%_N_AX_EEC_INI`: returns (points, error µm) from `$AA_ENC_COMP[0,N,X]`,
/// `_STEP`, `_MIN`, `_MAX` (values in mm, error sign: K3 / 808D manual).
fn read_sinumerik(text: &str) -> (Vec<f64>, Vec<f64>) {
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("%_N_AX_EEC_INI"));
    assert!(text.contains("\nCHANDATA(1)\n") && text.trim_end().ends_with("M17"));
    let mut vals = Vec::new();
    let (mut step, mut min, mut max) = (None, None, None);
    for l in text.lines().filter(|l| l.starts_with('$')) {
        let (k, v) = l.split_once('=').unwrap();
        let v: f64 = v.parse().unwrap();
        let idx = &k[k.find('[').unwrap() + 1..k.len() - 1];
        let parts: Vec<&str> = idx.split(',').collect();
        match &k[..k.find('[').unwrap()] {
            "$AA_ENC_COMP" => {
                assert_eq!(parts[0], "0");
                assert_eq!(
                    parts[1].parse::<usize>().unwrap(),
                    vals.len(),
                    "points in order"
                );
                vals.push(v * 1e3);
            }
            "$AA_ENC_COMP_STEP" => step = Some(v),
            "$AA_ENC_COMP_MIN" => min = Some(v),
            "$AA_ENC_COMP_MAX" => max = Some(v),
            "$AA_ENC_COMP_IS_MODULO" => assert_eq!(v, 0.0),
            other => panic!("unexpected {other}"),
        }
    }
    let (step, min, max) = (step.unwrap(), min.unwrap(), max.unwrap());
    assert!((min + step * (vals.len() - 1) as f64 - max).abs() < 1e-6);
    (
        (0..vals.len()).map(|i| min + i as f64 * step).collect(),
        vals,
    )
}

/// FANUC tapes: parameters 3620–3624 and `N1xxxxP` incremental corrections.
fn read_fanuc(params: &str, pitch: &str) -> (Vec<f64>, Vec<f64>, f64) {
    let tape = |t: &str| -> Vec<(u32, i64)> {
        assert!(t.starts_with("%\n") && t.trim_end().ends_with('%'));
        t.lines()
            .filter(|l| l.starts_with('N'))
            .map(|l| {
                let p = l.find('P').unwrap();
                let n = l[1..l.find(['A', 'P']).unwrap()].parse().unwrap();
                (n, l[p + 1..].parse().unwrap())
            })
            .collect()
    };
    let prm = tape(params);
    let get = |no: u32| prm.iter().find(|(n, _)| *n == no).map(|p| p.1);
    let (r, lo, hi, mag, step) = (
        get(3620).unwrap(),
        get(3621).unwrap(),
        get(3622).unwrap(),
        get(3623).unwrap() as f64,
        get(3624).unwrap() as f64 * 1e-3,
    );
    let data = tape(pitch);
    let val = |no: i64| {
        data.iter()
            .find(|(n, _)| *n as i64 == 10000 + no)
            .unwrap()
            .1 as f64
            * mag
    };
    // Correction at point k: sum of the sections' increments from the reference.
    let corr = |k: i64| -> f64 {
        if k >= r {
            (r + 1..=k).map(val).sum()
        } else {
            -(k + 1..=r).map(val).sum::<f64>()
        }
    };
    let ref_mm = 0.0;
    let pts = (lo..=hi).map(|k| ref_mm + (k - r) as f64 * step).collect();
    let err = (lo..=hi).map(|k| -corr(k)).collect();
    (pts, err, get(1851).unwrap_or(0) as f64)
}

/// HEIDENHAIN `.COM`: `NR AXISPOS X [BACKLASH]`, values mm.
fn read_heidenhain(text: &str) -> (Vec<f64>, Vec<f64>, Option<Vec<f64>>) {
    let mut l = text.lines();
    assert_eq!(l.next(), Some("BEGIN X.COM MM"));
    let head: Vec<&str> = l.next().unwrap().split_whitespace().collect();
    assert_eq!(&head[..3], ["NR", "AXISPOS", "X"]);
    let (mut p, mut e, mut b) = (vec![], vec![], vec![]);
    for (i, row) in l.take_while(|r| *r != "[END]").enumerate() {
        let f: Vec<f64> = row.split_whitespace().map(|x| x.parse().unwrap()).collect();
        assert_eq!(f[0] as usize, i);
        p.push(f[1]);
        e.push(f[2] * 1e3);
        if head.len() == 4 {
            b.push(f[3] * 1e3);
        }
    }
    assert!(text.trim_end().ends_with("[END]"));
    (p, e, (head.len() == 4).then_some(b))
}

/// LinuxCNC type-1 comp file: `nominal forward_trim reverse_trim`, mm.
fn read_linuxcnc(text: &str) -> [Vec<f64>; 3] {
    let mut out = [vec![], vec![], vec![]];
    for row in text.lines() {
        let f: Vec<f64> = row.split_whitespace().map(|x| x.parse().unwrap()).collect();
        assert_eq!(f.len(), 3, "{row}");
        out[0].push(f[0]);
        out[1].push(f[1] * 1e3);
        out[2].push(f[2] * 1e3);
    }
    out
}

/// The known error relative to the reference (0 mm), µm.
fn truth(x: f64) -> f64 {
    0.02 * x + 6.0 * (x / 80.0).sin()
}

fn check_curve(name: &str, pts: &[f64], err: &[f64], tol: f64, shift: f64) {
    assert!(pts.len() >= 20, "{name}: {} points", pts.len());
    for (p, e) in pts.iter().zip(err) {
        // Between targets the table interpolates the measured means linearly, so it is
        // compared with the truth interpolated the same way at the run's targets.
        let xs: Vec<f64> = (0..11)
            .map(|i| i as f64 * 50.0 + if i % 2 == 1 { 1.7 } else { 0.0 })
            .collect();
        let ys: Vec<f64> = xs.iter().map(|&x| truth(x)).collect();
        let want = interpolate(&xs, &ys, *p) - shift;
        assert!((e - want).abs() < tol, "{name} at {p} mm: {e} vs {want}");
    }
}

/// The run with the file's curve removed, evaluated here: (E before, E after).
fn predicted_e(d: &PositioningData, pts: &[f64], up: &[f64], down: &[f64]) -> (f64, f64) {
    let mut c = d.clone();
    for r in &mut c.readings {
        let ys = if r.direction == Direction::Up {
            up
        } else {
            down
        };
        r.deviation_um -= interpolate(pts, ys, r.target_mm);
    }
    (evaluate(d).axis.e.unwrap(), evaluate(&c).axis.e.unwrap())
}

fn assert_verification(
    name: &str,
    d: &PositioningData,
    t: &CompensationTable,
    pts: &[f64],
    up: &[f64],
    down: &[f64],
) {
    let v = verify(d, t);
    let (before, after) = predicted_e(d, pts, up, down);
    assert!((v.before.e.unwrap() - before).abs() < 1e-9);
    assert!(
        (v.after.e.unwrap() - after).abs() < 1e-3,
        "{name}: {} vs {after}",
        v.after.e.unwrap()
    );
    assert!(after < 0.25 * before, "{name}: E {before} → {after}");
}

#[test]
fn sinumerik_table_reads_back_as_the_error_curve() {
    let (_, d) = run(1);
    let t = build(&d, &opts(Dialect::Sinumerik, Mode::Backlash)).unwrap();
    let (pts, err) = read_sinumerik(file(&t, "EEC.INI"));
    // Error sign (808D manual): a positive value moves the axis negative, so an axis that
    // runs long (+20 µm/m) gets increasing positive values.
    assert!(err[err.len() - 1] > 5.0);
    check_curve("sinumerik", &pts, &err, 0.5, truth(0.0));
    let b = t.backlash_um.unwrap();
    assert!((b - 5.0).abs() < 0.3, "backlash {b}");
    assert!(t.notes.iter().any(|n| n.contains("MD32450")));
    assert!(t.notes.iter().any(|n| n.contains("MD38000")));
    let down: Vec<f64> = err.iter().map(|e| e + b).collect();
    assert_verification("sinumerik", &d, &t, &pts, &err, &down);
}

#[test]
fn fanuc_tapes_read_back_as_the_error_curve() {
    let (_, d) = run(2);
    let t = build(&d, &opts(Dialect::Fanuc, Mode::Backlash)).unwrap();
    let (pts, err, b) = read_fanuc(file(&t, "PARAM.TXT"), file(&t, "PITCH.TXT"));
    // Integer µm increments: the reconstructed curve carries their rounding.
    check_curve("fanuc", &pts, &err, 0.5 * pts.len() as f64, truth(0.0));
    assert!((b - 5.0).abs() <= 1.0, "backlash {b}");
    for (a, e) in err.iter().zip(&t.error_up_um) {
        assert!(
            (a - e).abs() < 1e-9,
            "the file and the verified table disagree"
        );
    }
    let down: Vec<f64> = err.iter().map(|e| e + b).collect();
    assert_verification("fanuc", &d, &t, &pts, &err, &down);
}

#[test]
fn fanuc_magnification_grows_with_steep_errors() {
    let (_, mut d) = run(3);
    for r in &mut d.readings {
        r.deviation_um += 3.0 * r.target_mm; // 3 mm/m: 150 µm per 50 mm section
    }
    let mut o = opts(Dialect::Fanuc, Mode::Mean);
    o.spacing_mm = Some(50.0);
    let t = build(&d, &o).unwrap();
    let p = file(&t, "PARAM.TXT");
    let mag: i64 = p
        .lines()
        .find(|l| l.starts_with("N03623"))
        .unwrap()
        .split('P')
        .nth(1)
        .unwrap()
        .parse()
        .unwrap();
    assert!(mag >= 2, "{p}");
    let pitch = file(&t, "PITCH.TXT");
    for l in pitch.lines().filter(|l| l.starts_with('N')) {
        let v: i64 = l.split('P').nth(1).unwrap().parse().unwrap();
        assert!(v.abs() <= 127, "{l}");
    }
}

#[test]
fn heidenhain_table_starts_at_zero_on_a_power_of_two_grid() {
    let (_, d) = run(4);
    let t = build(&d, &opts(Dialect::Heidenhain, Mode::Bidirectional)).unwrap();
    let (pts, up, down) = read_heidenhain(file(&t, "X.COM"));
    let down = down.expect("BACKLASH column in bidirectional mode");
    assert_eq!(up[0], 0.0, "0 at the datum");
    let step_units = ((pts[1] - pts[0]) * 1e4).round() as u64;
    assert!(
        step_units.is_power_of_two() && step_units <= 250_000,
        "{step_units}"
    );
    check_curve("heidenhain", &pts, &up, 0.5, truth(pts[0]));
    let rev: Vec<f64> = down.iter().zip(&up).map(|(a, b)| a - b).collect();
    assert!(rev.iter().all(|r| (r - 5.0).abs() < 0.6), "{rev:?}");
    assert_verification("heidenhain", &d, &t, &pts, &up, &down);
}

#[test]
fn linuxcnc_comp_file_reads_back_and_carries_the_backlash() {
    let (_, d) = run(5);
    let t = build(&d, &opts(Dialect::LinuxCnc, Mode::Backlash)).unwrap();
    let [pts, fwd, rev] = read_linuxcnc(file(&t, "x_comp.txt"));
    check_curve("linuxcnc", &pts, &fwd, 0.5, truth(0.0));
    assert!(fwd.iter().zip(&rev).all(|(f, r)| (r - f - 5.0).abs() < 0.3));
    let ini = file(&t, "joint.ini");
    assert!(ini.contains("[JOINT_0]\nCOMP_FILE = x_comp.txt\nCOMP_FILE_TYPE = 1"));
    assert_verification("linuxcnc", &d, &t, &pts, &fwd, &rev);
}

#[test]
fn limits_and_unsupported_modes_say_what_to_do() {
    let (_, d) = run(6);
    let mut o = opts(Dialect::LinuxCnc, Mode::Mean);
    o.spacing_mm = Some(1.0);
    let e = build(&d, &o).unwrap_err();
    assert!(
        matches!(e, CompensationError::Limit { .. }) && e.to_string().contains("--spacing"),
        "{e}"
    );
    for dialect in [Dialect::Fanuc, Dialect::Sinumerik] {
        let e = build(&d, &opts(dialect, Mode::Bidirectional)).unwrap_err();
        assert!(e.to_string().contains("--backlash"), "{e}");
    }
    let one_way = PositioningData {
        readings: d
            .readings
            .iter()
            .filter(|r| r.direction == Direction::Up)
            .copied()
            .collect(),
        ..d.clone()
    };
    let e = build(&one_way, &opts(Dialect::LinuxCnc, Mode::Mean)).unwrap_err();
    assert!(e.to_string().contains("bidirectionally"), "{e}");
    assert!("okuma".parse::<Dialect>().unwrap_err().contains("linuxcnc"));
}
