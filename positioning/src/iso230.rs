//! ISO 230-2:2014 evaluation of positioning accuracy and repeatability of one linear axis
//! (clauses 3.x of the standard, as summarised in `docs/methods.md` §000).
//!
//! Readings missing from a target (beam interruption) only reduce that target's sample; a
//! statistic that cannot be computed (fewer than two readings for a scatter, no reading in one
//! direction for a reversal) is `None` and the axis values are taken over the targets that
//! have it, which the caller reports.

use serde::{Deserialize, Serialize};

use crate::positioning_data::PositioningData;

/// ISO 230-2 statistics of one target, µm.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TargetStats {
    /// Target number, 1..m.
    pub index: usize,
    pub target_mm: f64,
    /// Readings used per direction.
    pub n_up: usize,
    pub n_down: usize,
    /// Mean unidirectional positional deviation x̄↑, x̄↓.
    pub mean_up_um: Option<f64>,
    pub mean_down_um: Option<f64>,
    /// Estimators of the unidirectional standard uncertainty of positioning s↑, s↓ (n − 1).
    pub s_up_um: Option<f64>,
    pub s_down_um: Option<f64>,
    /// Reversal value B_i = x̄↑ − x̄↓.
    pub b_um: Option<f64>,
    /// Unidirectional repeatability R↑_i = 4 s↑, R↓_i = 4 s↓.
    pub r_up_um: Option<f64>,
    pub r_down_um: Option<f64>,
    /// Bidirectional repeatability R_i = max(2s↑ + 2s↓ + |B_i|, R↑_i, R↓_i).
    pub r_um: Option<f64>,
    /// Mean bidirectional positional deviation x̄_i = (x̄↑ + x̄↓)/2.
    pub mean_um: Option<f64>,
}

/// ISO 230-2 results for the axis, µm. Serialised with the standard's symbols as keys.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AxisStats {
    /// Reversal value of the axis, max |B_i|.
    #[serde(rename = "B")]
    pub b: Option<f64>,
    /// Mean reversal value B̄ (mean of B_i).
    #[serde(rename = "B_mean")]
    pub b_mean: Option<f64>,
    #[serde(rename = "R_up")]
    pub r_up: Option<f64>,
    #[serde(rename = "R_down")]
    pub r_down: Option<f64>,
    #[serde(rename = "R")]
    pub r: Option<f64>,
    /// Unidirectional systematic positional deviation E↑ = max x̄↑ − min x̄↑.
    #[serde(rename = "E_up")]
    pub e_up: Option<f64>,
    #[serde(rename = "E_down")]
    pub e_down: Option<f64>,
    /// Bidirectional systematic positional deviation E = max(x̄↑, x̄↓) − min(x̄↑, x̄↓).
    #[serde(rename = "E")]
    pub e: Option<f64>,
    /// Range of the mean bidirectional positional deviation M = max x̄_i − min x̄_i.
    #[serde(rename = "M")]
    pub m: Option<f64>,
    /// Unidirectional accuracy A↑ = max(x̄↑ + 2s↑) − min(x̄↑ − 2s↑).
    #[serde(rename = "A_up")]
    pub a_up: Option<f64>,
    #[serde(rename = "A_down")]
    pub a_down: Option<f64>,
    /// Bidirectional accuracy A over both directions.
    #[serde(rename = "A")]
    pub a: Option<f64>,
}

/// The ISO 230-2 evaluation of a run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Iso230Report {
    pub axis: AxisStats,
    pub targets: Vec<TargetStats>,
}

fn mean_std(v: &[f64]) -> (Option<f64>, Option<f64>) {
    let n = v.len();
    if n == 0 {
        return (None, None);
    }
    let m = v.iter().sum::<f64>() / n as f64;
    if n < 2 {
        return (Some(m), None);
    }
    let ss = v.iter().map(|x| (x - m) * (x - m)).sum::<f64>();
    (Some(m), Some((ss / (n as f64 - 1.0)).sqrt()))
}

fn both<F: Fn(f64, f64) -> f64>(a: Option<f64>, b: Option<f64>, f: F) -> Option<f64> {
    Some(f(a?, b?))
}

fn max_of(it: impl Iterator<Item = Option<f64>>) -> Option<f64> {
    it.flatten()
        .fold(None, |acc, v| Some(acc.map_or(v, |a: f64| a.max(v))))
}

fn min_of(it: impl Iterator<Item = Option<f64>>) -> Option<f64> {
    it.flatten()
        .fold(None, |acc, v| Some(acc.map_or(v, |a: f64| a.min(v))))
}

/// Evaluates a run by ISO 230-2.
pub fn evaluate(data: &PositioningData) -> Iso230Report {
    let grid = data.grid();
    let targets_mm = data.targets_mm();
    let targets: Vec<TargetStats> = (0..data.n_targets())
        .map(|i| {
            let up: Vec<f64> = grid[0][i].iter().flatten().copied().collect();
            let down: Vec<f64> = grid[1][i].iter().flatten().copied().collect();
            let (mean_up_um, s_up_um) = mean_std(&up);
            let (mean_down_um, s_down_um) = mean_std(&down);
            let b_um = both(mean_up_um, mean_down_um, |a, b| a - b);
            let r_up_um = s_up_um.map(|s| 4.0 * s);
            let r_down_um = s_down_um.map(|s| 4.0 * s);
            let r_um = match (s_up_um, s_down_um, b_um) {
                (Some(su), Some(sd), Some(b)) => {
                    Some((2.0 * su + 2.0 * sd + b.abs()).max(4.0 * su).max(4.0 * sd))
                }
                _ => None,
            };
            TargetStats {
                index: i + 1,
                target_mm: targets_mm[i],
                n_up: up.len(),
                n_down: down.len(),
                mean_up_um,
                mean_down_um,
                s_up_um,
                s_down_um,
                b_um,
                r_up_um,
                r_down_um,
                r_um,
                mean_um: both(mean_up_um, mean_down_um, |a, b| 0.5 * (a + b)),
            }
        })
        .collect();
    let t = &targets;
    let range = |f: &dyn Fn(&TargetStats) -> Option<f64>| {
        both(max_of(t.iter().map(f)), min_of(t.iter().map(f)), |a, b| {
            a - b
        })
    };
    let n_b = t.iter().filter(|x| x.b_um.is_some()).count();
    let hi = |m: Option<f64>, s: Option<f64>| both(m, s, |m, s| m + 2.0 * s);
    let lo = |m: Option<f64>, s: Option<f64>| both(m, s, |m, s| m - 2.0 * s);
    let a_dir = |up: bool| {
        let pick = |x: &TargetStats| {
            if up {
                (x.mean_up_um, x.s_up_um)
            } else {
                (x.mean_down_um, x.s_down_um)
            }
        };
        both(
            max_of(t.iter().map(|x| hi(pick(x).0, pick(x).1))),
            min_of(t.iter().map(|x| lo(pick(x).0, pick(x).1))),
            |a, b| a - b,
        )
    };
    let axis = AxisStats {
        b: max_of(t.iter().map(|x| x.b_um.map(f64::abs))),
        b_mean: (n_b > 0).then(|| t.iter().filter_map(|x| x.b_um).sum::<f64>() / n_b as f64),
        r_up: max_of(t.iter().map(|x| x.r_up_um)),
        r_down: max_of(t.iter().map(|x| x.r_down_um)),
        r: max_of(t.iter().map(|x| x.r_um)),
        e_up: range(&|x| x.mean_up_um),
        e_down: range(&|x| x.mean_down_um),
        e: both(
            max_of(t.iter().flat_map(|x| [x.mean_up_um, x.mean_down_um])),
            min_of(t.iter().flat_map(|x| [x.mean_up_um, x.mean_down_um])),
            |a, b| a - b,
        ),
        m: range(&|x| x.mean_um),
        a_up: a_dir(true),
        a_down: a_dir(false),
        a: both(
            max_of(
                t.iter()
                    .flat_map(|x| [hi(x.mean_up_um, x.s_up_um), hi(x.mean_down_um, x.s_down_um)]),
            ),
            min_of(
                t.iter()
                    .flat_map(|x| [lo(x.mean_up_um, x.s_up_um), lo(x.mean_down_um, x.s_down_um)]),
            ),
            |a, b| a - b,
        ),
    };
    Iso230Report { axis, targets }
}
