//! The CapBall Monte Carlo of paper 001 (14 outputs, 807 poses × 3 equations, cyclic drift)
//! against the NumPy reference `benches/py/capball_mc.py`, measured in one run on the same
//! machine, as trials per CPU-second of one thread (the machine is shared, so wall-clock rates
//! would measure the other jobs too).
//!
//!     cargo bench -p metrolog-uncertainty --bench capball_vs_numpy
//!
//! First, end to end: the whole work of `metrolog identify capball --uncertainty mc`
//! (`capball::source_widths`: model set-up and four adaptive Monte Carlo runs with their
//! per-sequence statistics, stabilisation checks, intervals and correlations) on both cores,
//! against `capball_mc.py --end-to-end` doing the same sequences of the same trials with NumPy,
//! wall-clock and CPU seconds of each, three rounds interleaved. Then the kernels alone:
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

/// CPU seconds of the whole process, all threads (Linux /proc/self/stat, clock ticks of 10 ms).
fn process_cpu_s() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/stat").ok()?;
    let rest = s.rsplit_once(')')?.1;
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

/// The whole `source_widths` run as the CLI makes it: (wall s, CPU s, sequences per run).
fn rust_end_to_end() -> Option<(f64, f64, Vec<usize>)> {
    use uncertainty::capball::{CapballSources, Source, source_widths};
    let case = Paper001Case::paper001();
    let sources = case.cyclic_sources();
    let opts = uncertainty::McOptions::default();
    let c0 = process_cpu_s()?;
    let t0 = std::time::Instant::now();
    let build = |s: &CapballSources| {
        case.monte_carlo_model(&case.p_true, s)
            .map(|m| m.with_reduced_noise())
    };
    let (total, widths) = source_widths(&build, &sources, &opts, None).ok()?;
    let wall = t0.elapsed().as_secs_f64();
    let cpu = process_cpu_s()? - c0;
    // The sequences of each run, for NumPy to do the same trials: the total's from the result,
    // the single sources' by running them again (outside the timing).
    let mut seqs = vec![total.sequences];
    for src in [Source::Drift, Source::Sensor, Source::Frame] {
        let m = build(&sources.only(src)).ok()?;
        seqs.push(uncertainty::mc::run(&m, &opts, None).ok()?.sequences);
    }
    std::hint::black_box(widths);
    Some((wall, cpu, seqs))
}

fn numpy_end_to_end(seqs: &[usize]) -> Result<(f64, f64), String> {
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/benches/py/capball_mc.py");
    let list: Vec<String> = seqs.iter().map(|s| s.to_string()).collect();
    let out = std::process::Command::new("python3")
        .arg(script)
        .args([
            "--end-to-end",
            "--threads",
            "2",
            "--sequences",
            &list.join(","),
        ])
        .output()
        .map_err(|e| format!("python3: {e}"))?;
    let text = String::from_utf8_lossy(&out.stdout);
    if !out.status.success() {
        return Err(format!(
            "{text}{}",
            String::from_utf8_lossy(&out.stderr).trim()
        ));
    }
    let field = |k: &str| {
        text.lines()
            .find_map(|l| l.strip_prefix(k))
            .and_then(|v| v.trim().parse::<f64>().ok())
            .ok_or_else(|| format!("unexpected output: {text}"))
    };
    Ok((
        field("end-to-end seconds (wall): ")?,
        field("end-to-end seconds (CPU): ")?,
    ))
}

fn end_to_end() {
    for round in 1..=3 {
        let Some((wall, cpu, seqs)) = rust_end_to_end() else {
            println!("end to end: no /proc/self/stat or the run failed: nothing measured");
            return;
        };
        let trials: usize = seqs.iter().sum::<usize>() * 10_000;
        match numpy_end_to_end(&seqs) {
            Ok((nw, nc)) => println!(
                "end to end round {round} ({trials} trials, sequences {seqs:?}): Rust {wall:.3} s \
                 wall {cpu:.2} s CPU, NumPy {nw:.3} s wall {nc:.2} s CPU: {:.1}x wall, {:.1}x CPU",
                nw / wall,
                nc / cpu.max(0.01)
            ),
            Err(e) => println!(
                "end to end round {round}: Rust {wall:.3} s wall {cpu:.2} s CPU; NumPy not run ({e})"
            ),
        }
    }
}

fn main() {
    end_to_end();
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
