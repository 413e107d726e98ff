//! Paper 001: the multi-output adaptive Monte Carlo of the CapBall link and setup errors, and
//! its central finding — a drift treated statistically (ISO/TR 230-9, independent per point)
//! gives coverage intervals too narrow for the spread of repeated identifications on a machine
//! whose measuring loop drifts cyclically, while the cyclic model's intervals cover it.
//!
//! Independent expectations: for Gaussian per-point noise the identified parameters are exactly
//! Gaussian with covariance J⁺·Σ·J⁺ᵀ (a closed form the Monte Carlo does not use), and the
//! repeated identifications are simulated directly from the drift's time function.

use nalgebra::DMatrix;
use uncertainty::capball::{
    CapballSources, CyclicDrift, DriftModel, MeasuredCapball, Paper001Case, coverage_check,
    drift_range_um, parse_drift_record, simulate_identifications, source_widths,
};
use uncertainty::mc::{self, McOptions};

fn quick() -> McOptions {
    McOptions {
        fixed_trials: Some(20_000),
        seed: 4,
        ..McOptions::default()
    }
}

#[test]
fn gaussian_sources_match_the_closed_form_covariance() {
    let case = Paper001Case::paper001();
    let sources = CapballSources {
        drift: DriftModel::None,
        ..case.cyclic_sources()
    };
    let model = case.monte_carlo_model(&case.p_true, &sources).unwrap();
    let r = mc::run(&model, &quick(), None).unwrap();
    // u(p_j)² = Σ_r (J⁺)_jr² σ_r².
    let pinv = model.pseudo_inverse();
    for (j, o) in r.outputs.iter().enumerate() {
        let var: f64 = (0..pinv.ncols())
            .map(|c| {
                let s2 = case.sensor_u_um[c % 3].powi(2) + case.frame_u_um[c % 3].powi(2);
                pinv[(j, c)].powi(2) * s2
            })
            .sum();
        let u = var.sqrt();
        // 20 000 trials: relative standard error of a standard deviation ≈ 0.5 %.
        assert!(
            (o.standard_uncertainty / u - 1.0).abs() < 0.025,
            "{}: MC {} vs closed form {u}",
            o.name,
            o.standard_uncertainty
        );
        assert!((o.estimate - case.p_true[j]).abs() < 4.0 * u / (20_000f64).sqrt());
    }
}

#[test]
fn paper001_jacobian_identifies_all_parameters() {
    let case = Paper001Case::paper001();
    let j: &DMatrix<f64> = &case.jacobian;
    assert_eq!((j.nrows(), j.ncols()), (2421, 14));
    let sv = j.clone().svd(false, false).singular_values;
    let cond = sv.max() / sv.min();
    assert!(cond < 1e4, "condition number {cond}");
    // Noise-free identification returns the true parameters.
    let p = nalgebra::DVector::from_column_slice(&case.p_true);
    let de = j * &p;
    let pinv = uncertainty::capball::pseudo_inverse(j).unwrap();
    let back = pinv * de;
    for (a, b) in back.iter().zip(&case.p_true) {
        assert!((a - b).abs() < 1e-9);
    }
}

#[test]
fn statistical_drift_is_too_narrow_cyclic_drift_covers_repeated_identifications() {
    let case = Paper001Case::paper001();
    // 200 back-to-back identifications (the paper had 10; more runs measure the rate).
    let runs = simulate_identifications(
        &case.jacobian,
        &case.p_true,
        &case.times_s,
        case.sensor_u_um,
        case.frame_u_um,
        &case.drift,
        0.0,
        case.run_period_s,
        200,
        77,
    )
    .unwrap();
    let n = runs.len() as f64;
    let p_mean: Vec<f64> = (0..14)
        .map(|j| runs.iter().map(|r| r[j]).sum::<f64>() / n)
        .collect();
    let opts = McOptions {
        fixed_trials: Some(40_000),
        seed: 9,
        ..McOptions::default()
    };
    let stat = mc::run(
        &case
            .monte_carlo_model(&p_mean, &case.statistical_sources())
            .unwrap(),
        &opts,
        None,
    )
    .unwrap();
    let cyc = mc::run(
        &case
            .monte_carlo_model(&p_mean, &case.cyclic_sources())
            .unwrap(),
        &opts,
        None,
    )
    .unwrap();
    let c_stat = coverage_check(&stat, &runs);
    let c_cyc = coverage_check(&cyc, &runs);
    for j in 0..14 {
        eprintln!(
            "{:<10} u_stat {:>7.3}  u_cyc {:>7.3}  spread of runs {:>7.3}  coverage stat {:>5.3} cyc {:>5.3}",
            case.names[j],
            stat.outputs[j].standard_uncertainty,
            cyc.outputs[j].standard_uncertainty,
            c_stat.spread_ratio[j] * stat.outputs[j].standard_uncertainty,
            c_stat.per_parameter[j],
            c_cyc.per_parameter[j]
        );
    }
    eprintln!(
        "statistical: overall {:.3} per {:?}",
        c_stat.overall, c_stat.per_parameter
    );
    eprintln!(
        "cyclic:      overall {:.3} per {:?}",
        c_cyc.overall, c_cyc.per_parameter
    );
    // The statistical model's 95 % intervals miss most repeated identifications.
    assert!(
        c_stat.overall < 0.6,
        "statistical coverage {}",
        c_stat.overall
    );
    // The cyclic model's cover them at about the nominal rate: with 200 runs the binomial
    // standard error of a 95 % rate is 1.5 %, and the run phases are not perfectly uniform.
    assert!(
        c_cyc.overall > 0.90 && c_cyc.overall < 0.99,
        "cyclic coverage {}",
        c_cyc.overall
    );
    for (j, r) in c_cyc.per_parameter.iter().enumerate() {
        assert!(*r > 0.85, "{}: cyclic coverage {r}", case.names[j]);
    }
    // The spread of the runs is several times the statistical model's u.
    let median_ratio = {
        let mut v = c_stat.spread_ratio.clone();
        v.sort_by(f64::total_cmp);
        v[7]
    };
    assert!(median_ratio > 2.0, "spread / u_stat = {median_ratio}");
}

#[test]
fn drift_dominates_the_interval_widths_which_do_not_add_in_quadrature() {
    // Paper 001 Table 5: 95 % coverage-interval widths with one source at a time. The drift is
    // responsible for most of the total, and the quadratic sum of the three widths is *below*
    // the total for every parameter (the paper's own observation): a cyclic drift's
    // distribution is arcsine-like, its 95 % half-width is nearly its amplitude, and it adds to
    // the other sources more nearly linearly than in quadrature.
    let case = Paper001Case::paper001();
    let build = |s: &CapballSources| case.monte_carlo_model(&case.p_true, s);
    let (total, w) = source_widths(&build, &case.cyclic_sources(), &quick(), None).unwrap();
    eprintln!(
        "{:<10} {:>8} {:>8} {:>8} {:>8} {:>8}",
        "parameter", "W_total", "W_drift", "W_sensor", "W_frame", "W_quad"
    );
    for r in &w {
        eprintln!(
            "{:<10} {:>8.3} {:>8.3} {:>8.3} {:>8.3} {:>8.3}",
            r.name, r.total, r.drift, r.sensor, r.frame, r.quadrature
        );
    }
    let mut dominated = 0;
    let mut below = 0;
    for (j, r) in w.iter().enumerate() {
        // Where the other sources matter (their width ≥ 10 % of the drift's), the quadratic sum
        // is clearly below the total; where the drift is nearly all of it, total and quadratic
        // sum coincide to the Monte Carlo's accuracy (20 000 trials: about 1 % per width).
        if r.sensor.hypot(r.frame) >= 0.1 * r.drift {
            assert!(r.quadrature < r.total, "{}: {r:?}", r.name);
            below += 1;
        } else {
            assert!(
                (r.quadrature / r.total - 1.0).abs() < 0.025,
                "{}: {r:?}",
                r.name
            );
        }
        // ... and no wider than the plain sum of the widths.
        assert!(r.total <= r.drift + r.sensor + r.frame, "{}: {r:?}", r.name);
        if r.drift > r.sensor.max(r.frame) {
            dominated += 1;
        }
        let o = &total.outputs[j];
        assert!((o.symmetric_interval[1] - o.symmetric_interval[0] - r.total).abs() < 1e-12);
    }
    assert!(
        dominated >= 12,
        "drift dominates {dominated} of 14 parameters"
    );
    assert!(
        below >= 7,
        "quadratic sum below the total for {below} parameters"
    );
}

#[test]
fn sine_drift_plus_noise_interval_matches_the_arcsine_convolution() {
    // Independent expectation: with a one-harmonic drift a·sin(ωt) and Gaussian per-point noise,
    // each identified parameter is p̂ + R·cos(φ − θ) + N(0, σ²) with φ uniform, R the length of
    // (J⁺·a sin ωt, J⁺·a cos ωt) and σ² = Σ (J⁺)² σ_r². Its 97.5 % point solves
    // (1/π)∫₀^π Φ((y − R cos θ)/σ) dθ = 0.975, computed here by quadrature; J⁺ is formed here
    // from the normal equations, not by the library's SVD.
    use statrs::distribution::{ContinuousCDF, Normal};
    let case = Paper001Case::paper001();
    let period = 1500.0;
    let sources = CapballSources {
        drift: DriftModel::Cyclic(CyclicDrift::sine(period, [2.0, 2.0, 6.0])),
        ..case.cyclic_sources()
    };
    let model = case.monte_carlo_model(&case.p_true, &sources).unwrap();
    let opts = McOptions {
        fixed_trials: Some(200_000),
        seed: 8,
        ..McOptions::default()
    };
    let r = mc::run(&model.with_reduced_noise(), &opts, None).unwrap();
    let j = &case.jacobian;
    let pinv = (j.transpose() * j).try_inverse().unwrap() * j.transpose();
    let w = std::f64::consts::TAU / period;
    let n = case.times_s.len();
    let (mut ds, mut dc) = (vec![0.0; 3 * n], vec![0.0; 3 * n]);
    for (i, t) in case.times_s.iter().enumerate() {
        for (a, amp) in [1.0, 1.0, 3.0].iter().enumerate() {
            ds[3 * i + a] = amp * (w * t).sin();
            dc[3 * i + a] = amp * (w * t).cos();
        }
    }
    let ps = &pinv * nalgebra::DVector::from_vec(ds);
    let pc = &pinv * nalgebra::DVector::from_vec(dc);
    let std_normal = Normal::new(0.0, 1.0).unwrap();
    for (k, o) in r.outputs.iter().enumerate() {
        let rr = ps[k].hypot(pc[k]);
        let sigma = (0..pinv.ncols())
            .map(|c| pinv[(k, c)].powi(2) * (0.1f64.powi(2) + 0.3f64.powi(2)))
            .sum::<f64>()
            .sqrt();
        let cdf = |y: f64| {
            let m = 4000;
            (0..m)
                .map(|i| {
                    let th = std::f64::consts::PI * (i as f64 + 0.5) / m as f64;
                    std_normal.cdf((y - rr * th.cos()) / sigma)
                })
                .sum::<f64>()
                / m as f64
        };
        let (mut lo, mut hi) = (0.0, rr + 10.0 * sigma);
        for _ in 0..80 {
            let mid = 0.5 * (lo + hi);
            if cdf(mid) < 0.975 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let exact_width = 2.0 * lo;
        let mc_width = o.symmetric_interval[1] - o.symmetric_interval[0];
        assert!(
            (mc_width / exact_width - 1.0).abs() < 0.01,
            "{}: MC width {mc_width}, quadrature {exact_width} (R {rr}, σ {sigma})",
            o.name
        );
    }
}

#[test]
fn adaptive_run_converges_and_is_reproducible() {
    let case = Paper001Case::paper001();
    let model = case
        .monte_carlo_model(&case.p_true, &case.cyclic_sources())
        .unwrap();
    let opts = McOptions {
        ndig: 1,
        ..McOptions::default()
    };
    let a = mc::run(&model, &opts, None).unwrap();
    assert!(a.converged && a.sequences >= 2);
    for o in &a.outputs {
        let s = o.stability.unwrap();
        assert!(
            s.iter().all(|v| *v <= o.tolerance),
            "{}: {s:?} vs {}",
            o.name,
            o.tolerance
        );
    }
    let b = mc::run(&model, &opts, None).unwrap();
    assert_eq!(a, b);
}

#[test]
fn reduced_noise_gives_the_same_distribution() {
    // Per-point noise drawn in full vs drawn in parameter space: same u and intervals to
    // Monte Carlo accuracy (20 000 trials: ~0.5 % on u, ~1 % on the endpoints' offsets).
    let case = Paper001Case::paper001();
    let full = case
        .monte_carlo_model(&case.p_true, &case.cyclic_sources())
        .unwrap();
    let reduced = full.clone().with_reduced_noise();
    let a = mc::run(&full, &quick(), None).unwrap();
    let b = mc::run(&reduced, &quick(), None).unwrap();
    for (x, y) in a.outputs.iter().zip(&b.outputs) {
        assert!(
            (x.standard_uncertainty / y.standard_uncertainty - 1.0).abs() < 0.03,
            "{}: {} vs {}",
            x.name,
            x.standard_uncertainty,
            y.standard_uncertainty
        );
        let half =
            |o: &uncertainty::McOutput| 0.5 * (o.symmetric_interval[1] - o.symmetric_interval[0]);
        assert!((half(x) / half(y) - 1.0).abs() < 0.04, "{}", x.name);
    }
}

#[test]
fn cyclic_drift_is_fitted_from_a_drift_record() {
    // Two hours at one fixed pose, one sample every 5 s, the case's cooling cycle (25 min,
    // 2/2/6 µm peak to valley) plus 0.1 µm sensor noise; written as the drift-record CSV.
    let case = Paper001Case::paper001();
    let csv = drift_record_csv(&case, 1440, 3);
    let rec = parse_drift_record(&csv).unwrap();
    let fit = CyclicDrift::fit(&rec, 3).unwrap();
    assert!(
        (fit.period_s / 1500.0 - 1.0).abs() < 0.005,
        "{}",
        fit.period_s
    );
    let ptv = fit.peak_to_valley_um();
    for (a, b) in ptv.iter().zip([2.0, 2.0, 6.0]) {
        assert!((a - b).abs() < 0.1, "{ptv:?}");
    }
    // The statistical model's E_VE is the record's own range (noise included).
    let r = drift_range_um(&rec);
    assert!((r[2] - 6.0).abs() < 0.6, "{r:?}");
    // A record shorter than one cycle is refused with a way out.
    let e = CyclicDrift::fit(&rec[..200], 3).unwrap_err().to_string();
    assert!(e.contains("full cycle") || e.contains("period"), "{e}");
    // Bad input: a clear error.
    let e = parse_drift_record("time_s,ex_um\n1,2\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("ey_um"), "{e}");
}

/// Two hours at one fixed pose (one sample every 5 s for `n` samples), the case's cooling cycle
/// (25 min, 2/2/6 µm peak to valley) plus 0.1 µm sensor noise, as the drift-record CSV.
fn drift_record_csv(case: &Paper001Case, n: usize, seed: u64) -> String {
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let noise = Normal::new(0.0, 0.1).unwrap();
    let mut csv = String::from(
        "# simulated: paper 001 case, cooling cycle 1500 s, 2/2/6 µm peak to valley, 0.1 µm noise\n\
         time_s,ex_um,ey_um,ez_um\n",
    );
    for i in 0..n {
        let t = 5.0 * i as f64;
        let d = case.drift.value_um(t + 300.0);
        csv.push_str(&format!(
            "{t},{:.4},{:.4},{:.4}\n",
            d[0] + noise.sample(&mut rng),
            d[1] + noise.sample(&mut rng),
            d[2] + noise.sample(&mut rng)
        ));
    }
    csv
}

/// A measured dataset as docs/datasets.md describes it: `n_runs` back-to-back runs of the
/// 807-pose trajectory on a machine whose loop drifts cyclically (the case's drift), sensor and
/// frame noise per point; the first `warmup` runs carry an extra shift of EC0Y (the joints
/// still warming) that the analysis must leave out.
fn simulated_runs(
    case: &Paper001Case,
    n_runs: u32,
    warmup: u32,
    seed: u64,
) -> Vec<geometry::capball::CapballRecord> {
    use geometry::capball::{CapballErrors, CapballRecord, CapballSetup, TrajectorySpec};
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};
    let setup = CapballSetup::paper_default();
    let poses = setup.trajectory(&TrajectorySpec::default());
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let n = Normal::new(0.0, (0.1f64.powi(2) + 0.3f64.powi(2)).sqrt()).unwrap();
    let mut records = Vec::new();
    for run in 1..=n_runs {
        let mut p = case.p_true.clone();
        if run <= warmup {
            p[0] += 3.0 * (warmup + 1 - run) as f64;
        }
        let truth = CapballErrors::from_slice(&p);
        let t0 = (run - 1) as f64 * case.run_period_s;
        for (i, pose) in poses.iter().enumerate() {
            let t = case.times_s[i];
            let e = setup.volumetric_error_um(&truth, pose);
            let d = case.drift.value_um(t0 + t);
            records.push(CapballRecord {
                run,
                pose_index: i as u32 + 1,
                time_s: Some(t),
                pose: *pose,
                e_um: [
                    e[0] + d[0] + n.sample(&mut rng),
                    e[1] + d[1] + n.sample(&mut rng),
                    e[2] + d[2] + n.sample(&mut rng),
                ],
            });
        }
    }
    records
}

/// `cargo test -p metrolog-uncertainty --test uncertainty_capball -- --ignored` regenerates the
/// example files of `metrolog identify capball --uncertainty mc` (README).
#[test]
#[ignore = "writes examples/budgets/capball_runs.csv and capball_drift_record.csv"]
fn write_capball_mc_examples() {
    let case = Paper001Case::paper001();
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/../examples/budgets");
    let runs = simulated_runs(&case, 6, 2, 11);
    let text = format!(
        "# simulated: paper 001 case, 6 back-to-back runs (18 min apart), runs 1-2 warm-up\n{}",
        geometry::capball::write_dataset(&runs)
    );
    std::fs::write(format!("{dir}/capball_runs.csv"), text).unwrap();
    std::fs::write(
        format!("{dir}/capball_drift_record.csv"),
        drift_record_csv(&case, 1440, 3),
    )
    .unwrap();
}

#[test]
fn measured_runs_give_the_monte_carlo_and_the_coverage_check() {
    let case = Paper001Case::paper001();
    let setup = geometry::capball::CapballSetup::paper_default();
    let records = simulated_runs(&case, 8, 3, 5);
    let m = MeasuredCapball::from_records(&setup.machine, &records, 3).unwrap();
    assert_eq!(m.warmup, vec![1, 2, 3]);
    assert_eq!(m.runs.len(), 5);
    // The warm-up shift is out of the centre value.
    assert!((m.p_hat[0] - case.p_true[0]).abs() < 3.0, "{}", m.p_hat[0]);
    let sources = CapballSources {
        sensor_u_um: case.sensor_u_um,
        frame_u_um: case.frame_u_um,
        drift: DriftModel::Cyclic(case.drift.clone()),
    };
    let model = m.model(&sources).unwrap().with_reduced_noise();
    let r = mc::run(&model, &quick(), None).unwrap();
    let c = coverage_check(&r, &m.run_params());
    assert!(c.overall > 0.8, "{c:?}");
    // Statistical model from the same drift's range: narrower, misses more runs.
    let stat = CapballSources {
        drift: DriftModel::statistical_from_range(case.drift.peak_to_valley_um()),
        ..sources
    };
    let rs = mc::run(
        &m.model(&stat).unwrap().with_reduced_noise(),
        &quick(),
        None,
    )
    .unwrap();
    let cs = coverage_check(&rs, &m.run_params());
    assert!(cs.overall < c.overall, "{cs:?} vs {c:?}");
    // Too many warm-up runs: a clear error.
    let e = MeasuredCapball::from_records(&setup.machine, &records, 8).unwrap_err();
    assert!(e.to_string().contains("leave none"), "{e}");
}
