//! The CapBall Monte Carlo of paper 001 (14 outputs, 807 poses × 3 equations, cyclic drift)
//! against the NumPy reference `benches/py/capball_mc.py`, measured in one run on the same
//! machine, as trials per CPU-second of one thread (the machine is shared, so wall-clock rates
//! would measure the other jobs too).
//!
//!     cargo bench -p metrolog-uncertainty --bench capball_vs_numpy
//!
//! Two Rust figures: the per-point path (every trial draws the 2421 per-point normals and
//! projects them with the precomputed pseudo-inverse, batched into matrix products: the same
//! work as the NumPy script) and the reduced path (the per-point noise drawn directly in
//! parameter space through a square root of J⁺ΣJ⁺ᵀ, exact for Gaussian per-point noise; see
//! `CapballMc::with_reduced_noise`). The NumPy script is run twice, once per path.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use uncertainty::capball::{CapballMc, Paper001Case};
use uncertainty::mc::{BLOCK_TRIALS, TrialSource};

/// CPU time of the calling thread (Linux schedstat, ns).
fn thread_cpu_s() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    Some(s.split_whitespace().next()?.parse::<f64>().ok()? * 1e-9)
}

fn rust_rate(model: &CapballMc, blocks: usize) -> Option<f64> {
    let mut scratch = model.scratch();
    let mut out = vec![0.0; BLOCK_TRIALS * model.n_outputs()];
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    model.fill(&mut rng, &mut scratch, &mut out); // warm-up
    let t0 = thread_cpu_s()?;
    for b in 0..blocks {
        rng.set_stream(b as u64);
        model.fill(&mut rng, &mut scratch, &mut out);
    }
    let t1 = thread_cpu_s()?;
    Some((blocks * BLOCK_TRIALS) as f64 / (t1 - t0))
}

fn numpy_rate(trials: usize, reduced: bool) -> Result<f64, String> {
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/benches/py/capball_mc.py");
    let mut cmd = std::process::Command::new("python3");
    cmd.arg(script).arg("--trials").arg(trials.to_string());
    if reduced {
        cmd.arg("--reduced");
    }
    let out = cmd.output().map_err(|e| format!("python3: {e}"))?;
    let text = String::from_utf8_lossy(&out.stdout);
    if !out.status.success() {
        return Err(format!(
            "{text}{}",
            String::from_utf8_lossy(&out.stderr).trim()
        ));
    }
    text.lines()
        .find_map(|l| l.strip_prefix("trials per CPU-second: "))
        .and_then(|v| v.trim().parse().ok())
        .ok_or_else(|| format!("unexpected output: {text}"))
}

/// Where a per-point trial spends its time: its 2421 normals from each generator (ChaCha8 and
/// xoshiro256++ one at a time through `rand_distr`, and `FastNormals`, the one used), and its
/// share of the batched projection (σ-scaled J⁺ times 50 trials' normals).
fn parts() -> Option<()> {
    use rand::rngs::SmallRng;
    use rand_distr::{Distribution, StandardNormal};
    use uncertainty::normals::FastNormals;
    let (rows, batch, reps) = (2421, 50, 200);
    let mut buf = vec![0.0; rows * batch];
    let per_trial = |t0: f64, t1: f64| (t1 - t0) / (reps * batch) as f64 * 1e6;
    let mut chacha = ChaCha8Rng::seed_from_u64(1);
    let t0 = thread_cpu_s()?;
    for _ in 0..reps {
        buf.iter_mut()
            .for_each(|e| *e = StandardNormal.sample(&mut chacha));
    }
    let t1 = thread_cpu_s()?;
    let mut small = SmallRng::seed_from_u64(1);
    for _ in 0..reps {
        buf.iter_mut()
            .for_each(|e| *e = StandardNormal.sample(&mut small));
    }
    let t2 = thread_cpu_s()?;
    let mut fast = FastNormals::from_rng(&mut chacha);
    for _ in 0..reps {
        fast.fill(&mut buf);
    }
    let t3 = thread_cpu_s()?;
    let case = Paper001Case::paper001();
    let model = case
        .monte_carlo_model(&case.p_true, &case.cyclic_sources())
        .ok()?;
    let pinv = model.pseudo_inverse().clone();
    let e = nalgebra::DMatrix::<f64>::from_column_slice(rows, batch, &buf);
    let mut p = nalgebra::DMatrix::<f64>::zeros(14, batch);
    let t4 = thread_cpu_s()?;
    for _ in 0..reps {
        p.gemm(1.0, &pinv, &e, 0.0);
    }
    let t5 = thread_cpu_s()?;
    println!(
        "parts per per-point trial (µs): normals rand_distr+chacha8 {:.2}, rand_distr+xoshiro \
         {:.2}, FastNormals {:.2}; projection {:.2} ({:.3})",
        per_trial(t0, t1),
        per_trial(t1, t2),
        per_trial(t2, t3),
        per_trial(t4, t5),
        p[(0, 0)] + buf[0]
    );
    Some(())
}

fn main() {
    if parts().is_none() {
        println!("no per-thread CPU clock (/proc/thread-self/schedstat): nothing measured");
        return;
    }
    // `cargo bench` passes --bench; nothing else to parse.
    let case = Paper001Case::paper001();
    let model = case
        .monte_carlo_model(&case.p_true, &case.cyclic_sources())
        .expect("the paper-001 case builds");
    let reduced = model.clone().with_reduced_noise();
    for (label, m, blocks, np_trials, np_reduced) in [
        ("per-point", &model, 60, 30_000, false),
        ("reduced", &reduced, 2000, 300_000, true),
    ] {
        let Some(r) = rust_rate(m, blocks) else {
            println!("no per-thread CPU clock (/proc/thread-self/schedstat): nothing measured");
            return;
        };
        match numpy_rate(np_trials, np_reduced) {
            Ok(n) => println!(
                "capball MC {label:<9}: Rust {r:>10.0} trials per CPU-second, NumPy {n:>9.0}: \
                 ratio {:.2}",
                r / n
            ),
            Err(e) => println!(
                "capball MC {label:<9}: Rust {r:>10.0} trials per CPU-second; NumPy not run ({e})"
            ),
        }
    }
}
