//! Runs measured in blocks: each target and direction approached several times in a row (a
//! repeatability test target by target) instead of in the interleaved ISO 230-2 order. The
//! per-target, per-direction baseline then absorbs any drift over the run, but a trend within
//! the blocks is still in the residuals, and the data cannot say whether it follows time or
//! the count of repeated approaches. [`within_block_trend`] measures it and says so: a note,
//! never a finding (the blocks and their pace are [`Obs::blocks`] and [`Obs::block_pair_s`]).

use statrs::distribution::{ContinuousCDF, FisherSnedecor};

use super::fit::FinalFit;
use super::obs::{MIN_BLOCK, Obs};

/// A trend within the blocks is reported when a common slope per direction explains more
/// of the residuals than noise would at this false-alarm level (F test).
const P_TREND: f64 = 1e-3;

/// A slope per direction of the residuals against the approach's number within its block.
struct Trend {
    /// Per approach, µm: positive approaches, negative approaches.
    slope: [f64; 2],
    t: [f64; 2],
    p: f64,
}

fn trend(obs: &Obs, fin: &FinalFit, blocks: &[Vec<usize>]) -> Option<Trend> {
    // Sums by direction: Σ (k − k̄)², Σ (k − k̄)(r − r̄), and the residuals' SS within blocks.
    let (mut sxx, mut sxy, mut syy) = ([0.0; 2], [0.0; 2], 0.0);
    let (mut n, mut n_blocks) = (0usize, 0usize);
    for b in blocks {
        let used: Vec<(f64, f64)> = b
            .iter()
            .enumerate()
            .filter(|(_, j)| !fin.out[**j])
            .map(|(k, &j)| (k as f64, fin.resid[j]))
            .collect();
        if used.len() < MIN_BLOCK {
            continue;
        }
        let d = usize::from(obs.dir_half[b[0]] < 0.0);
        let m = used.len() as f64;
        let (kb, rb) = (
            used.iter().map(|u| u.0).sum::<f64>() / m,
            used.iter().map(|u| u.1).sum::<f64>() / m,
        );
        for (k, r) in &used {
            sxx[d] += (k - kb).powi(2);
            sxy[d] += (k - kb) * (r - rb);
            syy += (r - rb).powi(2);
        }
        n += used.len();
        n_blocks += 1;
    }
    let dof = n.checked_sub(n_blocks + 2).filter(|d| *d > 0)? as f64;
    if sxx.iter().any(|s| *s <= 0.0) {
        return None;
    }
    let slope = [sxy[0] / sxx[0], sxy[1] / sxx[1]];
    let explained = slope[0] * sxy[0] + slope[1] * sxy[1];
    let s2 = (syy - explained).max(0.0) / dof;
    if s2 <= 0.0 {
        return None;
    }
    let f = FisherSnedecor::new(2.0, dof).ok()?;
    Some(Trend {
        slope,
        t: [
            slope[0] / (s2 / sxx[0]).sqrt(),
            slope[1] / (s2 / sxx[1]).sqrt(),
        ],
        p: f.sf(explained / 2.0 / s2),
    })
}

/// The note on a clear trend within the blocks of a run measured in blocks (None otherwise).
pub(super) fn within_block_trend(obs: &Obs, fin: &FinalFit) -> Option<String> {
    let blocks = obs.blocks()?;
    let tr = trend(obs, fin, &blocks)?;
    if tr.p >= P_TREND {
        return None;
    }
    let signs = if tr.slope[0].signum() == tr.slope[1].signum() {
        "the same sign in both directions would point to a drift during the run"
    } else {
        "opposite signs in the two directions point to a reversal value that changes \
         (lost motion building up, or a change in time)"
    };
    let (lo, hi) = (
        blocks.iter().map(Vec::len).min().unwrap_or(0),
        blocks.iter().map(Vec::len).max().unwrap_or(0),
    );
    let size = if lo == hi {
        lo.to_string()
    } else {
        format!("{lo}–{hi}")
    };
    Some(format!(
        "each target and direction is measured in one block of {size} repeated approaches, and \
         within the blocks the readings trend: {:+.3} µm per approach in positive approaches \
         (t = {:.1}), {:+.3} µm in negative ones (t = {:.1}); F test p = {:.1e}. The \
         per-target, per-direction baseline takes any change over the run, so the data cannot \
         tell whether this follows time or the count of repeated approaches (creep or settling \
         that builds up with each approach); {signs}. It is not an effect of the vocabulary and \
         is not reported as one: measure the targets interleaved (the ISO 230-2 order) to tell \
         the two apart",
        tr.slope[0], tr.t[0], tr.slope[1], tr.t[1], tr.p,
    ))
}
