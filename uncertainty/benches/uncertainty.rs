//! Monte Carlo throughput: the CapBall case of paper 001 (14 outputs, 807 poses × 3 equations,
//! cyclic drift) per core and as a full adaptive run, and a small budget.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use uncertainty::budget::Budget;
use uncertainty::capball::Paper001Case;
use uncertainty::mc::{self, BLOCK_TRIALS, McOptions, TrialSource};

/// CPU time of the calling thread (Linux schedstat, ns): the machine this runs on is shared, so
/// wall-clock figures understate the per-core rate; this one does not.
fn thread_cpu_s() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    Some(s.split_whitespace().next()?.parse::<f64>().ok()? * 1e-9)
}

fn capball(c: &mut Criterion) {
    let case = Paper001Case::paper001();
    let model = case
        .monte_carlo_model(&case.p_true, &case.cyclic_sources())
        .unwrap();
    if let Some(t0) = thread_cpu_s() {
        let mut scratch = model.scratch();
        let mut out = vec![0.0; BLOCK_TRIALS * model.n_outputs()];
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let blocks = 100;
        for _ in 0..blocks {
            model.fill(&mut rng, &mut scratch, &mut out);
        }
        if let Some(t1) = thread_cpu_s() {
            println!(
                "capball per-point trials per CPU-second (one thread): {:.0}",
                (blocks * BLOCK_TRIALS) as f64 / (t1 - t0)
            );
        }
    }
    let t = std::time::Instant::now();
    let r = mc::run(&model, &McOptions::default(), None).unwrap();
    println!(
        "capball adaptive run (ndig 2, all cores): {} sequences, {} trials, {:.2} s wall",
        r.sequences,
        r.trials,
        t.elapsed().as_secs_f64()
    );
    let mut g = c.benchmark_group("capball_mc");
    g.throughput(Throughput::Elements(BLOCK_TRIALS as u64));
    g.bench_function("block_of_500_trials_one_core", |b| {
        let mut scratch = model.scratch();
        let mut out = vec![0.0; BLOCK_TRIALS * model.n_outputs()];
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        b.iter(|| model.fill(&mut rng, &mut scratch, &mut out));
    });
    // The two halves of a trial, for the report: the per-point noise and its projection.
    g.throughput(Throughput::Elements(1));
    g.bench_function("parts/normals_2421", |b| {
        use rand_distr::{Distribution, StandardNormal};
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let mut v = vec![0.0f64; 2421];
        b.iter(|| {
            for x in v.iter_mut() {
                *x = StandardNormal.sample(&mut rng);
            }
            v[7]
        })
    });
    g.bench_function("parts/projection_14x2421_per_trial_batched_50", |b| {
        let pinv = model.pseudo_inverse().clone();
        let e = nalgebra::DMatrix::<f64>::from_element(2421, 50, 0.5);
        let mut p = nalgebra::DMatrix::<f64>::zeros(14, 50);
        b.iter(|| {
            p.gemm(1.0, &pinv, &e, 0.0);
            p[(0, 0)]
        })
    });
    let reduced = model.clone().with_reduced_noise();
    g.bench_function("block_of_500_trials_one_core_reduced_noise", |b| {
        let mut scratch = reduced.scratch();
        let mut out = vec![0.0; BLOCK_TRIALS * reduced.n_outputs()];
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        b.iter(|| reduced.fill(&mut rng, &mut scratch, &mut out));
    });
    g.finish();
    let mut g = c.benchmark_group("capball_adaptive");
    g.sample_size(10);
    g.bench_function("full_adaptive_run_ndig2_all_cores", |b| {
        b.iter(|| {
            let r = mc::run(&model, &McOptions::default(), None).unwrap();
            assert!(r.converged);
            r.trials
        })
    });
    g.bench_function("full_adaptive_run_ndig2_reduced_noise", |b| {
        b.iter(|| {
            let r = mc::run(&reduced, &McOptions::default(), None).unwrap();
            assert!(r.converged);
            r.trials
        })
    });
    g.finish();
}

fn budget(c: &mut Criterion) {
    let b =
        Budget::from_toml(include_str!("../../examples/budgets/jcgm101_9_3_mass.toml")).unwrap();
    let mut g = c.benchmark_group("budget_mc");
    g.throughput(Throughput::Elements(BLOCK_TRIALS as u64));
    g.bench_function("mass_9_3_block_of_500_one_core", |bch| {
        let mut scratch = b.scratch();
        let mut out = vec![0.0; BLOCK_TRIALS];
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        bch.iter(|| b.fill(&mut rng, &mut scratch, &mut out));
    });
    g.finish();
}

criterion_group!(benches, capball, budget);
criterion_main!(benches);
