//! Monte Carlo propagation of distributions (JCGM 101), with the adaptive procedure of §7.9,
//! probabilistically symmetric and shortest coverage intervals (§7.7) and the validation of a GUM
//! result (§8). Several outputs are handled component by component (the adaptive criterion must
//! hold for every output).
//!
//! Reproducibility: trials are generated in fixed blocks of [`BLOCK_TRIALS`]; block `b` of the
//! whole run draws from ChaCha8 seeded with the run's seed on stream `b`. Blocks run in parallel
//! on all cores (rayon) and write to their own slice, so the values, and every statistic, are
//! the same for any number of threads.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::Serialize;

use super::UncertaintyError;
use super::gum::GumOutput;

/// Trials per block (the unit of parallel work and of random-stream assignment).
pub const BLOCK_TRIALS: usize = 500;

/// A generator of Monte Carlo trials: draws the inputs and evaluates the model.
pub trait TrialSource: Sync {
    /// Per-worker scratch memory, so that no trial allocates.
    type Scratch: Send;
    fn n_outputs(&self) -> usize;
    fn output_names(&self) -> Vec<String>;
    fn scratch(&self) -> Self::Scratch;
    /// Fills `out` (trial-major: `n_trials × n_outputs`) with the output values of independent
    /// trials drawn from `rng`.
    fn fill(&self, rng: &mut ChaCha8Rng, scratch: &mut Self::Scratch, out: &mut [f64]);
}

/// Which coverage interval the adaptive procedure watches.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, serde::Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum IntervalKind {
    /// Probabilistically symmetric (JCGM 101 §7.7.2).
    #[default]
    Symmetric,
    /// Shortest (JCGM 101 §7.7.3).
    Shortest,
}

/// Options of a Monte Carlo run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct McOptions {
    /// Coverage probability p.
    pub coverage_probability: f64,
    /// Significant decimal digits regarded as meaningful in u(y) (JCGM 101 §7.9.2).
    pub ndig: u32,
    /// Absolute numerical tolerances per output; override the ones derived from `ndig`
    /// (paper 001 sets δ directly).
    pub tolerance: Option<Vec<f64>>,
    pub seed: u64,
    /// A fixed number of trials instead of the adaptive procedure (rounded up to whole blocks).
    pub fixed_trials: Option<usize>,
    /// The adaptive procedure stops here even if not stabilised (`converged = false`).
    pub max_trials: usize,
    pub interval: IntervalKind,
}

impl Default for McOptions {
    fn default() -> Self {
        McOptions {
            coverage_probability: 0.95,
            ndig: 2,
            tolerance: None,
            seed: 1,
            fixed_trials: None,
            max_trials: 10_000_000,
            interval: IntervalKind::Symmetric,
        }
    }
}

/// Progress after each sequence (or block group, for a fixed run).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct McProgress {
    pub sequences: usize,
    pub trials: usize,
    /// Largest 2s/δ over all control variables and outputs (≤ 1 means stabilised);
    /// `None` before two sequences exist or for a fixed run.
    pub worst_ratio: Option<f64>,
    pub max_trials: usize,
}

/// The Monte Carlo result for one output.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct McOutput {
    pub name: String,
    /// Average of the model values (JCGM 101 eq. 15).
    pub estimate: f64,
    /// Their standard deviation (JCGM 101 eq. 16).
    pub standard_uncertainty: f64,
    pub symmetric_interval: [f64; 2],
    pub shortest_interval: [f64; 2],
    /// Numerical tolerance δ (JCGM 101 §7.9.2) at the end of the run.
    pub tolerance: f64,
    /// 2·s of the sequence averages of [y, u(y), y_low, y_high] at the end of an adaptive run.
    pub stability: Option<[f64; 4]>,
}

/// The result of a Monte Carlo run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct McResult {
    pub coverage_probability: f64,
    pub trials: usize,
    pub sequences: usize,
    /// True when the adaptive criterion was met (always true for a fixed run).
    pub converged: bool,
    pub outputs: Vec<McOutput>,
    /// Correlation coefficients between the outputs.
    pub output_correlation: Vec<Vec<f64>>,
    /// All model values of each output, sorted ascending (for histograms and densities).
    #[serde(skip)]
    pub sorted_values: Vec<Vec<f64>>,
}

/// Validation of a GUM result by Monte Carlo (JCGM 101 §8.2).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Validation {
    pub output: String,
    /// |y − U_p − y_low|.
    pub d_low: f64,
    /// |y + U_p − y_high|.
    pub d_high: f64,
    /// Numerical tolerance δ associated with the GUM u(y).
    pub tolerance: f64,
    /// Both d ≤ δ: the GUM result is validated.
    pub passed: bool,
}

/// JCGM 101 §7.9.2: write u as c·10^l with c an `ndig`-digit integer; δ = ½·10^l.
pub fn numerical_tolerance(u: f64, ndig: u32) -> f64 {
    if u <= 0.0 || !u.is_finite() {
        return 0.0;
    }
    let l = u.log10().floor() as i32 - ndig.max(1) as i32 + 1;
    0.5 * 10f64.powi(l)
}

/// Trials per sequence: M = max(J, 10⁴) with J the smallest integer ≥ 100/(1 − p)
/// (JCGM 101 §7.9.4 b), rounded up to whole blocks.
pub fn sequence_trials(p: f64) -> usize {
    let j = (100.0 / (1.0 - p) - 1e-9).ceil() as usize;
    j.max(10_000).div_ceil(BLOCK_TRIALS) * BLOCK_TRIALS
}

/// Coverage interval of `sorted` values for probability `p` (JCGM 101 §7.7).
pub fn coverage_interval(sorted: &[f64], p: f64, kind: IntervalKind) -> [f64; 2] {
    let m = sorted.len();
    if m == 0 {
        return [f64::NAN, f64::NAN];
    }
    // q = pM if an integer, else the integer part of pM + 1/2.
    let q = ((p * m as f64) + 0.5).floor() as usize;
    let q = q.clamp(1, m.saturating_sub(1).max(1));
    match kind {
        IntervalKind::Symmetric => {
            // r = (M − q)/2 if an integer, else (M − q + 1)/2 (1-based).
            let r = (m - q).div_ceil(2).max(1);
            [sorted[r - 1], sorted[(r - 1 + q).min(m - 1)]]
        }
        IntervalKind::Shortest => {
            let mut best = 0;
            let mut width = f64::INFINITY;
            for r in 0..(m - q) {
                let w = sorted[r + q] - sorted[r];
                if w < width {
                    width = w;
                    best = r;
                }
            }
            [sorted[best], sorted[best + q]]
        }
    }
}

fn mean_std(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let ss = v.iter().map(|x| (x - m) * (x - m)).sum::<f64>();
    (m, (ss / (n - 1.0).max(1.0)).sqrt())
}

/// Average and standard deviation *of the average* of per-sequence values (JCGM 101 eq. 19).
fn mean_and_sd_of_mean(v: &[f64]) -> (f64, f64) {
    let h = v.len() as f64;
    let m = v.iter().sum::<f64>() / h;
    let ss = v.iter().map(|x| (x - m) * (x - m)).sum::<f64>();
    (m, (ss / (h * (h - 1.0))).sqrt())
}

/// Runs `n_blocks` blocks starting at global block `first_block`, returning values column-wise.
fn run_blocks<S: TrialSource>(
    src: &S,
    seed: u64,
    first_block: u64,
    n_blocks: usize,
) -> Vec<Vec<f64>> {
    let n_out = src.n_outputs();
    let mut buf = vec![0.0; n_blocks * BLOCK_TRIALS * n_out];
    buf.par_chunks_mut(BLOCK_TRIALS * n_out)
        .enumerate()
        .for_each_init(
            || src.scratch(),
            |scratch, (b, chunk)| {
                let mut rng = ChaCha8Rng::seed_from_u64(seed);
                rng.set_stream(first_block + b as u64);
                src.fill(&mut rng, scratch, chunk);
            },
        );
    let n = n_blocks * BLOCK_TRIALS;
    (0..n_out)
        .map(|j| (0..n).map(|t| buf[t * n_out + j]).collect())
        .collect()
}

fn check_finite(
    names: &[String],
    cols: &[Vec<f64>],
    trials_before: usize,
) -> Result<(), UncertaintyError> {
    for (j, col) in cols.iter().enumerate() {
        if let Some(t) = col.iter().position(|v| !v.is_finite()) {
            return Err(UncertaintyError::NonFinite {
                output: names[j].clone(),
                context: format!("in Monte Carlo trial {}", trials_before + t + 1),
            });
        }
    }
    Ok(())
}

/// Runs the Monte Carlo method on `src` (adaptive unless `opts.fixed_trials` is set).
pub fn run<S: TrialSource>(
    src: &S,
    opts: &McOptions,
    progress: Option<&(dyn Fn(&McProgress) + Sync)>,
) -> Result<McResult, UncertaintyError> {
    let p = opts.coverage_probability;
    if !(p > 0.0 && p < 1.0) {
        return Err(UncertaintyError::Invalid(format!(
            "coverage probability {p} must lie strictly between 0 and 1"
        )));
    }
    let names = src.output_names();
    let n_out = src.n_outputs();
    if let Some(t) = &opts.tolerance {
        if t.len() != n_out || t.iter().any(|v| !(*v > 0.0)) {
            return Err(UncertaintyError::Invalid(format!(
                "give one positive numerical tolerance per output ({n_out})"
            )));
        }
    }
    let mut all: Vec<Vec<f64>> = vec![Vec::new(); n_out];
    let mut sequences = 0;
    let mut converged = true;
    let mut stability: Vec<Option<[f64; 4]>> = vec![None; n_out];

    if let Some(m) = opts.fixed_trials {
        let n_blocks = m.max(1).div_ceil(BLOCK_TRIALS);
        // Report progress in slices of about a hundred blocks.
        let step = 100.max(n_blocks / 50);
        let mut done = 0;
        while done < n_blocks {
            let nb = step.min(n_blocks - done);
            let cols = run_blocks(src, opts.seed, done as u64, nb);
            check_finite(&names, &cols, done * BLOCK_TRIALS)?;
            for (a, c) in all.iter_mut().zip(cols) {
                a.extend(c);
            }
            done += nb;
            if let Some(cb) = progress {
                cb(&McProgress {
                    sequences: 1,
                    trials: done * BLOCK_TRIALS,
                    worst_ratio: None,
                    max_trials: n_blocks * BLOCK_TRIALS,
                });
            }
        }
        sequences = 1;
    } else {
        let m = sequence_trials(p);
        let blocks_per_seq = m / BLOCK_TRIALS;
        // Per output, per sequence: y, u, y_low, y_high.
        let mut seq_stats: Vec<Vec<[f64; 4]>> = vec![Vec::new(); n_out];
        loop {
            let cols = run_blocks(
                src,
                opts.seed,
                (sequences * blocks_per_seq) as u64,
                blocks_per_seq,
            );
            check_finite(&names, &cols, sequences * m)?;
            for (j, c) in cols.into_iter().enumerate() {
                let (mu, sd) = mean_std(&c);
                let mut s = c.clone();
                s.sort_unstable_by(f64::total_cmp);
                let [lo, hi] = coverage_interval(&s, p, opts.interval);
                seq_stats[j].push([mu, sd, lo, hi]);
                all[j].extend(c);
            }
            sequences += 1;
            let trials = sequences * m;
            let mut worst: Option<f64> = None;
            if sequences >= 2 {
                let mut ok = true;
                for j in 0..n_out {
                    let (_, u_all) = mean_std(&all[j]);
                    let delta = match &opts.tolerance {
                        Some(t) => t[j],
                        None => numerical_tolerance(u_all, opts.ndig),
                    };
                    let mut two_s = [0.0; 4];
                    for (k, ts) in two_s.iter_mut().enumerate() {
                        let v: Vec<f64> = seq_stats[j].iter().map(|s| s[k]).collect();
                        *ts = 2.0 * mean_and_sd_of_mean(&v).1;
                    }
                    stability[j] = Some(two_s);
                    if u_all == 0.0 {
                        continue; // a constant output is as stable as it gets
                    }
                    let r = two_s.iter().fold(0.0f64, |a, b| a.max(*b)) / delta;
                    worst = Some(worst.map_or(r, |w| w.max(r)));
                    if r > 1.0 {
                        ok = false;
                    }
                }
                if let Some(cb) = progress {
                    cb(&McProgress {
                        sequences,
                        trials,
                        worst_ratio: worst,
                        max_trials: opts.max_trials,
                    });
                }
                if ok {
                    break;
                }
            } else if let Some(cb) = progress {
                cb(&McProgress {
                    sequences,
                    trials,
                    worst_ratio: None,
                    max_trials: opts.max_trials,
                });
            }
            if trials + m > opts.max_trials {
                converged = false;
                break;
            }
        }
    }

    let trials = all.first().map_or(0, Vec::len);
    let means: Vec<f64> = all.iter().map(|c| mean_std(c).0).collect();
    let sds: Vec<f64> = all.iter().map(|c| mean_std(c).1).collect();
    let output_correlation = (0..n_out)
        .map(|a| {
            (0..n_out)
                .map(|b| {
                    if a == b {
                        return 1.0;
                    }
                    let cov = all[a]
                        .iter()
                        .zip(&all[b])
                        .map(|(x, y)| (x - means[a]) * (y - means[b]))
                        .sum::<f64>()
                        / (trials as f64 - 1.0);
                    let d = sds[a] * sds[b];
                    if d > 0.0 { cov / d } else { 0.0 }
                })
                .collect()
        })
        .collect();
    let mut outputs = Vec::with_capacity(n_out);
    for (j, col) in all.iter_mut().enumerate() {
        col.par_sort_unstable_by(f64::total_cmp);
        let tolerance = match &opts.tolerance {
            Some(t) => t[j],
            None => numerical_tolerance(sds[j], opts.ndig),
        };
        outputs.push(McOutput {
            name: names[j].clone(),
            estimate: means[j],
            standard_uncertainty: sds[j],
            symmetric_interval: coverage_interval(col, p, IntervalKind::Symmetric),
            shortest_interval: coverage_interval(col, p, IntervalKind::Shortest),
            tolerance,
            stability: stability[j],
        });
    }
    Ok(McResult {
        coverage_probability: p,
        trials,
        sequences,
        converged,
        outputs,
        output_correlation,
        sorted_values: all,
    })
}

/// Validates a GUM result against Monte Carlo (JCGM 101 §8.2), comparing the GUM interval
/// `y ± U_p` with the probabilistically symmetric Monte Carlo interval; δ comes from the GUM u(y)
/// with `ndig` significant digits.
pub fn validate(gum: &GumOutput, mc: &McOutput, ndig: u32) -> Validation {
    let [lo, hi] = mc.symmetric_interval;
    let d_low = (gum.interval[0] - lo).abs();
    let d_high = (gum.interval[1] - hi).abs();
    let tolerance = numerical_tolerance(gum.standard_uncertainty, ndig);
    Validation {
        output: gum.name.clone(),
        d_low,
        d_high,
        tolerance,
        passed: d_low <= tolerance && d_high <= tolerance,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tolerance_per_clause_7_9_2() {
        // JCGM 101 §7.9.2: u(y) = 1.02 with ndig = 2 is 10 × 10⁻¹, so δ = 0.05;
        // u = 0.0754 with ndig = 2 is 75 × 10⁻³, so δ = 0.0005.
        assert!((numerical_tolerance(1.02, 2) - 0.05).abs() < 1e-15);
        assert!((numerical_tolerance(0.0754, 2) - 0.0005).abs() < 1e-15);
        assert!((numerical_tolerance(0.0754, 1) - 0.005).abs() < 1e-15);
        assert!((numerical_tolerance(32.0, 2) - 0.5).abs() < 1e-15);
    }

    #[test]
    fn sequence_length_per_clause_7_9_4() {
        assert_eq!(sequence_trials(0.95), 10_000);
        assert_eq!(sequence_trials(0.99), 10_000);
        assert_eq!(sequence_trials(0.999), 100_000);
    }

    #[test]
    fn interval_indices_per_clause_7_7() {
        // M = 1000 values 1..=1000, p = 0.95: q = 950, r = 25 → [25, 975].
        let v: Vec<f64> = (1..=1000).map(f64::from).collect();
        assert_eq!(
            coverage_interval(&v, 0.95, IntervalKind::Symmetric),
            [25.0, 975.0]
        );
        // A skewed sample: the shortest interval hugs the dense end.
        let s: Vec<f64> = (1..=1000)
            .map(|i| (f64::from(i) / 1000.0).powi(3))
            .collect();
        let [lo, _] = coverage_interval(&s, 0.9, IntervalKind::Shortest);
        assert_eq!(lo, s[0]);
    }
}
