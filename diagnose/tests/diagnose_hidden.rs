//! Hidden effects, harder (issue 11): a generator with random parameters from realistic
//! ranges for every effect of the vocabulary (`docs/datasets.md`), combinations of two,
//! ISO-minimum runs (5 targets × 5 cycles, with and without times), correlated and
//! heavy-tailed noise, aliasing traps and an erratic reference.
//!
//! The forward model is written here, independently of the analysis code: it does not use
//! `AxisModel` or `simulate`, only the definitions of `docs/datasets.md` (signs included).
//!
//! Ranges (σ = white reading noise, 0.3–3 µm; a laser-triangulation reference is noisier
//! than an interferometer): targets 5–15 over 200–1000 mm, cycles 5–15, 10–40 s per reading;
//! drifts 3–6 σ over the run; warm-up 3–6 σ with τ = 0.1–0.5 of the run; cyclic 2.5–5 σ with a
//! period of 5–40 min (≤ run/2, outside the alias bands of the cycle length: there no data can
//! tell it from the baseline); thermal 8–30 µm/m by the end of the run (≥ 3 σ at the end of the
//! axis); one target 3–6× noisier; 1–4 outliers of 8–15 σ; a step of 3–8 σ between 20 and 80 %
//! of the run; a reversal change of 3–8 σ; cycle offsets with a spread of 2–5 σ. Correlated
//! noise: AR(1), ρ = 0.5–0.7. Heavy tails: Student t, 3–5 degrees of freedom. Aliasing trap:
//! 3–5 targets, 1.5–4 min per reading, a pause at each turn-around, no effect. Erratic
//! reference: the reference jumps by 30–300 σ at random moments (3–10 % of readings) and stays.
//!
//! CI runs a few datasets per class; the full table (≥ 200 per class):
//! `cargo test --release -p metrolog-diagnose --test diagnose_hidden -- --ignored --nocapture`
//! (`CLASS=` one class, `PER_CLASS=` the count, `SHOW_MISSES=1` the misses and extra names,
//! `SHOW_PARAMS=1` the parameters outside 2 u). Its columns: detection (every hidden effect
//! named; for a no-effect class, no finding); the same counting an effect the report names as
//! one the data cannot tell from a named one (`Finding::alternatives`); runs with such an
//! alternative; runs naming an effect not hidden, and of those the ones naming a machine
//! cause (not a step, offsets per cycle, outliers or `unexplained`, which point at the
//! measuring set-up first); hidden parameters within 2 standard uncertainties; the runs whose
//! hidden mean effects an oracle knowing their shapes detects 95 % of the time at a
//! false-alarm level of 0.001 (`oracle_lambdas`: the yardstick for "as well as the data
//! allow", a warm-up counted by its curvature alone), and the detection among those runs.

use diagnose::axis::{Options, diagnose};
use positioning::axis_model::Direction;
use positioning::positioning_data::{PositioningData, Reading};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal, StudentT};
use rayon::prelude::*;

/// Classes: (name, effects expected to be named). An empty list is a no-effect class.
const CLASSES: [(&str, &[&str]); 24] = [
    ("none", &[]),
    ("none_iso_min", &[]),
    ("none_iso_min_no_times", &[]),
    ("correlated_noise", &[]),
    ("heavy_tailed_noise", &[]),
    ("alias_trap", &[]),
    ("linear_drift", &["linear_drift"]),
    ("exponential_warmup", &["exponential_warmup"]),
    ("cyclic_drift", &["cyclic_drift"]),
    ("thermal_expansion", &["thermal_expansion"]),
    ("local_anomaly", &["local_anomaly"]),
    ("outliers", &["outliers"]),
    ("step", &["step"]),
    ("reversal_drift", &["reversal_drift"]),
    ("cycle_offsets", &["cycle_offsets"]),
    ("erratic_reference", &["unexplained"]),
    ("warmup+cyclic", &["exponential_warmup", "cyclic_drift"]),
    ("step+linear", &["step", "linear_drift"]),
    ("reversal+thermal", &["reversal_drift", "thermal_expansion"]),
    ("iso_min_warmup", &["exponential_warmup"]),
    ("iso_min_warmup_no_times", &["exponential_warmup"]),
    ("iso_min_step", &["step"]),
    ("iso_min_reversal_drift", &["reversal_drift"]),
    ("iso_min_cycle_offsets", &["cycle_offsets"]),
];

/// The true value of a parameter a class hides: (effect, parameter, value).
type Truth = Vec<(&'static str, &'static str, f64)>;

/// One reading slot of a run: cycle (0-based), +1/−1 direction, target (0-based), time.
struct Slot {
    cycle: usize,
    up: bool,
    target: usize,
    t: f64,
}

/// An ISO 230-2 schedule: up pass then down pass, `dt` per reading with ±10 % jitter, and a
/// `pause` at each turn-around.
fn schedule(rng: &mut ChaCha8Rng, m: usize, n: usize, dt: f64, pause: f64) -> Vec<Slot> {
    let mut out = Vec::new();
    let mut t = 0.0;
    for c in 0..n {
        for up in [true, false] {
            for k in 0..m {
                let target = if up { k } else { m - 1 - k };
                out.push(Slot {
                    cycle: c,
                    up,
                    target,
                    t,
                });
                t += dt * rng.random_range(0.9..1.1);
            }
            t += pause;
        }
    }
    out
}

/// Is `period` within half a beat over the run of a harmonic of the cycle length? (Then no
/// data set can tell a periodic effect from the per-target, per-direction terms.)
fn aliased(period: f64, cycle: f64, duration: f64) -> bool {
    let (f, fc) = (1.0 / period, 1.0 / cycle);
    let k = (f / fc).round();
    k >= 1.0 && (f - k * fc).abs() < 0.75 / duration
}

/// What an oracle knows of a run: the white-noise σ and each hidden mean effect's
/// contribution to every reading (noise-free, in µm), by effect.
struct Oracle {
    sigma: f64,
    signals: Vec<(String, Vec<f64>)>,
    /// A scale change's time shape g(t) at every reading: the same drift common to every
    /// target is what a scale change must be told from.
    scale_shape: Option<Vec<f64>>,
}

/// A random run of class `class`, what it hides, and what an oracle knows of it.
fn random_case(seed: u64, class: &str) -> (PositioningData, Truth, Oracle) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let iso_min = class.starts_with("iso_min") || class.starts_with("none_iso_min");
    let trap = class == "alias_trap";
    let (m, n) = if iso_min {
        (5, 5)
    } else if trap {
        (rng.random_range(3..=5usize), rng.random_range(5..=10usize))
    } else {
        (rng.random_range(5..=15usize), rng.random_range(5..=15usize))
    };
    let sigma = rng.random_range(0.3..3.0);
    let length_mm = rng.random_range(200.0..1000.0);
    let dt = if trap {
        rng.random_range(90.0..240.0)
    } else {
        rng.random_range(10.0..40.0)
    };
    let pause = if trap {
        rng.random_range(60.0..300.0)
    } else {
        0.0
    };
    let slots = schedule(&mut rng, m, n, dt, pause);
    let duration = slots.last().map_or(1.0, |s| s.t);
    let x_mm: Vec<f64> = (0..m)
        .map(|i| i as f64 * length_mm / (m - 1) as f64 + rng.random_range(-0.3..0.3))
        .collect();
    // Static systematic deviation per target and direction: a smooth wave plus a reversal.
    let b0 = rng.random_range(-5.0..5.0) * sigma;
    let wave: Vec<f64> = (0..m)
        .map(|i| 10.0 * sigma * (i as f64 * 1.3 + seed as f64 % 7.0).sin())
        .collect();
    let mut dev: Vec<f64> = slots
        .iter()
        .map(|s| wave[s.target] + if s.up { 0.5 * b0 } else { -0.5 * b0 })
        .collect();
    let mut truth: Truth = Vec::new();
    let parts: Vec<&str> = match class {
        "warmup+cyclic" => vec!["exponential_warmup", "cyclic_drift"],
        "step+linear" => vec!["step", "linear_drift"],
        "reversal+thermal" => vec!["reversal_drift", "thermal_expansion"],
        "iso_min_warmup" | "iso_min_warmup_no_times" => vec!["exponential_warmup"],
        c => vec![c.trim_start_matches("iso_min_")],
    };
    let sign = |rng: &mut ChaCha8Rng| if rng.random::<bool>() { 1.0 } else { -1.0 };
    let cycle_len = duration / n as f64;
    let mut signals = Vec::new();
    let mut scale_shape = None;
    for p in parts {
        let before = dev.clone();
        match p {
            "linear_drift" => {
                let total = sign(&mut rng) * rng.random_range(3.0..6.0) * sigma;
                let rate = total / duration * 3600.0;
                for (d, s) in dev.iter_mut().zip(&slots) {
                    *d += rate * s.t / 3600.0;
                }
                truth.push(("linear_drift", "rate_um_per_h", rate));
            }
            "exponential_warmup" => {
                let a = sign(&mut rng) * rng.random_range(3.0..6.0) * sigma;
                let tau = rng.random_range(0.1..0.5) * duration;
                for (d, s) in dev.iter_mut().zip(&slots) {
                    *d += a * (1.0 - (-s.t / tau).exp());
                }
                truth.push(("exponential_warmup", "amplitude_um", a));
            }
            "cyclic_drift" => {
                let a = rng.random_range(2.5..5.0) * sigma;
                let hi = (40.0 * 60.0_f64).min(duration / 2.0);
                let mut period = rng.random_range(300.0..hi.max(301.0));
                for _ in 0..100 {
                    if !aliased(period, cycle_len, duration) {
                        break;
                    }
                    period = rng.random_range(300.0..hi.max(301.0));
                }
                let ph = rng.random_range(0.0..std::f64::consts::TAU);
                for (d, s) in dev.iter_mut().zip(&slots) {
                    *d += a * (std::f64::consts::TAU * s.t / period + ph).sin();
                }
                truth.push(("cyclic_drift", "period_s", period));
                truth.push(("cyclic_drift", "amplitude_um", a));
            }
            "thermal_expansion" => {
                // At least 3 σ at the far end of the axis by the end of the run.
                let lo = (8.0_f64).max(3.0 * sigma / (length_mm * 1e-3));
                let end_ppm = sign(&mut rng) * rng.random_range(lo..lo.max(30.0) + 1.0);
                let tau = rng.random_range(0.2..1.0) * duration;
                let g_end = 1.0 - (-duration / tau).exp();
                for (d, s) in dev.iter_mut().zip(&slots) {
                    *d += end_ppm / g_end * x_mm[s.target] * 1e-3 * (1.0 - (-s.t / tau).exp());
                }
                scale_shape = Some(slots.iter().map(|s| 1.0 - (-s.t / tau).exp()).collect());
                truth.push(("thermal_expansion", "scale_ppm", end_ppm));
            }
            "step" => {
                let size = sign(&mut rng) * rng.random_range(3.0..8.0) * sigma;
                let t0 = rng.random_range(0.2..0.8) * duration;
                for (d, s) in dev.iter_mut().zip(&slots) {
                    if s.t >= t0 {
                        *d += size;
                    }
                }
                truth.push(("step", "size_um", size));
            }
            "reversal_drift" => {
                // B = x̄↑ − x̄↓ changes by `change` from the start to the end.
                let change = sign(&mut rng) * rng.random_range(3.0..8.0) * sigma;
                for (d, s) in dev.iter_mut().zip(&slots) {
                    let h = if s.up { 0.5 } else { -0.5 };
                    *d += h * change * s.t / duration;
                }
                truth.push(("reversal_drift", "change_um", change));
            }
            "cycle_offsets" => {
                let sd = rng.random_range(2.0..5.0) * sigma;
                let off: Vec<f64> = (0..n)
                    .map(|_| {
                        let z: f64 = StandardNormal.sample(&mut rng);
                        sd * z
                    })
                    .collect();
                for (d, s) in dev.iter_mut().zip(&slots) {
                    *d += off[s.cycle];
                }
                let mean = off.iter().sum::<f64>() / n as f64;
                let s2 = off.iter().map(|o| (o - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
                truth.push(("cycle_offsets", "std_um", s2.sqrt()));
            }
            "erratic_reference" => {
                let share = rng.random_range(0.03..0.10);
                let mut level = 0.0;
                for d in dev.iter_mut() {
                    if rng.random::<f64>() < share {
                        level = sign(&mut rng) * rng.random_range(30.0..300.0) * sigma;
                    }
                    *d += level;
                }
            }
            _ => {}
        }
        let f: Vec<f64> = dev.iter().zip(&before).map(|(a, b)| a - b).collect();
        if p != "erratic_reference" && f.iter().any(|v| *v != 0.0) {
            signals.push((p.to_string(), f));
        }
    }
    // Noise.
    let anomaly = (class == "local_anomaly").then(|| {
        let t = rng.random_range(0..m);
        let r = rng.random_range(3.0..6.0);
        truth.push(("local_anomaly", "std_ratio", r));
        (t, r)
    });
    let rho: f64 = rng.random_range(0.5..0.7);
    let nu: f64 = rng.random_range(3.0..5.0);
    let mut prev = 0.0;
    for (d, s) in dev.iter_mut().zip(&slots) {
        let z: f64 = StandardNormal.sample(&mut rng);
        let e = match class {
            "correlated_noise" => {
                prev = rho * prev + (1.0 - rho * rho).sqrt() * z;
                prev
            }
            "heavy_tailed_noise" => {
                let t: f64 = StudentT::new(nu).map_or(z, |st| st.sample(&mut rng));
                t * ((nu - 2.0) / nu).sqrt()
            }
            _ => z,
        };
        let k = anomaly.filter(|a| a.0 == s.target).map_or(1.0, |a| a.1);
        *d += sigma * k * e;
    }
    if class == "outliers" {
        let count = rng.random_range(1..=4usize);
        for _ in 0..count {
            let j = rng.random_range(0..dev.len());
            dev[j] += sign(&mut rng) * rng.random_range(8.0..15.0) * sigma;
        }
    }
    let no_times = class.ends_with("no_times");
    let readings = slots
        .iter()
        .zip(&dev)
        .enumerate()
        .map(|(k, (s, d))| Reading {
            cycle: s.cycle + 1,
            direction: if s.up { Direction::Up } else { Direction::Down },
            index: s.target + 1,
            target_mm: x_mm[s.target],
            deviation_um: *d,
            time_s: if no_times { k as f64 } else { s.t },
            air_c: None,
            material_c: None,
        })
        .collect();
    let data = PositioningData {
        axis: Some("X".into()),
        material_compensation: true,
        has_times: !no_times,
        readings,
        ..Default::default()
    };
    (
        data,
        truth,
        Oracle {
            sigma,
            signals,
            scale_shape,
        },
    )
}

/// Power of an oracle: the non-centrality λ = ‖P⊥f‖²/σ² of each hidden mean effect f, P⊥
/// removing the per-(target, direction) constants and the other hidden effects, whose shapes
/// (τ, period, step moment) the oracle knows. A test of one known shape at the false-alarm
/// level α = 0.001 detects it with 95 % probability when λ ≥ (z₀.₉₉₉₅ + z₀.₉₅)² ≈ 24.4; below
/// that no method can reach 95 % at that level. A warm-up is told from a linear drift only by
/// its curvature and from a step only by its smoothness, so its λ is the least left after
/// removing a straight line in time or a step at any reading: naming a warm-up rather than a
/// drift or a step needs that much. A scale change likewise counts only by what tells it from
/// a drift common to every target: the least left after removing a straight line in time, or
/// its own time shape g(t) at every target. Written here, apart from the analysis.
fn oracle_lambdas(data: &PositioningData, o: &Oracle) -> Vec<f64> {
    let key = |r: &Reading| (r.index, r.direction == Direction::Up);
    let centre = |f: &[f64]| -> Vec<f64> {
        let mut sums: std::collections::HashMap<(usize, bool), (f64, f64)> = Default::default();
        for (r, v) in data.readings.iter().zip(f) {
            let e = sums.entry(key(r)).or_default();
            e.0 += v;
            e.1 += 1.0;
        }
        data.readings
            .iter()
            .zip(f)
            .map(|(r, v)| v - sums[&key(r)].0 / sums[&key(r)].1)
            .collect()
    };
    let t: Vec<f64> = data.readings.iter().map(|r| r.time_s).collect();
    // A warm-up's rivals: a straight line, and a step at any reading.
    let rivals: Vec<Vec<f64>> = std::iter::once(centre(&t))
        .chain(t.iter().skip(1).map(|&t0| {
            centre(
                &t.iter()
                    .map(|&x| f64::from(u8::from(x >= t0)))
                    .collect::<Vec<_>>(),
            )
        }))
        .collect();
    let cs: Vec<Vec<f64>> = o.signals.iter().map(|(_, f)| centre(f)).collect();
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    (0..cs.len())
        .map(|i| {
            let others: Vec<&[f64]> = (0..cs.len())
                .filter(|&j| j != i)
                .map(|j| cs[j].as_slice())
                .collect();
            let lambda = |extra: Option<&[f64]>| {
                let mut with = others.clone();
                with.extend(extra);
                let f = residual(&cs[i], &with);
                dot(&f, &f) / (o.sigma * o.sigma)
            };
            match (o.signals[i].0.as_str(), &o.scale_shape) {
                ("exponential_warmup", _) => rivals
                    .iter()
                    .map(|r| lambda(Some(r)))
                    .fold(f64::INFINITY, f64::min),
                ("thermal_expansion", Some(g)) => {
                    lambda(Some(&rivals[0])).min(lambda(Some(&centre(g))))
                }
                _ => lambda(None),
            }
        })
        .collect()
}

/// `f` less its least-squares fit on `others` (normal equations by Gaussian elimination; at
/// most three columns).
fn residual(f: &[f64], others: &[&[f64]]) -> Vec<f64> {
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let k = others.len();
    let mut a: Vec<Vec<f64>> = (0..k)
        .map(|i| {
            let mut row: Vec<f64> = (0..k).map(|j| dot(others[i], others[j])).collect();
            row.push(dot(others[i], f));
            row
        })
        .collect();
    for c in 0..k {
        let p = (c..k)
            .max_by(|&x, &y| a[x][c].abs().total_cmp(&a[y][c].abs()))
            .unwrap_or(c);
        a.swap(c, p);
        if a[c][c].abs() < 1e-300 {
            continue;
        }
        let pivot = a[c].clone();
        for (r, row) in a.iter_mut().enumerate() {
            if r != c {
                let m = row[c] / pivot[c];
                row[c..]
                    .iter_mut()
                    .zip(&pivot[c..])
                    .for_each(|(x, y)| *x -= m * y);
            }
        }
    }
    let coef: Vec<f64> = (0..k)
        .map(|i| {
            if a[i][i].abs() < 1e-300 {
                0.0
            } else {
                a[i][k] / a[i][i]
            }
        })
        .collect();
    (0..f.len())
        .map(|j| f[j] - (0..k).map(|i| coef[i] * others[i][j]).sum::<f64>())
        .collect()
}

/// λ at which the oracle test of [`oracle_lambdas`] detects 95 % of runs.
const LAMBDA_95: f64 = 24.4;

/// Probability that the oracle's test (one known shape, amplitude unknown, two-sided at a
/// false-alarm level of 0.001: |z| > 3.2905) detects an effect of non-centrality λ.
fn oracle_power(lambda: f64) -> f64 {
    use statrs::distribution::{ContinuousCDF, Normal};
    let Ok(n) = Normal::new(0.0, 1.0) else {
        return f64::NAN;
    };
    let s = lambda.max(0.0).sqrt();
    n.cdf(s - 3.2905) + n.cdf(-s - 3.2905)
}

#[test]
fn the_oracle_detects_95_percent_at_lambda_95() {
    assert!((oracle_power(LAMBDA_95) - 0.95).abs() < 0.002);
    assert!((oracle_power(0.0) - 0.001).abs() < 1e-5);
}

/// Per class: datasets, detected (every expected effect named), extra effects named, and
/// parameters checked / within 2 standard uncertainties.
#[derive(Debug, Default, Clone, Copy)]
struct Tally {
    runs: usize,
    detected: usize,
    /// Every expected effect named, or given as one the data cannot tell from a named one.
    detected_alt: usize,
    /// Runs whose hidden mean effects an oracle would detect 95 % of the time
    /// ([`oracle_lambdas`]), and how many of them are detected (named; named or given as an
    /// alternative).
    detectable: usize,
    detected_detectable: usize,
    detected_alt_detectable: usize,
    /// Sum over runs of the probability that the oracle detects every hidden mean effect
    /// (the product of [`oracle_power`] over them): its mean is the best detection rate a
    /// method could reach at the oracle's false-alarm level.
    oracle_power: f64,
    /// Runs with a finding the data cannot tell from another effect.
    with_alt: usize,
    /// Runs naming an effect not hidden that points at the machine (a drift, warm-up, cycle,
    /// scale change, reversal change or noisy target), not at the measuring set-up (a step,
    /// offsets per cycle, outliers or `unexplained`).
    machine_wrong: usize,
    any_finding: usize,
    wrong: usize,
    params: usize,
    params_ok: usize,
}

fn run_class(class: &str, expect: &[&str], count: usize, seed0: u64) -> Tally {
    (0..count)
        .into_par_iter()
        .map(|k| {
            let seed = seed0 + 7919 * k as u64 + class.len() as u64;
            let (data, truth, oracle) = random_case(seed, class);
            let d = diagnose(&data, &Options::default()).expect("diagnose");
            let f = &d.report.findings;
            let named = |e: &str| f.iter().any(|x| x.effect.name() == e);
            let rival = |e: &str| {
                f.iter()
                    .any(|x| x.effect.name() == e || x.alternatives.iter().any(|a| a.effect.name() == e))
            };
            let mut t = Tally {
                runs: 1,
                ..Default::default()
            };
            t.detected = usize::from(if expect.is_empty() {
                f.is_empty()
            } else {
                expect.iter().all(|e| named(e))
            });
            t.detected_alt = usize::from(if expect.is_empty() {
                f.is_empty()
            } else {
                expect.iter().all(|e| rival(e))
            });
            let lambdas = oracle_lambdas(&data, &oracle);
            if !expect.is_empty() && !lambdas.is_empty() && lambdas.iter().all(|l| *l >= LAMBDA_95)
            {
                t.detectable = 1;
                t.detected_detectable = t.detected;
                t.detected_alt_detectable = t.detected_alt;
            }
            if !expect.is_empty() && !lambdas.is_empty() {
                t.oracle_power = lambdas.iter().map(|l| oracle_power(*l)).product();
            }
            t.with_alt = usize::from(f.iter().any(|x| !x.alternatives.is_empty()));
            t.machine_wrong = usize::from(f.iter().any(|x| {
                !expect.contains(&x.effect.name())
                    && !matches!(
                        x.effect.name(),
                        "step" | "cycle_offsets" | "outliers" | "unexplained"
                    )
            }));
            t.any_finding = usize::from(!f.is_empty());
            t.wrong = usize::from(f.iter().any(|x| !expect.contains(&x.effect.name())));
            for (e, p, v) in &truth {
                if let Some(x) = f.iter().find(|x| x.effect.name() == *e)
                    && let (Some(est), Some(u)) = (x.params().get(*p), x.params_u.get(*p))
                {
                    t.params += 1;
                    t.params_ok += usize::from((est - v).abs() <= 2.0 * u);
                    if std::env::var("SHOW_PARAMS").is_ok() && (est - v).abs() > 2.0 * u {
                        eprintln!("param miss {class} seed {seed}: {e}.{p} true {v:.4} est {est:.4} u {u:.4} ({:.1} u)", (est - v) / u);
                    }
                }
            }
            if std::env::var("SHOW_MISSES").is_ok() && (t.detected == 0 || t.wrong == 1) {
                eprintln!(
                    "{class} seed {seed}: m={} n={} λ {lambdas:.0?} truth {truth:?} findings {:?}",
                    data.n_targets(),
                    data.n_cycles(),
                    f.iter()
                        .map(|x| (
                            x.effect.name(),
                            x.significance,
                            x.params(),
                            x.alternatives
                                .iter()
                                .map(|a| (a.effect.name(), a.delta_bic))
                                .collect::<Vec<_>>()
                        ))
                        .collect::<Vec<_>>()
                );
            }
            t
        })
        .reduce(Tally::default, |a, b| Tally {
            runs: a.runs + b.runs,
            detected: a.detected + b.detected,
            detected_alt: a.detected_alt + b.detected_alt,
            detectable: a.detectable + b.detectable,
            detected_detectable: a.detected_detectable + b.detected_detectable,
            detected_alt_detectable: a.detected_alt_detectable + b.detected_alt_detectable,
            oracle_power: a.oracle_power + b.oracle_power,
            with_alt: a.with_alt + b.with_alt,
            machine_wrong: a.machine_wrong + b.machine_wrong,
            any_finding: a.any_finding + b.any_finding,
            wrong: a.wrong + b.wrong,
            params: a.params + b.params,
            params_ok: a.params_ok + b.params_ok,
        })
}

fn pct(a: usize, b: usize) -> String {
    if b == 0 {
        "–".into()
    } else {
        format!("{:.1} %", 100.0 * a as f64 / b as f64)
    }
}

/// The full table: `cargo test --release -p metrolog-diagnose --test diagnose_hidden --
/// --ignored --nocapture` (PER_CLASS overrides the 200 datasets per class).
#[test]
#[ignore = "≥ 200 datasets per class; run with --release"]
fn table_200_per_class() {
    let only = std::env::var("CLASS").ok();
    let per: usize = std::env::var("PER_CLASS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(200);
    println!(
        "| class | runs | detection (no effect: no finding) | named or indistinguishable from a named one | runs with an indistinguishable alternative | other effect named | of which a machine cause | params within 2u | runs an oracle detects 95 % of the time | detection among them (named / or indistinguishable) | the oracle's own detection rate |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    for (class, expect) in CLASSES {
        if only.as_deref().is_some_and(|o| o != class) {
            continue;
        }
        let t = run_class(class, expect, per, 1);
        println!(
            "| {class} | {} | {} | {} | {} | {} | {} | {} | {} | {} / {} | {} |",
            t.runs,
            pct(t.detected, t.runs),
            pct(t.detected_alt, t.runs),
            pct(t.with_alt, t.runs),
            pct(t.wrong, t.runs),
            pct(t.machine_wrong, t.runs),
            pct(t.params_ok, t.params),
            pct(t.detectable, t.runs),
            pct(t.detected_detectable, t.detectable),
            pct(t.detected_alt_detectable, t.detectable),
            if t.detectable > 0 || t.oracle_power > 0.0 {
                format!("{:.1} %", 100.0 * t.oracle_power / t.runs as f64)
            } else {
                "–".into()
            },
        );
    }
}

/// CI: a small sample of every class (the table above measures the rates): no finding on
/// noise-only runs (heavy tails: at most one), and every class with an effect named in at
/// least half of its runs.
#[test]
fn every_class_small_sample() {
    let mut failures = Vec::new();
    for (class, expect) in CLASSES {
        let t = run_class(class, expect, 4, 99);
        let need = match (expect.is_empty(), class) {
            (true, "heavy_tailed_noise") => 3,
            (true, _) => 4,
            (false, _) => 2,
        };
        if t.detected < need {
            failures.push(format!("{class}: {}/{}", t.detected, t.runs));
        }
    }
    assert!(failures.is_empty(), "classes missed: {failures:?}");
}

/// On 5 targets × 5 cycles a warm-up with a long time constant is nearly a straight line: the
/// tool must then name the warm-up or say that the data cannot tell it from the effect it
/// names, in the finding's cause. Without the alternatives this class scored 70 % (the table).
#[test]
fn iso_min_warmup_is_named_or_given_as_indistinguishable() {
    let t = run_class("iso_min_warmup", &["exponential_warmup"], 40, 5);
    assert!(t.detected_alt >= 32 && t.detected_alt > t.detected, "{t:?}");
    let report = (0..40)
        .map(|k| random_case(5 + 7919 * k + 14, "iso_min_warmup").0)
        .map(|d| diagnose(&d, &Options::default()).expect("diagnose").report)
        .find(|r| r.findings.iter().any(|f| !f.alternatives.is_empty()))
        .expect("a finding with an alternative");
    assert!(
        report.conclusion.contains("the data cannot tell"),
        "{}",
        report.conclusion
    );
    let with_rival = report
        .findings
        .iter()
        .find(|f| !f.alternatives.is_empty())
        .expect("a finding with an alternative");
    for a in &with_rival.alternatives {
        assert!(
            with_rival
                .cause
                .contains(&format!("cannot tell it from {}", a.effect))
                && a.delta_bic < 6.0,
            "{with_rival:?}"
        );
    }
}

/// Alternatives are not clutter: a clear linear drift on a long run rarely gets one.
#[test]
fn a_long_linear_drift_rarely_gets_an_alternative() {
    let t = run_class("linear_drift", &["linear_drift"], 40, 5);
    assert!(t.detected >= 36 && t.with_alt <= 6, "{t:?}");
}
/// One dataset of the table, its truth and findings: `SEED=847345 CLASS=step+linear cargo test
/// --release -p metrolog-diagnose --test diagnose_hidden one_dataset -- --ignored --nocapture`
/// (the seeds are those `SHOW_MISSES=1` prints).
#[test]
#[ignore = "needs SEED and CLASS"]
fn one_dataset() {
    let seed: u64 = std::env::var("SEED")
        .expect("SEED")
        .parse()
        .expect("SEED: a number");
    let class = std::env::var("CLASS").expect("CLASS");
    let (data, truth, _) = random_case(seed, &class);
    let d = diagnose(&data, &Options::default()).unwrap();
    eprintln!("truth {truth:?}\nreport {:#?}", d.report);
}

/// An erratic reference (jumps that stay) is `unexplained`, and the jumps are not dressed up
/// as a machine cause: a cycle or drift fitted through them is demoted to a note. Without that
/// rule a machine cause is named in 14 of these 100 runs (18 % of the table's 200).
#[test]
fn an_erratic_reference_gets_no_machine_cause() {
    let t = run_class("erratic_reference", &["unexplained"], 100, 1);
    assert!(t.detected >= 90 && t.machine_wrong <= 8, "{t:?}");
}

/// Heavy-tailed noise (Student t, 3–5 degrees of freedom) against isolated outliers on normal
/// noise: the residuals' whole shape is weighed (a Bayes factor of normal noise with events
/// against a t, `tails.rs`), so the tail of a t is rarely reported as outliers while real
/// outliers still are. With the zone and kurtosis tests alone, 26 of these 200 heavy-tailed
/// runs named an effect and 192 of the 200 outlier runs named their outliers; with the Bayes
/// factor 9 and 187 (on 1000 runs each: 1.7 % and 96.1 %).
#[test]
fn heavy_tails_are_not_reported_as_outliers() {
    let heavy = run_class("heavy_tailed_noise", &[], 200, 5000);
    let outliers = run_class("outliers", &["outliers"], 200, 5000);
    eprintln!("{heavy:?}\n{outliers:?}");
    assert!(heavy.wrong <= 12, "{heavy:?}");
    assert!(outliers.detected >= 184, "{outliers:?}");
}

/// A warm-up beside a cycle: the cycle's period, found first, is biased by the warm-up and
/// can leave it looking like a step. The backfitting swaps an effect with the others'
/// parameters searched again around the newcomer; without that, a step was named instead of
/// the warm-up in 10 of these 100 runs (8 of the 61 where an oracle tells the warm-up from a
/// drift), with it in none of those 61.
#[test]
fn a_warmup_beside_a_cycle_is_not_taken_for_a_step() {
    let t = run_class(
        "warmup+cyclic",
        &["exponential_warmup", "cyclic_drift"],
        100,
        5000,
    );
    eprintln!("{t:?}");
    assert!(
        t.detected >= 85 && t.detected_detectable + 2 >= t.detectable,
        "{t:?}"
    );
}
