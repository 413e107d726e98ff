//! Thermal-drift elimination (Stejskal et al. 2017, `papers/000`): differences between
//! adjacent targets of one cycle see almost no drift, so their scatter is the repeatability
//! without the drift, and the deviation chart can be rebuilt from a reference reading.
//!
//! Choices where the paper leaves a detail open (written down as `docs/methods.md` asks):
//! - The scatter of the adjacent differences is the per-difference sample standard deviation
//!   (divisor n − 1), which is what compares with the classic ISO 230-2 `s`; the paper's eq. 6
//!   (divisor n(n − 1), the standard error of the mean difference) is reported beside it.
//! - The scatter of pair (i, i+1) belongs to target i+1 (the paper computes it for i = 2..m).
//! - Borders of the rebuilt chart are ±k·s_diff, s_diff not divided by √2, as in the paper
//!   ("the novel method applies a confidence interval expanded 1.4 times"); k = 2 from 30
//!   cycles on, else the Student t quantile with n − 1 degrees of freedom at the same
//!   one-sided probability Φ(2) = 0.97725 (the paper's widening for fewer than 30 repetitions).
//! - The ratio classic/drift-free divides the classic `s` of target i+1 by s_diff of the pair,
//!   as in the paper's example (s = 1.64 µm, 3.09×).
//! - A pair whose difference scatter stands out is found by an F test of its variance against
//!   the pooled variance of the other pairs of that direction, at 1 % family-wise (Bonferroni).
//!   A target is flagged when both pairs touching it stand out, or when it is an end target
//!   and its only pair does.

use serde::{Deserialize, Serialize};
use statrs::distribution::{ContinuousCDF, FisherSnedecor, StudentsT};

use crate::axis_model::Direction;
use crate::positioning_data::PositioningData;

/// Statistics of the difference between adjacent targets i and i+1 in one direction.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AdjacentPair {
    /// The first target of the pair (1-based); the pair is (index, index + 1).
    pub index: usize,
    /// Cycles where both readings exist.
    pub n: usize,
    /// Eq. 4: mean of x_i − x_{i+1}, µm.
    pub mean_diff_um: Option<f64>,
    /// Sample standard deviation of the differences (n − 1), µm.
    pub s_diff_um: Option<f64>,
    /// Eq. 6 as printed: standard error of the mean difference, µm.
    pub s_mean_diff_um: Option<f64>,
    /// Classic ISO 230-2 `s` of target index + 1 divided by `s_diff_um`.
    pub ratio_classic_to_drift_free: Option<f64>,
    /// F-test p-value of this pair's variance against the other pairs' pooled variance.
    pub p_value: Option<f64>,
    /// The pair's scatter stands out (family-wise 1 %).
    pub stands_out: bool,
}

/// One point of the rebuilt (drift-free) deviation chart.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ChartPoint {
    pub index: usize,
    pub target_mm: f64,
    /// Rebuilt deviation, µm.
    pub deviation_um: Option<f64>,
    /// Half-width of the border (k·s_diff of the pair ending at this target), µm.
    pub border_um: Option<f64>,
}

/// Drift elimination for one direction.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DirectionDrift {
    pub direction: Direction,
    pub pairs: Vec<AdjacentPair>,
    pub chart: Vec<ChartPoint>,
    /// Cycle whose target-1 reading anchors the chart.
    pub reference_cycle: Option<usize>,
    /// Mean classic `s` over targets 2..m divided by mean s_diff over the pairs.
    pub mean_ratio: Option<f64>,
}

/// Result of the drift elimination for both directions.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DriftReport {
    /// Coverage factor of the borders (2, or the Student-t equivalent below 30 cycles).
    pub k: f64,
    /// Cycles used for k.
    pub n_cycles: usize,
    /// The cycle asked for as reference.
    pub reference_cycle: usize,
    pub directions: Vec<DirectionDrift>,
    /// Targets (1-based) whose adjacent-difference scatter stands out: a local heat source or
    /// a structural fault.
    pub anomalous_targets: Vec<usize>,
    /// Notes for the reader (substituted reference, missing pairs).
    pub notes: Vec<String>,
}

/// Coverage factor for ±2s-equivalent borders with `n` readings (Student t below 30).
pub fn coverage_factor(n: usize) -> f64 {
    if !(2..30).contains(&n) {
        return 2.0;
    }
    match StudentsT::new(0.0, 1.0, (n - 1) as f64) {
        Ok(t) => t.inverse_cdf(0.977_249_868_051_820_8),
        Err(_) => 2.0,
    }
}

/// The default reference cycle: the first one that starts after 2 h of measuring (the
/// paper's advice), else the last cycle; without real times, the last cycle.
pub fn default_reference_cycle(data: &PositioningData) -> usize {
    let n = data.n_cycles().max(1);
    if !data.has_times {
        return n;
    }
    let t0 = data
        .readings
        .iter()
        .map(|r| r.time_s)
        .fold(f64::INFINITY, f64::min);
    (1..=n)
        .find(|&c| {
            data.readings
                .iter()
                .filter(|r| r.cycle == c)
                .map(|r| r.time_s)
                .fold(f64::INFINITY, f64::min)
                - t0
                >= 7200.0
        })
        .unwrap_or(n)
}

fn sample_std(v: &[f64]) -> Option<(f64, f64)> {
    if v.len() < 2 {
        return None;
    }
    let m = v.iter().sum::<f64>() / v.len() as f64;
    let ss: f64 = v.iter().map(|x| (x - m) * (x - m)).sum();
    Some((m, (ss / (v.len() as f64 - 1.0)).sqrt()))
}

/// Runs the drift elimination; `reference_cycle` anchors the rebuilt chart (1-based).
pub fn eliminate(data: &PositioningData, reference_cycle: usize) -> DriftReport {
    let grid = data.grid();
    let targets_mm = data.targets_mm();
    let (m, n_cyc) = (data.n_targets(), data.n_cycles());
    let k = coverage_factor(n_cyc);
    let mut notes = Vec::new();
    let mut directions = Vec::new();
    let mut flagged = vec![false; m];
    for (slot, dir) in [(0usize, Direction::Up), (1, Direction::Down)] {
        let g = &grid[slot];
        if g.iter().all(|t| t.iter().all(|v| v.is_none())) {
            continue;
        }
        let sign = if slot == 0 { "+" } else { "-" };
        let mut pairs: Vec<AdjacentPair> = (0..m.saturating_sub(1))
            .map(|i| {
                let d: Vec<f64> = (0..n_cyc)
                    .filter_map(|c| Some(g[i][c]? - g[i + 1][c]?))
                    .collect();
                let ms = sample_std(&d);
                let classic: Vec<f64> = g[i + 1].iter().flatten().copied().collect();
                let s_classic = sample_std(&classic).map(|x| x.1);
                AdjacentPair {
                    index: i + 1,
                    n: d.len(),
                    mean_diff_um: (!d.is_empty()).then(|| d.iter().sum::<f64>() / d.len() as f64),
                    s_diff_um: ms.map(|x| x.1),
                    s_mean_diff_um: ms.map(|x| x.1 / (d.len() as f64).sqrt()),
                    ratio_classic_to_drift_free: match (s_classic, ms) {
                        (Some(c), Some((_, s))) if s > 0.0 => Some(c / s),
                        _ => None,
                    },
                    p_value: None,
                    stands_out: false,
                }
            })
            .collect();
        // F test of each pair against the pooled others.
        let n_tests = 2 * m.saturating_sub(1).max(1);
        for i in 0..pairs.len() {
            let Some(si) = pairs[i].s_diff_um else {
                continue;
            };
            let (mut ss, mut dof) = (0.0, 0.0);
            for (j, p) in pairs.iter().enumerate() {
                if let (true, Some(s)) = (j != i, p.s_diff_um) {
                    ss += s * s * (p.n as f64 - 1.0);
                    dof += p.n as f64 - 1.0;
                }
            }
            if dof < 1.0 || ss <= 0.0 {
                continue;
            }
            let f = si * si / (ss / dof);
            if let Ok(fd) = FisherSnedecor::new(pairs[i].n as f64 - 1.0, dof) {
                let p = fd.sf(f);
                pairs[i].p_value = Some(p);
                pairs[i].stands_out = p < 0.01 / n_tests as f64;
            }
        }
        for t in 0..m {
            let left = (t > 0).then(|| pairs[t - 1].stands_out);
            let right = (t + 1 < m).then(|| pairs[t].stands_out);
            let hit = match (left, right) {
                (Some(a), Some(b)) => a && b,
                (Some(a), None) => a && m > 1,
                (None, Some(b)) => b,
                (None, None) => false,
            };
            flagged[t] |= hit;
        }
        // Rebuilt chart from the reference reading of target 1.
        let mut ref_cycle = reference_cycle.clamp(1, n_cyc.max(1));
        if m > 0 && g[0].get(ref_cycle - 1).copied().flatten().is_none() {
            let alt = (0..n_cyc)
                .filter(|&c| g[0][c].is_some())
                .min_by_key(|&c| (c as i64 - (ref_cycle as i64 - 1)).abs());
            match alt {
                Some(c) => {
                    notes.push(format!(
                        "direction {sign}: target 1 has no reading in cycle {ref_cycle}; \
                         the chart is anchored on cycle {}",
                        c + 1
                    ));
                    ref_cycle = c + 1;
                }
                None => notes.push(format!("direction {sign}: target 1 has no reading at all")),
            }
        }
        let mut chart = Vec::with_capacity(m);
        let mut value = g
            .first()
            .and_then(|t| t.get(ref_cycle - 1).copied().flatten());
        for t in 0..m {
            if t > 0 {
                let p = &pairs[t - 1];
                value = match (value, p.mean_diff_um) {
                    (Some(v), Some(d)) => Some(v - d),
                    _ => None,
                };
                if p.mean_diff_um.is_none() {
                    notes.push(format!(
                        "direction {sign}: targets {} and {} never read in one cycle; the \
                         rebuilt chart stops there",
                        t,
                        t + 1
                    ));
                }
            }
            chart.push(ChartPoint {
                index: t + 1,
                target_mm: targets_mm[t],
                deviation_um: value,
                border_um: if t == 0 {
                    Some(0.0)
                } else {
                    pairs[t - 1].s_diff_um.map(|s| k * s)
                },
            });
        }
        let classic: Vec<f64> = (1..m)
            .filter_map(|t| sample_std(&g[t].iter().flatten().copied().collect::<Vec<_>>()))
            .map(|x| x.1)
            .collect();
        let diffs: Vec<f64> = pairs.iter().filter_map(|p| p.s_diff_um).collect();
        let mean_ratio = (!classic.is_empty() && !diffs.is_empty()).then(|| {
            (classic.iter().sum::<f64>() / classic.len() as f64)
                / (diffs.iter().sum::<f64>() / diffs.len() as f64)
        });
        directions.push(DirectionDrift {
            direction: dir,
            pairs,
            chart,
            reference_cycle: (m > 0).then_some(ref_cycle),
            mean_ratio,
        });
    }
    DriftReport {
        k,
        n_cycles: n_cyc,
        reference_cycle,
        directions,
        anomalous_targets: (0..m).filter(|&t| flagged[t]).map(|t| t + 1).collect(),
        notes,
    }
}
