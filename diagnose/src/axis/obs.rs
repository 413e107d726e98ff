//! The observations of a positioning run as the diagnosis reads them: one row per reading,
//! with its group (target and direction), cycle, fold and time, and the run's pace (the
//! reading interval, the cycle length, the blocks of a run measured in blocks). Plain data,
//! built from the run alone: every other part of the diagnosis reads it.

use positioning::positioning_data::{PositioningData, dir_slot};

/// Fewest readings of a block in a run measured in blocks ([`Obs::blocks`]).
pub(super) const MIN_BLOCK: usize = 3;

#[derive(Clone)]
pub(super) struct Obs {
    pub(super) y: Vec<f64>,
    pub(super) t: Vec<f64>,
    pub(super) x_mm: Vec<f64>,
    pub(super) temp_c: Option<Vec<f64>>,
    pub(super) group: Vec<usize>,
    pub(super) n_groups: usize,
    pub(super) n_targets: usize,
    pub(super) target: Vec<usize>,
    pub(super) fold: Vec<usize>,
    pub(super) n_folds: usize,
    pub(super) duration_s: f64,
    pub(super) dt_s: f64,
    /// Start of the run, s.
    pub(super) t0: f64,
    /// +½ for positive approaches, −½ for negative ones: B = x̄↑ − x̄↓ changes by the
    /// coefficient of a column `dir_half · f(t)` when f goes from 0 to 1 (`docs/datasets.md`).
    pub(super) dir_half: Vec<f64>,
    /// 0-based cycle of every row.
    pub(super) cycle: Vec<usize>,
    pub(super) n_cycles: usize,
    /// Rows in time order (ties in row order).
    pub(super) time_order: Vec<usize>,
    /// Length of one bidirectional cycle, s ([`Obs::cycle_length_s`]), or of a pair of blocks
    /// in a run measured in blocks ([`Obs::block_pair_s`]): every period of a cyclic drift's
    /// grid is checked against it.
    pub(super) cycle_s: Option<f64>,
}

impl Obs {
    pub(super) fn new(data: &PositioningData, max_folds: usize) -> Self {
        let r = &data.readings;
        let t0 = r.iter().map(|r| r.time_s).fold(f64::INFINITY, f64::min);
        let t1 = r.iter().map(|r| r.time_s).fold(f64::NEG_INFINITY, f64::max);
        let mut ts: Vec<f64> = r.iter().map(|r| r.time_s).collect();
        ts.sort_by(f64::total_cmp);
        let dt_s = median_step(&ts).unwrap_or(1.0);
        let n_folds = data.n_cycles().clamp(2, max_folds.max(2));
        let temp_c = r
            .iter()
            .all(|r| r.material_c.is_some())
            .then(|| r.iter().map(|r| r.material_c.unwrap_or(0.0)).collect());
        let mut obs = Obs {
            y: r.iter().map(|r| r.deviation_um).collect(),
            t: r.iter().map(|r| r.time_s).collect(),
            x_mm: r.iter().map(|r| r.target_mm).collect(),
            temp_c,
            group: r
                .iter()
                .map(|r| 2 * (r.index - 1) + dir_slot(r.direction))
                .collect(),
            n_groups: 2 * data.n_targets(),
            n_targets: data.n_targets(),
            target: r.iter().map(|r| r.index - 1).collect(),
            fold: r.iter().map(|r| (r.cycle - 1) % n_folds).collect(),
            n_folds,
            duration_s: (t1 - t0).max(1.0),
            dt_s,
            t0,
            dir_half: r
                .iter()
                .map(|r| 0.5 - dir_slot(r.direction) as f64)
                .collect(),
            cycle: r.iter().map(|r| r.cycle - 1).collect(),
            n_cycles: data.n_cycles(),
            time_order: {
                let mut o: Vec<usize> = (0..r.len()).collect();
                o.sort_by(|&a, &b| r[a].time_s.total_cmp(&r[b].time_s));
                o
            },
            cycle_s: None,
        };
        obs.cycle_s = obs.block_pair_s().or_else(|| obs.cycle_length_s());
        obs
    }

    /// The same observations with folds dealt diagonally over (cycle, target): every
    /// held-out reading then has readings of its own cycle and of its own target in the
    /// training set, which an effect per cycle (`cycle_offsets`) needs to be checked on at
    /// all.
    pub(super) fn with_diagonal_folds(&self) -> Obs {
        let fold = (0..self.len())
            .map(|j| (self.cycle[j] + self.target[j]) % self.n_folds)
            .collect();
        Obs {
            fold,
            ..self.clone()
        }
    }

    pub(super) fn len(&self) -> usize {
        self.y.len()
    }

    /// Length of one bidirectional cycle, s: the median time between the starts of successive
    /// cycles (None with fewer than two cycles).
    pub(super) fn cycle_length_s(&self) -> Option<f64> {
        let mut start = vec![f64::INFINITY; self.n_cycles];
        for j in 0..self.len() {
            start[self.cycle[j]] = start[self.cycle[j]].min(self.t[j]);
        }
        median_step(&start)
    }

    /// Readings (rows, in time order) of each block, when every (target, direction) group is
    /// one block of consecutive readings of at least [`MIN_BLOCK`]; None for an interleaved
    /// run.
    pub(super) fn blocks(&self) -> Option<Vec<Vec<usize>>> {
        let mut out: Vec<Vec<usize>> = Vec::new();
        for &j in &self.time_order {
            match out.last_mut() {
                Some(b) if self.group[b[0]] == self.group[j] => b.push(j),
                _ => out.push(vec![j]),
            }
        }
        let mut seen = vec![false; self.n_groups];
        for b in &out {
            let g = self.group[b[0]];
            if seen[g] || b.len() < MIN_BLOCK {
                return None;
            }
            seen[g] = true;
        }
        Some(out)
    }

    /// The time of a pair of blocks in a run measured in blocks (twice the median time between
    /// the starts of successive blocks; None for an interleaved run). A pattern that repeats
    /// with the blocks (a creep within each, its sign by direction) repeats with this period: a
    /// cyclic drift at it or its harmonics is the run's structure, not a temperature cycle.
    pub(super) fn block_pair_s(&self) -> Option<f64> {
        let starts: Vec<f64> = self.blocks()?.iter().map(|b| self.t[b[0]]).collect();
        median_step(&starts).map(|d| 2.0 * d)
    }
}

/// The median of the positive, finite differences between successive values of `v` (None
/// when there are none): the pace of readings, cycles or blocks.
fn median_step(v: &[f64]) -> Option<f64> {
    let mut d: Vec<f64> = v
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|d| d.is_finite() && *d > 0.0)
        .collect();
    d.sort_by(f64::total_cmp);
    d.get(d.len() / 2).copied()
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use positioning::axis_model::Direction;
    use positioning::positioning_data::Reading;

    /// A bidirectional run of 4 targets × 6 cycles with deviations that follow no effect.
    pub(in crate::axis) fn run() -> Obs {
        let mut readings = Vec::new();
        for cycle in 1..=6 {
            for (dir, order) in [
                (Direction::Up, [1, 2, 3, 4]),
                (Direction::Down, [4, 3, 2, 1]),
            ] {
                for index in order {
                    let k = readings.len() as f64;
                    readings.push(Reading {
                        cycle,
                        direction: dir,
                        index,
                        target_mm: 100.0 * index as f64,
                        deviation_um: (k * 1.7).sin() + 0.3 * (k * 0.37).cos() + 0.01 * k,
                        // Jittered: with a regular pace a drift would be a sum of offsets per
                        // cycle and constants per target.
                        time_s: 30.0 * k + 7.0 * (k * 2.3).sin(),
                        air_c: None,
                        material_c: None,
                    });
                }
            }
        }
        let data = PositioningData {
            has_times: true,
            readings,
            ..Default::default()
        };
        Obs::new(&data, 5)
    }
}
