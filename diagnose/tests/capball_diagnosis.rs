//! CapBall diagnosis against runs with hidden effects from a generator whose forward model is
//! written separately in this test (`support/capball_gen.rs`), cross-checked against
//! metrology's chain and analytic Jacobian. The sweep over ≥ 100 datasets per class is
//! `#[ignore]`d (`cargo test --release -p metrolog-diagnose --test capball_diagnosis -- --ignored --nocapture`);
//! CI runs a small sample.

#[path = "support/capball_gen.rs"]
mod capball_gen;

use capball_gen::{Class, Dataset, exact_error_um, generate, pose_on_ball, trajectory};
use diagnose::capball::{CapballDiagnosisReport, Options, diagnose};
use geometry::capball::{CapballErrors, CapballSetup, N_PARAMS, forward_um};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde_json::Value;

#[test]
fn generator_chain_matches_metrology() {
    let setup = CapballSetup::paper_default();
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    for _ in 0..20 {
        let a = rng.random_range(-110.0..10.0);
        let c = rng.random_range(0.0..360.0);
        let pose = pose_on_ball(a, c);
        // The generator's poses are metrology's poses.
        let m = setup.pose_for(a, c);
        assert!(
            (pose.x_mm - m.x_mm).abs() < 1e-9
                && (pose.y_mm - m.y_mm).abs() < 1e-9
                && (pose.z_mm - m.z_mm).abs() < 1e-9
        );
        // Forward values agree with metrology's exact chain.
        let p: [f64; 14] = std::array::from_fn(|_| rng.random_range(-80.0..80.0));
        let e = CapballErrors::from_slice(&p);
        let mine = exact_error_um(&p, &pose, None);
        let theirs = forward_um(&e.link, &e.setup, &pose);
        for k in 0..3 {
            assert!((mine[k] - theirs[k]).abs() < 1e-6, "{mine:?} vs {theirs:?}");
        }
        // Numerical derivative of this chain vs the analytic identification Jacobian.
        let j = setup.jacobian(&pose);
        for col in 0..N_PARAMS {
            let mut hi = [0.0; 14];
            let mut lo = [0.0; 14];
            hi[col] = 0.5;
            lo[col] = -0.5;
            let (eh, el) = (
                exact_error_um(&hi, &pose, None),
                exact_error_um(&lo, &pose, None),
            );
            for k in 0..3 {
                let d = eh[k] - el[k];
                assert!(
                    (d - j[(k, col)]).abs() < 1e-6,
                    "column {col} row {k}: {d} vs {}",
                    j[(k, col)]
                );
            }
        }
    }
    assert_eq!(trajectory(10, 0.0, -90.0, 2.0).len(), 10);
}

fn run_diag(d: &Dataset) -> CapballDiagnosisReport {
    let setup = CapballSetup::paper_default();
    diagnose(
        &setup,
        &d.ident,
        std::slice::from_ref(&d.validation),
        d.record.as_ref(),
        &Options::default(),
    )
    .expect("diagnosis")
    .report
}

fn names(r: &CapballDiagnosisReport) -> Vec<String> {
    r.findings
        .iter()
        .map(|f| f.effect.name().to_string())
        .collect()
}

fn num(v: &Value) -> f64 {
    v.as_f64().unwrap_or(f64::NAN)
}

/// Whether the reported parameters of the hidden effect lie within 3 standard uncertainties
/// (for an axis error: axis and harmonic right, amplitude checked only when no part of it is
/// absorbed, i.e. not for harmonic 1 of C whose co-rotating part is an eccentricity).
fn params_ok(d: &Dataset, r: &CapballDiagnosisReport, effect: &str) -> bool {
    let Some(f) = r.findings.iter().find(|f| f.effect.name() == effect) else {
        return false;
    };
    let within = |est: f64, truth: f64, u: f64| (est - truth).abs() <= 3.0 * u.max(1e-9);
    let t = &d.truth;
    match effect {
        "cyclic_drift" => {
            let Some((period, amps)) = t.cyclic else {
                return false;
            };
            let p = num(&f.params()["period_s"]);
            let up = num(&f.params_u["period_s"]);
            let ok_amp = ["x", "y", "z"].iter().enumerate().all(|(k, c)| {
                within(
                    num(&f.params()["amplitude_um"][c]),
                    amps[k].0,
                    num(&f.params_u["amplitude_um"][c]),
                )
            });
            within(p, period, up) && ok_amp
        }
        "linear_drift" => {
            let Some(rate) = t.linear_um_per_h else {
                return false;
            };
            ["x", "y", "z"].iter().enumerate().all(|(k, c)| {
                within(
                    num(&f.params()["rate_um_per_h"][c]),
                    rate[k],
                    num(&f.params_u["rate_um_per_h"][c]),
                )
            })
        }
        "sensor_gain" => {
            let Some((ch, g)) = t.gain else { return false };
            f.params()["channel"] == ["x", "y", "z"][ch]
                && within(
                    num(&f.params()["gain_pct"]),
                    100.0 * g,
                    num(&f.params_u["gain_pct"]),
                )
        }
        "axis_error" => {
            let Some(m) = t.axis else { return false };
            let same = f.params()["axis"] == m.axis.to_string()
                && num(&f.params()["harmonic"]) == m.harmonic as f64;
            if m.axis == 'C' && m.harmonic == 1 {
                return same;
            }
            same && within(
                num(&f.params()["amplitude_um"]),
                m.amplitude_um,
                num(&f.params_u["amplitude_um"]),
            )
        }
        "outliers" => num(&f.params()["count"]) >= t.outliers as f64,
        _ => false,
    }
}

#[derive(Default)]
struct Tally {
    n: usize,
    detected: usize,
    params_ok: usize,
    extra: usize,
}

fn score(d: &Dataset, r: &CapballDiagnosisReport, t: &mut Tally) {
    let found = names(r);
    t.n += 1;
    let hidden: Vec<&str> = d.truth.effects.clone();
    if hidden.iter().all(|h| found.iter().any(|f| f == h)) {
        if hidden.is_empty() {
            // For clean runs "detected" counts runs without any finding.
            if found.is_empty() {
                t.detected += 1;
            }
        } else {
            t.detected += 1;
        }
    }
    if hidden.iter().all(|h| params_ok(d, r, h)) && !hidden.is_empty() {
        t.params_ok += 1;
    }
    if found.iter().any(|f| !hidden.contains(&f.as_str())) {
        t.extra += 1;
    }
}

fn sweep(per_class: usize, seed0: u64) -> Vec<(Class, bool, Tally)> {
    let mut out = Vec::new();
    // CAPBALL_CLASS=<name as in the table> sweeps one class only.
    let only = std::env::var("CAPBALL_CLASS").ok();
    for class in Class::ALL {
        if only.as_deref().is_some_and(|c| c != class.name()) {
            continue;
        }
        for record in [false, true] {
            if record && class != Class::Cyclic {
                continue;
            }
            let mut t = Tally::default();
            for i in 0..per_class {
                let d = generate(class, seed0 + 1000 * i as u64 + class as u64, record);
                let r = run_diag(&d);
                let before = (t.detected, t.params_ok, t.extra);
                score(&d, &r, &mut t);
                if std::env::var("CAPBALL_VERBOSE").is_ok()
                    && (
                        t.detected,
                        t.params_ok + usize::from(d.truth.effects.is_empty()),
                        t.extra,
                    ) != (before.0 + 1, before.1 + 1, before.2)
                {
                    println!(
                        "--- {} seed {} truth {:?}",
                        class.name(),
                        seed0 + 1000 * i as u64 + class as u64,
                        d.truth
                    );
                    for f in &r.findings {
                        println!(
                            "    {} {} sig {:.1} val {:.3}->{:.3} | {}",
                            f.effect.name(),
                            serde_json::to_string(&f.params()).unwrap_or_default(),
                            f.significance,
                            f.heldout_rms_before_um,
                            f.heldout_rms_after_um,
                            serde_json::to_string(&f.params_u).unwrap_or_default()
                        );
                    }
                }
            }
            out.push((class, record, t));
        }
    }
    out
}

fn print_table(rows: &[(Class, bool, Tally)]) {
    println!(
        "| class | drift record | datasets | named | params within 3u | other effects named |"
    );
    println!("|---|---|---|---|---|---|");
    for (c, rec, t) in rows {
        let pct = |k: usize| 100.0 * k as f64 / t.n.max(1) as f64;
        println!(
            "| {} | {} | {} | {:.0} % | {:.0} % | {:.1} % |",
            c.name(),
            if *rec { "yes" } else { "no" },
            t.n,
            pct(t.detected),
            pct(t.params_ok),
            pct(t.extra)
        );
    }
}

#[test]
fn clean_runs_give_no_finding() {
    for seed in 0..2 {
        let d = generate(Class::None, 100 + seed, false);
        let r = run_diag(&d);
        assert!(r.findings.is_empty(), "seed {seed}: {:?}", r.findings);
        assert!(r.baseline.rms_um < 0.5);
    }
}

#[test]
fn paper_cooling_cycle_is_named_with_its_gain() {
    // Paper 001's pattern: a 25-min cooling cycle, 2/2/6 µm peak to valley; with a drift record.
    let mut d = generate(Class::Cyclic, 42, true);
    let (p, mut a) = d.truth.cyclic.expect("cyclic");
    a[0].0 = 1.0;
    a[1].0 = 1.0;
    a[2].0 = 3.0;
    d.truth.cyclic = Some((1500.0, a));
    let _ = p;
    let d = regenerate_with(d, 42);
    let r = run_diag(&d);
    let f = r
        .findings
        .iter()
        .find(|f| f.effect.name() == "cyclic_drift")
        .expect("cyclic drift named");
    assert!(f.heldout_rms_after_um < f.heldout_rms_before_um);
    assert!(
        (num(&f.params()["period_s"]) - 1500.0).abs() < 3.0 * num(&f.params_u["period_s"]).max(1.0)
    );
    assert!(params_ok(&d, &r, "cyclic_drift"), "{:?}", f);
}

/// The same dataset again with the (edited) truth: readings recomputed, noise redrawn.
fn regenerate_with(d: Dataset, seed: u64) -> Dataset {
    use rand_distr::{Distribution, Normal};
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let noise = Normal::new(0.0, d.truth.noise_um).expect("noise");
    let mut out = d;
    for run in [&mut out.ident, &mut out.validation] {
        for i in 0..run.poses.len() {
            run.e_um[i] = out
                .truth
                .reading(&run.poses[i], run.time_s[i])
                .map(|v| v + noise.sample(&mut rng));
        }
    }
    if let Some(rec) = out.record.as_mut() {
        let p = pose_on_ball(0.0, 0.0);
        for i in 0..rec.time_s.len() {
            rec.e_um[i] = out
                .truth
                .reading(&p, rec.time_s[i])
                .map(|v| v + noise.sample(&mut rng));
        }
    }
    out
}

#[test]
fn c_axial_once_per_rev_is_absorbed() {
    // A 2 µm axial once-per-revolution motion of C: the same as a tilt of the C axis line, so
    // the diagnosis must not name it, and must say the data cannot show it.
    let mut d = generate(Class::None, 77, false);
    d.truth.axis = Some(capball_gen::AxisMotion {
        axis: 'C',
        harmonic: 1,
        amplitude_um: 2.0,
        phase: 0.4,
        direction: nalgebra::Vector3::z(),
        axial: true,
    });
    let d = regenerate_with(d, 77);
    let r = run_diag(&d);
    assert!(r.findings.is_empty(), "{:?}", r.findings);
    let a = r
        .absorbed
        .iter()
        .find(|a| a.effect.name() == "axis_error" && a.detail == "C harmonic 1")
        .expect("C harmonic 1 listed as absorbed");
    assert!(a.invisible >= 2, "{a:?}");
    assert!(
        a.taken_by
            .iter()
            .any(|p| p.starts_with("EA0C") || p.starts_with("EB0C")),
        "{a:?}"
    );
}

#[test]
fn small_sample_per_class() {
    let rows = sweep(1, 9000);
    print_table(&rows);
    for (c, _, t) in &rows {
        assert!(t.detected >= 1, "class {} never detected", c.name());
    }
}

#[test]
#[ignore = "sweep: ≥ 100 datasets per class, run with --release -- --ignored --nocapture"]
fn sweep_per_class() {
    let n = std::env::var("CAPBALL_SWEEP_N")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(100);
    let rows = sweep(n, 1);
    print_table(&rows);
    // The clean class's false alarms (absent when CAPBALL_CLASS picks another class).
    if let Some(none) = rows.iter().find(|r| r.0 == Class::None).map(|r| &r.2) {
        assert!(
            none.extra as f64 <= 0.02 * none.n as f64,
            "false alarms {}",
            none.extra
        );
    }
}
