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

/// The most trials a run may be asked for (a budget's `trials`/`max_trials`, a command's
/// `--trials`): every trial's outputs are kept for the coverage intervals, so the count bounds
/// the memory (10⁷ trials: about 80 MB per output; 2⁶⁴ − 1 aborted on an exabyte allocation).
pub const MAX_TRIALS: usize = 20_000_000;

/// The most significant digits the adaptive tolerance may ask for (JCGM 101 §7.9.2 uses 1 or
/// 2): each further digit needs about 100 times the trials, so more only runs to the trial
/// limit without deciding anything.
pub const MAX_NDIG: u32 = 4;

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
    /// All model values of each output in trial order (for histograms and densities; not
    /// sorted: the intervals are found by selection).
    #[serde(skip)]
    pub values: Vec<Vec<f64>>,
}

/// The outcome of a validation (JCGM 101 §8.1) once the Monte Carlo endpoints' own numerical
/// uncertainty is accounted for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Verdict {
    /// Both d ≤ δ with a margin of [`DECISION_MARGIN`] standard errors of the endpoints.
    Validated,
    /// One d > δ by that margin: the GUM interval is not good enough at this tolerance.
    NotValidated,
    /// d is within the endpoints' numerical spread of δ: more trials would be needed to decide
    /// (the true d is close to δ; the answer would depend on the seed).
    Undecided,
}

/// Standard errors of the Monte Carlo endpoints that must separate d from δ before a verdict is
/// given: with 3, a verdict flips with another seed in fewer than about 1 run in 700 even when
/// the true d sits right at the margin.
pub const DECISION_MARGIN: f64 = 3.0;

/// Validation of a GUM result by Monte Carlo (JCGM 101 §8.1), see [`validate`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Validation {
    pub output: String,
    /// Coverage factor of the GUM interval compared: k_p for the Monte Carlo's coverage
    /// probability from ν_eff (JCGM 100 G.4), which is not the reported k when the budget fixes
    /// one (k = 2 is a 95.45 % interval for a normal output, not a 95 % one).
    pub coverage_factor: f64,
    /// The GUM interval compared, y ± k_p·u(y).
    pub gum_interval: [f64; 2],
    /// The Monte Carlo probabilistically symmetric interval.
    pub mc_interval: [f64; 2],
    /// |y − U_p − y_low|.
    pub d_low: f64,
    /// |y + U_p − y_high|.
    pub d_high: f64,
    /// Numerical tolerance δ associated with the GUM u(y) (JCGM 101 §7.9.2, ndig digits).
    pub tolerance: f64,
    /// Standard errors of the Monte Carlo endpoints (from the order statistics around them).
    pub endpoint_standard_error: [f64; 2],
    pub verdict: Verdict,
    /// `verdict == Validated`.
    pub passed: bool,
    /// Why the compared GUM interval differs from the reported one, if it does.
    pub note: Option<String>,
}

impl Validation {
    /// One line for reports.
    pub fn message(&self) -> String {
        let v = match self.verdict {
            Verdict::Validated => "validated".to_string(),
            Verdict::NotValidated => "NOT validated: use the Monte Carlo result".to_string(),
            Verdict::Undecided => format!(
                "undecided: d is within {DECISION_MARGIN} numerical standard errors \
                 ({:.2e}, {:.2e}) of δ; run more trials (settings.max_trials) to decide",
                self.endpoint_standard_error[0], self.endpoint_standard_error[1]
            ),
        };
        match &self.note {
            Some(n) => format!("{v} ({n})"),
            None => v,
        }
    }
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

/// Count, mean and sum of squared deviations of a set of values; two sets merge exactly
/// (Chan, Golub and LeVeque), so the statistics of all h·M values are kept without passing
/// over them again after each sequence.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Moments {
    n: f64,
    mean: f64,
    m2: f64,
}

impl Moments {
    fn of(v: &[f64]) -> Moments {
        let n = v.len() as f64;
        if v.is_empty() {
            return Moments::default();
        }
        let mean = v.iter().sum::<f64>() / n;
        let m2 = v.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>();
        Moments { n, mean, m2 }
    }

    fn merge(self, o: Moments) -> Moments {
        if self.n == 0.0 {
            return o;
        }
        if o.n == 0.0 {
            return self;
        }
        let n = self.n + o.n;
        let d = o.mean - self.mean;
        Moments {
            n,
            mean: self.mean + d * o.n / n,
            m2: self.m2 + o.m2 + d * d * self.n * o.n / n,
        }
    }

    /// Standard deviation with n − 1 (JCGM 101 eq. 16).
    fn sd(&self) -> f64 {
        (self.m2 / (self.n - 1.0).max(1.0)).sqrt()
    }
}

/// Standard deviation *of the average* of per-sequence values (JCGM 101 eq. 19).
fn sd_of_mean(v: &[f64]) -> f64 {
    let h = v.len() as f64;
    let m = v.iter().sum::<f64>() / h;
    let ss = v.iter().map(|x| (x - m) * (x - m)).sum::<f64>();
    (ss / (h * (h - 1.0))).sqrt()
}

/// The order statistics of the 0-based `ranks` (ascending, distinct) of `v`, by nested
/// selections (`v` is reordered): each step selects the rank that splits the remaining part
/// most evenly and goes on in the two sides, so ranks in the two tails cost about two passes,
/// not one each.
fn order_stats(v: &mut [f64], ranks: &[usize], out: &mut Vec<f64>) {
    let Some(mid) = (0..ranks.len()).min_by_key(|&i| ranks[i].abs_diff(v.len() / 2)) else {
        return;
    };
    if v.is_empty() {
        return;
    }
    let r = ranks[mid].min(v.len() - 1);
    let (left, x, right) = v.select_nth_unstable_by(r, f64::total_cmp);
    let x = *x;
    order_stats(left, &ranks[..mid], out);
    out.push(x);
    let shifted: Vec<usize> = ranks[mid + 1..].iter().map(|k| k - r - 1).collect();
    order_stats(right, &shifted, out);
}

/// The order statistics of 0-based ranks `a ≤ b` of `v` (reordered in place).
fn two_order_stats(v: &mut [f64], a: usize, b: usize) -> (f64, f64) {
    if a >= b {
        let x = *v.select_nth_unstable_by(a, f64::total_cmp).1;
        return (x, x);
    }
    let mut out = Vec::with_capacity(2);
    order_stats(v, &[a, b], &mut out);
    (out[0], out[1])
}

/// q = pM if an integer, else the integer part of pM + 1/2 (JCGM 101 §7.7.1).
fn coverage_count(m: usize, p: f64) -> usize {
    (((p * m as f64) + 0.5).floor() as usize).clamp(1, m.saturating_sub(1).max(1))
}

/// The coverage interval of unsorted `v` (reordered in place), the same values as
/// [`coverage_interval`] of the sorted values. The symmetric interval needs two selections;
/// the shortest one only the lowest and highest M − q values in order (its start lies among
/// the lowest M − q, its end among the highest), which are selected, then sorted: for p = 0.95
/// a tenth of the values is sorted instead of all.
pub fn coverage_interval_unsorted(v: &mut [f64], p: f64, kind: IntervalKind) -> [f64; 2] {
    let m = v.len();
    if m < 2 {
        return v.first().map_or([f64::NAN; 2], |x| [*x, *x]);
    }
    let q = coverage_count(m, p);
    match kind {
        IntervalKind::Symmetric => {
            let ([a, b], _) = symmetric_indices(m, p);
            let (lo, hi) = two_order_stats(v, a, b);
            [lo, hi]
        }
        IntervalKind::Shortest => {
            let tail = m - q;
            if q < tail + 1 {
                v.sort_unstable_by(f64::total_cmp);
                return coverage_interval(v, p, kind);
            }
            v.select_nth_unstable_by(tail, f64::total_cmp);
            v[..tail].sort_unstable_by(f64::total_cmp);
            v[tail..].select_nth_unstable_by(q - tail, f64::total_cmp);
            v[q..].sort_unstable_by(f64::total_cmp);
            let best = (0..tail)
                .min_by(|&r, &s| (v[r + q] - v[r]).total_cmp(&(v[s + q] - v[s])))
                .unwrap_or(0);
            [v[best], v[best + q]]
        }
    }
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
        .into_par_iter()
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
    run_until(src, opts, progress, &|_| true)
}

fn check_options(opts: &McOptions, n_out: usize) -> Result<(), UncertaintyError> {
    let p = opts.coverage_probability;
    if !(p > 0.0 && p < 1.0) {
        return Err(UncertaintyError::Invalid(format!(
            "coverage probability {p} must lie strictly between 0 and 1"
        )));
    }
    if let Some(t) = &opts.tolerance
        && (t.len() != n_out || t.iter().any(|v| v.is_nan() || *v <= 0.0))
    {
        return Err(UncertaintyError::Invalid(format!(
            "give one positive numerical tolerance per output ({n_out})"
        )));
    }
    Ok(())
}

/// The values of a run so far, per output, and what the adaptive procedure keeps of them.
struct Accumulator {
    values: Vec<Vec<f64>>,
    moments: Vec<Moments>,
    /// Per output, per sequence: y, u(y), y_low, y_high (JCGM 101 §7.9.4 c).
    sequences: Vec<Vec<[f64; 4]>>,
}

impl Accumulator {
    fn new(n_out: usize) -> Accumulator {
        Accumulator {
            values: vec![Vec::new(); n_out],
            moments: vec![Moments::default(); n_out],
            sequences: vec![Vec::new(); n_out],
        }
    }

    fn trials(&self) -> usize {
        self.values.first().map_or(0, Vec::len)
    }

    /// Adds one sequence's values (column-wise); with `stats`, its y, u(y) and interval too.
    fn push(&mut self, cols: Vec<Vec<f64>>, stats: Option<(f64, IntervalKind)>) {
        let per: Vec<(Moments, Option<[f64; 2]>)> = cols
            .par_iter()
            .map(|c| {
                let iv = stats.map(|(p, kind)| coverage_interval_unsorted(&mut c.clone(), p, kind));
                (Moments::of(c), iv)
            })
            .collect();
        for (j, (c, (mo, iv))) in cols.into_iter().zip(per).enumerate() {
            if let Some([lo, hi]) = iv {
                self.sequences[j].push([mo.mean, mo.sd(), lo, hi]);
            }
            self.moments[j] = self.moments[j].merge(mo);
            self.values[j].extend(c);
        }
    }

    /// 2·s of the sequence averages of y, u(y), y_low, y_high for output `j` (§7.9.4 f–g).
    fn two_s(&self, j: usize) -> [f64; 4] {
        let mut two_s = [0.0; 4];
        for (k, ts) in two_s.iter_mut().enumerate() {
            let v: Vec<f64> = self.sequences[j].iter().map(|s| s[k]).collect();
            *ts = 2.0 * sd_of_mean(&v);
        }
        two_s
    }
}

/// The stabilisation check of JCGM 101 §7.9.4 after h ≥ 2 sequences: δ from u(y) of all h·M
/// values (or the given tolerance), stabilised when every 2s ≤ δ for every output. Returns
/// the largest 2s/δ and the 2s per output.
fn stabilisation(acc: &Accumulator, opts: &McOptions) -> (Option<f64>, Vec<[f64; 4]>) {
    let mut worst: Option<f64> = None;
    let mut all_two_s = Vec::with_capacity(acc.values.len());
    for j in 0..acc.values.len() {
        let u_all = acc.moments[j].sd();
        let delta = match &opts.tolerance {
            Some(t) => t[j],
            None => numerical_tolerance(u_all, opts.ndig),
        };
        let two_s = acc.two_s(j);
        all_two_s.push(two_s);
        if u_all == 0.0 {
            continue; // a constant output is as stable as it gets
        }
        let r = two_s.iter().fold(0.0f64, |a, b| a.max(*b)) / delta;
        worst = Some(worst.map_or(r, |w| w.max(r)));
    }
    (worst, all_two_s)
}

/// [`run`], where the adaptive procedure also waits for `also_done(values so far, per output)`
/// before it stops (a validation that must be decided, JCGM 101 §8.2). `also_done` costs a
/// pass over all values, so it is asked when the run is stabilised and then only each time the
/// number of trials has grown by a quarter (at most a quarter more trials than needed, and the
/// checks cost a fixed multiple of one pass instead of one pass per sequence).
///
/// `converged` in the result says whether the §7.9 criterion was met when the run stopped; a
/// run that reached `max_trials` while stabilised but waiting for `also_done` is converged.
pub fn run_until<S: TrialSource>(
    src: &S,
    opts: &McOptions,
    progress: Option<&(dyn Fn(&McProgress) + Sync)>,
    also_done: &dyn Fn(&[Vec<f64>]) -> bool,
) -> Result<McResult, UncertaintyError> {
    let names = src.output_names();
    check_options(opts, names.len())?;
    let mut acc = Accumulator::new(src.n_outputs());
    let (sequences, converged, stability) = match opts.fixed_trials {
        Some(m) => {
            run_fixed(src, opts, &names, m, &mut acc, progress)?;
            (1, true, vec![None; names.len()])
        }
        None => run_adaptive(src, opts, &names, &mut acc, progress, also_done)?,
    };
    Ok(summarise(
        acc.values, &names, opts, &stability, sequences, converged,
    ))
}

fn run_fixed<S: TrialSource>(
    src: &S,
    opts: &McOptions,
    names: &[String],
    m: usize,
    acc: &mut Accumulator,
    progress: Option<&(dyn Fn(&McProgress) + Sync)>,
) -> Result<(), UncertaintyError> {
    let n_blocks = m.max(1).div_ceil(BLOCK_TRIALS);
    // Report progress in slices of about a hundred blocks.
    let step = 100.max(n_blocks / 50);
    let mut done = 0;
    while done < n_blocks {
        let nb = step.min(n_blocks - done);
        let cols = run_blocks(src, opts.seed, done as u64, nb);
        check_finite(names, &cols, done * BLOCK_TRIALS)?;
        acc.push(cols, None);
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
    Ok(())
}

type AdaptiveOutcome = (usize, bool, Vec<Option<[f64; 4]>>);

fn run_adaptive<S: TrialSource>(
    src: &S,
    opts: &McOptions,
    names: &[String],
    acc: &mut Accumulator,
    progress: Option<&(dyn Fn(&McProgress) + Sync)>,
    also_done: &dyn Fn(&[Vec<f64>]) -> bool,
) -> Result<AdaptiveOutcome, UncertaintyError> {
    let p = opts.coverage_probability;
    let m = sequence_trials(p);
    let blocks_per_seq = m / BLOCK_TRIALS;
    let mut sequences = 0;
    let mut stable = false;
    let mut stability = vec![None; names.len()];
    let mut next_check = 0;
    loop {
        let first = (sequences * blocks_per_seq) as u64;
        let cols = run_blocks(src, opts.seed, first, blocks_per_seq);
        check_finite(names, &cols, sequences * m)?;
        acc.push(cols, Some((p, opts.interval)));
        sequences += 1;
        let trials = acc.trials();
        let mut worst = None;
        if sequences >= 2 {
            let (w, two_s) = stabilisation(acc, opts);
            worst = w;
            stability = two_s.into_iter().map(Some).collect();
            stable = w.is_none_or(|r| r <= 1.0);
        }
        if let Some(cb) = progress {
            cb(&McProgress {
                sequences,
                trials,
                worst_ratio: worst,
                max_trials: opts.max_trials,
            });
        }
        if stable && trials >= next_check {
            if also_done(&acc.values) {
                break;
            }
            next_check = trials + trials / 4;
        }
        if trials + m > opts.max_trials {
            break;
        }
    }
    Ok((sequences, stable, stability))
}

/// Correlation coefficients of the columns (pairs computed in parallel).
fn correlations(all: &[Vec<f64>], moments: &[Moments]) -> Vec<Vec<f64>> {
    let n_out = all.len();
    let pairs: Vec<(usize, usize)> = (0..n_out)
        .flat_map(|a| (a + 1..n_out).map(move |b| (a, b)))
        .collect();
    let r: Vec<f64> = pairs
        .par_iter()
        .map(|&(a, b)| {
            let (ma, mb) = (moments[a].mean, moments[b].mean);
            let cov: f64 = all[a]
                .iter()
                .zip(&all[b])
                .map(|(x, y)| (x - ma) * (y - mb))
                .sum();
            let d = moments[a].m2.sqrt() * moments[b].m2.sqrt();
            if d > 0.0 { cov / d } else { 0.0 }
        })
        .collect();
    let mut c = vec![vec![1.0; n_out]; n_out];
    for (&(a, b), v) in pairs.iter().zip(r) {
        c[a][b] = v;
        c[b][a] = v;
    }
    c
}

/// The statistics of a finished run from its model values per output (JCGM 101 §7.5–7.7):
/// one pass for the moments, selections for the intervals, no full sort.
fn summarise(
    all: Vec<Vec<f64>>,
    names: &[String],
    opts: &McOptions,
    stability: &[Option<[f64; 4]>],
    sequences: usize,
    converged: bool,
) -> McResult {
    let p = opts.coverage_probability;
    let trials = all.first().map_or(0, Vec::len);
    let per: Vec<(Moments, [f64; 2], [f64; 2])> = all
        .par_iter()
        .map(|c| {
            let mut s = c.clone();
            let sym = coverage_interval_unsorted(&mut s, p, IntervalKind::Symmetric);
            let short = coverage_interval_unsorted(&mut s, p, IntervalKind::Shortest);
            (Moments::of(c), sym, short)
        })
        .collect();
    let moments: Vec<Moments> = per.iter().map(|x| x.0).collect();
    let output_correlation = correlations(&all, &moments);
    let outputs = per
        .iter()
        .enumerate()
        .map(|(j, &(mo, sym, short))| McOutput {
            name: names[j].clone(),
            estimate: mo.mean,
            standard_uncertainty: mo.sd(),
            symmetric_interval: sym,
            shortest_interval: short,
            tolerance: match &opts.tolerance {
                Some(t) => t[j],
                None => numerical_tolerance(mo.sd(), opts.ndig),
            },
            stability: stability[j],
        })
        .collect();
    McResult {
        coverage_probability: p,
        trials,
        sequences,
        converged,
        outputs,
        output_correlation,
        values: all,
    }
}

/// Indices (0-based) of the probabilistically symmetric interval's endpoints in `m` sorted
/// values (JCGM 101 §7.7.2), and the index distance of one standard error of each endpoint:
/// the number of values below an endpoint is binomial(m, α), so its standard deviation in
/// index is √(m·α·(1−α)).
fn symmetric_indices(m: usize, p: f64) -> ([usize; 2], usize) {
    let q = coverage_count(m, p);
    let r = (m - q).div_ceil(2).max(1);
    let alpha = 0.5 * (1.0 - p);
    let k = (m as f64 * alpha * (1.0 - alpha)).sqrt().ceil().max(1.0) as usize;
    ([r - 1, (r - 1 + q).min(m - 1)], k)
}

/// The symmetric interval of unsorted `values` and its endpoints' standard errors, without a
/// full sort (selection), for the checks made while a run goes on.
fn interval_with_errors(values: &[f64], p: f64) -> ([f64; 2], [f64; 2]) {
    let m = values.len();
    if m < 3 {
        return ([f64::NAN; 2], [f64::INFINITY; 2]);
    }
    let ([a, b], k) = symmetric_indices(m, p);
    let top = m - 1;
    let ranks = [
        a.saturating_sub(k),
        a,
        (a + k).min(top),
        b.saturating_sub(k),
        b,
        (b + k).min(top),
    ];
    // Distinct ascending ranks for the selection, then each looked up.
    let mut distinct = ranks.to_vec();
    distinct.sort_unstable();
    distinct.dedup();
    let mut found = Vec::with_capacity(distinct.len());
    order_stats(&mut values.to_vec(), &distinct, &mut found);
    let at = |r: usize| found[distinct.binary_search(&r).unwrap_or(0)];
    let (lo, hi) = (at(ranks[1]), at(ranks[4]));
    let se_lo = 0.5 * (at(ranks[2]) - at(ranks[0]));
    let se_hi = 0.5 * (at(ranks[5]) - at(ranks[3]));
    ([lo, hi], [se_lo, se_hi])
}

/// The GUM interval compared in a validation: y ± k_p·u with k_p for probability `p` and the
/// output's ν_eff, and a note when that is not the interval the GUM result reports.
fn gum_interval_at(gum: &GumOutput, p: f64) -> (f64, [f64; 2], Option<String>) {
    let k = super::gum::coverage_factor(p, gum.dof_eff);
    let u = k * gum.standard_uncertainty;
    let note = ((k - gum.coverage_factor).abs() > 1e-9).then(|| {
        format!(
            "the reported U uses k = {:.3}; the GUM interval for p = {:.2} % compared here \
             uses k = {k:.3}",
            gum.coverage_factor,
            100.0 * p
        )
    });
    (k, [gum.estimate - u, gum.estimate + u], note)
}

/// Validates a GUM result against Monte Carlo (JCGM 101 §8.1): the GUM interval y ± U_p for the
/// Monte Carlo's coverage probability `p` is compared with the probabilistically symmetric
/// Monte Carlo interval of `values` (this output's model values, sorted or not); δ comes from
/// the GUM u(y) with `ndig` significant digits. The verdict accounts for the numerical spread
/// of the Monte Carlo endpoints so that it does not depend on the seed (see [`Verdict`]).
pub fn validate(gum: &GumOutput, values: &[f64], p: f64, ndig: u32) -> Validation {
    let (coverage_factor, gum_interval, note) = gum_interval_at(gum, p);
    let (mc_interval, se) = interval_with_errors(values, p);
    let d_low = (gum_interval[0] - mc_interval[0]).abs();
    let d_high = (gum_interval[1] - mc_interval[1]).abs();
    let tolerance = numerical_tolerance(gum.standard_uncertainty, ndig);
    let m = DECISION_MARGIN;
    let verdict = if d_low + m * se[0] <= tolerance && d_high + m * se[1] <= tolerance {
        Verdict::Validated
    } else if d_low - m * se[0] > tolerance || d_high - m * se[1] > tolerance {
        Verdict::NotValidated
    } else {
        Verdict::Undecided
    };
    Validation {
        output: gum.name.clone(),
        coverage_factor,
        gum_interval,
        mc_interval,
        d_low,
        d_high,
        tolerance,
        endpoint_standard_error: se,
        verdict,
        passed: verdict == Verdict::Validated,
        note,
    }
}

/// The Monte Carlo run for validating `gum` (JCGM 101 §8.2): the adaptive procedure of §7.9
/// with the numerical tolerance δ of each GUM u(y) (`ndig` digits), continued until every
/// output's verdict is decided (or `opts.max_trials` is reached). A fixed number of trials in
/// `opts` is run as given. Returns the run and the validations.
///
/// §8.2 recommends running the adaptive procedure with δ/5 so that the Monte Carlo's own
/// numerical error is negligible in the comparison. Here that error is accounted for
/// explicitly instead: a verdict needs d and δ to differ by [`DECISION_MARGIN`] standard errors
/// of the endpoints, and the run goes on until they do. This is what makes the verdict the
/// same for every seed (JCGM 101 9.2.3 has d = 0.0405 against δ = 0.05: a margin of 0.0095,
/// about two endpoint standard errors of a δ/5 run), and it spares the 16 million trials δ/5
/// costs for 9.3, whose d is 90 δ.
/// See docs/methods.md, "Validation of a GUM result".
pub fn run_for_validation<S: TrialSource>(
    src: &S,
    gum: &[GumOutput],
    opts: &McOptions,
    progress: Option<&(dyn Fn(&McProgress) + Sync)>,
) -> Result<(McResult, Vec<Validation>), UncertaintyError> {
    let p = opts.coverage_probability;
    let ndig = opts.ndig;
    let mut o = opts.clone();
    if o.tolerance.is_none() && o.fixed_trials.is_none() {
        // A zero-uncertainty output has no tolerance; any positive value stops it at once.
        let t = gum
            .iter()
            .map(|g| numerical_tolerance(g.standard_uncertainty, ndig))
            .map(|v| if v > 0.0 { v } else { 1.0 })
            .collect();
        o.tolerance = Some(t);
    }
    let decided = |cols: &[Vec<f64>]| {
        gum.iter()
            .zip(cols)
            .all(|(g, c)| validate(g, c, p, ndig).verdict != Verdict::Undecided)
    };
    let r = run_until(src, &o, progress, &decided)?;
    let v = gum
        .iter()
        .zip(&r.values)
        .map(|(g, c)| validate(g, c, p, ndig))
        .collect();
    Ok((r, v))
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

    /// Values with ties and a skew, in a scrambled order.
    fn scrambled(m: usize) -> Vec<f64> {
        (0..m)
            .map(|i| {
                let k = (i * 7919 + 13) % m;
                ((k / 3) as f64 / m as f64).powi(3)
            })
            .collect()
    }

    #[test]
    fn intervals_by_selection_equal_the_sorted_ones() {
        for m in [2, 3, 10, 101, 1000, 10_007] {
            let v = scrambled(m);
            let mut sorted = v.clone();
            sorted.sort_unstable_by(f64::total_cmp);
            for p in [0.5, 0.9, 0.95, 0.99] {
                for kind in [IntervalKind::Symmetric, IntervalKind::Shortest] {
                    let want = coverage_interval(&sorted, p, kind);
                    let got = coverage_interval_unsorted(&mut v.clone(), p, kind);
                    assert_eq!(got, want, "m {m} p {p} {kind:?}");
                }
            }
        }
    }

    #[test]
    fn nested_selection_finds_every_rank() {
        let v = scrambled(5000);
        let mut sorted = v.clone();
        sorted.sort_unstable_by(f64::total_cmp);
        let ranks = [0, 3, 124, 125, 126, 2500, 4874, 4875, 4999];
        let mut out = Vec::new();
        order_stats(&mut v.clone(), &ranks, &mut out);
        let want: Vec<f64> = ranks.iter().map(|&r| sorted[r]).collect();
        assert_eq!(out, want);
    }

    #[test]
    fn merged_moments_equal_those_of_the_whole() {
        let v = scrambled(3001);
        let whole = Moments::of(&v);
        let merged = Moments::of(&v[..1000])
            .merge(Moments::of(&v[1000..2999]))
            .merge(Moments::of(&v[2999..]));
        assert!((whole.mean - merged.mean).abs() < 1e-15);
        assert!((whole.sd() - merged.sd()).abs() < 1e-14);
        assert_eq!(whole.n, merged.n);
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
