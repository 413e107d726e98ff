//! A run being diagnosed: its observations ([`Obs`]) with what the search keeps for the run
//! (the grid searches' columns and sums, [`Cache`]) and the same observations with diagonal
//! folds, made when first needed.

use std::ops::Deref;
use std::sync::OnceLock;

use super::family::Family;
use super::obs::Obs;
use super::sums::Cache;

pub(super) struct Run {
    obs: Obs,
    /// Columns of the searched effects and their weighted sums, kept for the run.
    pub(super) cache: Cache,
    /// The same observations with diagonal folds ([`Run::diagonal`]).
    diagonal: OnceLock<Obs>,
}

impl Deref for Run {
    type Target = Obs;

    fn deref(&self) -> &Obs {
        &self.obs
    }
}

impl Run {
    pub(super) fn new(obs: Obs) -> Self {
        Run {
            obs,
            cache: Cache::default(),
            diagonal: OnceLock::new(),
        }
    }

    /// The same observations with folds dealt diagonally over (cycle, target)
    /// ([`Obs::with_diagonal_folds`]), made when first needed.
    pub(super) fn diagonal(&self) -> &Obs {
        self.diagonal.get_or_init(|| self.obs.with_diagonal_folds())
    }
}

impl Family {
    /// The regressors of the effect with its parameter at `theta`: kept for the run for a
    /// grid-searched family ([`Family::is_searched_dense`]), computed otherwise.
    pub(super) fn columns(self, run: &Run, theta: f64) -> Vec<Vec<f64>> {
        if self.is_searched_dense() {
            run.cache.columns(run, self, theta).to_vec()
        } else {
            self.compute_columns(run, theta)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::axis::fit::{heldout_residuals, heldout_rms};
    use crate::axis::obs::tests::run;

    /// A model with offsets per cycle predicts a cycle held out whole at the mean offset of
    /// the cycles it was fitted on (here: exactly what the baseline predicts), whichever cycle
    /// is the reference; on diagonal folds it predicts every reading of such a run exactly.
    #[test]
    fn a_cycle_held_out_whole_is_predicted_at_the_mean_offset() {
        let mut obs = run();
        let offset = [0.0, 3.0, -1.0, 4.0, 2.0, -2.0];
        obs.y = (0..obs.len())
            .map(|j| 2.0 * obs.target[j] as f64 + offset[obs.cycle[j]])
            .collect();
        let w = vec![1.0; obs.len()];
        let eval = vec![true; obs.len()];
        let offsets = Family::CycleOffsets.compute_columns(&obs, f64::NAN);
        // 6 cycles in 5 folds: fold 0 holds cycles 0 (the reference) and 5.
        for (r, j) in heldout_residuals(&obs, &w, &offsets, &eval) {
            let f = obs.fold[j];
            let trained: Vec<f64> = (0..6).filter(|c| c % 5 != f).map(|c| offset[c]).collect();
            let mean = trained.iter().sum::<f64>() / trained.len() as f64;
            let want = offset[obs.cycle[j]] - mean;
            assert!((r - want).abs() < 1e-9, "fold {f}: {r} vs {want}");
        }
        let run = Run::new(obs);
        let (obs, diag) = (&*run, run.diagonal());
        assert_ne!(diag.fold, obs.fold);
        assert!(heldout_rms(diag, &w, &offsets, &eval) < 1e-9);
        assert!(heldout_rms(diag, &w, &[], &eval) > 1.0);
    }
}
