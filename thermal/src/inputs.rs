//! The model's input columns: sensor temperature rises and spindle speed, through lags.

use crate::dataset::ThermalDataset;
use crate::filter::{lag_held, zero_phase};
use rustc_hash::FxHashMap as HashMap;
use std::cell::RefCell;
use std::collections::VecDeque;
use std::rc::Rc;

/// Where a term's input comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(crate) enum Src {
    /// Sensor index in the dataset.
    Sensor(usize),
    /// Spindle speed as (rpm / 1000)^exponent.
    Spindle(u32),
    /// A sensor smoothed without delay (a first-order filter run forward, then backward, with
    /// the term's time constant): in the diagnosis, the counterpart of a lag that only averages
    /// the reading's noise. `thermal::fit` never offers it.
    Smoothed(usize),
}

/// A term before its coefficient is known: an input and its lag.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Spec {
    pub(crate) src: Src,
    pub(crate) tau_heat_s: f64,
    pub(crate) tau_cool_s: f64,
}

impl Spec {
    pub(crate) fn symmetric(src: Src, tau_s: f64) -> Self {
        Self {
            src,
            tau_heat_s: tau_s,
            tau_cool_s: tau_s,
        }
    }

    pub(crate) fn is_asymmetric(&self) -> bool {
        self.tau_heat_s != self.tau_cool_s
    }

    pub(crate) fn key(&self) -> Key {
        (
            self.src,
            self.tau_heat_s.to_bits(),
            self.tau_cool_s.to_bits(),
        )
    }
}

/// A column's cache key: its input and its two time constants' bits.
/// A term as a hash key: its input and its time constants' bits.
pub(crate) type Key = (Src, u64, u64);

/// The raw inputs of one dataset and the lagged columns computed from them (cached).
pub(crate) struct Inputs {
    pub(crate) time_s: Vec<f64>,
    /// Temperature rise above the reference, K, per sensor.
    rises: Vec<Vec<f64>>,
    /// Spindle speed in 1000 rpm.
    krpm: Option<Vec<f64>>,
    /// Weight of a step's first speed reading in the speed over the step (0.5: a change
    /// halfway between readings).
    spindle_hold: f64,
    cache: RefCell<ColumnCache>,
}

/// Lagged columns computed once: those of the time constants on the search grid (and 0) for
/// the whole search, the others (a golden-section search's trials, a refined model's) only the
/// [`OFF_GRID_KEPT`] most recent. Keeping every trial held 0.8 GB for the real spindle file.
#[derive(Default)]
struct ColumnCache {
    grid: Vec<u64>,
    columns: HashMap<Key, Rc<Vec<f64>>>,
    off_grid: VecDeque<Key>,
}

/// Columns off the search grid kept at most (each is one value per sample).
const OFF_GRID_KEPT: usize = 512;

impl ColumnCache {
    fn new(time_s: &[f64]) -> Self {
        let taus = if time_s.is_empty() {
            vec![]
        } else {
            tau_grid(time_s)
        };
        let mut grid: Vec<u64> = taus.iter().map(|t| t.to_bits()).collect();
        grid.push(0.0f64.to_bits());
        Self {
            grid,
            ..Self::default()
        }
    }

    fn on_grid(&self, key: &Key) -> bool {
        self.grid.contains(&key.1) && self.grid.contains(&key.2)
    }

    fn get(&self, key: &Key) -> Option<Rc<Vec<f64>>> {
        self.columns.get(key).cloned()
    }

    fn insert(&mut self, key: Key, col: Rc<Vec<f64>>) {
        if !self.on_grid(&key) {
            self.off_grid.push_back(key);
            if self.off_grid.len() > OFF_GRID_KEPT
                && let Some(old) = self.off_grid.pop_front()
            {
                self.columns.remove(&old);
            }
        }
        self.columns.insert(key, col);
    }

    fn clear(&mut self) {
        self.columns.clear();
        self.off_grid.clear();
    }
}

impl Inputs {
    /// Inputs of `ds` with temperature rises above `reference_c` (one per sensor).
    pub(crate) fn new(ds: &ThermalDataset, reference_c: &[f64]) -> Self {
        let rises = ds
            .temperatures_c
            .iter()
            .zip(reference_c)
            .map(|(t, r)| t.iter().map(|v| v - r).collect())
            .collect();
        let krpm = ds
            .spindle_rpm
            .as_ref()
            .map(|v| v.iter().map(|r| r / 1000.0).collect());
        Self {
            time_s: ds.time_s.clone(),
            rises,
            krpm,
            spindle_hold: 0.5,
            cache: RefCell::new(ColumnCache::new(&ds.time_s)),
        }
    }

    /// The same inputs with the speed over a step weighted `w` on its first reading.
    pub(crate) fn with_spindle_hold(mut self, w: f64) -> Self {
        self.spindle_hold = w;
        self.cache.borrow_mut().clear();
        self
    }

    pub(crate) fn spindle_hold(&self) -> f64 {
        self.spindle_hold
    }

    pub(crate) fn has_spindle(&self) -> bool {
        self.krpm.is_some()
    }

    /// The raw (unlagged) input of `src`, or `None` when the dataset lacks it.
    pub(crate) fn raw(&self, src: Src) -> Option<Vec<f64>> {
        match src {
            Src::Sensor(i) | Src::Smoothed(i) => self.rises.get(i).cloned(),
            Src::Spindle(p) => self
                .krpm
                .as_ref()
                .map(|v| v.iter().map(|x| x.abs().powi(p as i32)).collect()),
        }
    }

    /// The lagged column of `spec` (computed once per dataset).
    pub(crate) fn column(&self, spec: &Spec) -> Option<Rc<Vec<f64>>> {
        if let Some(c) = self.cache.borrow().get(&spec.key()) {
            return Some(c);
        }
        let raw = self.raw(spec.src)?;
        let w = match spec.src {
            Src::Spindle(_) => self.spindle_hold,
            Src::Sensor(_) | Src::Smoothed(_) => 0.5,
        };
        let col = Rc::new(match spec.src {
            Src::Smoothed(_) => zero_phase(&self.time_s, &raw, spec.tau_heat_s),
            _ => lag_held(&self.time_s, &raw, spec.tau_heat_s, spec.tau_cool_s, w),
        });
        self.cache.borrow_mut().insert(spec.key(), Rc::clone(&col));
        Some(col)
    }
}

/// Time constants tried, s: 1 min to 12 h, those between two samples and half the run.
pub(crate) fn tau_grid(time_s: &[f64]) -> Vec<f64> {
    const MINUTES: [f64; 18] = [
        1.0, 2.0, 3.0, 5.0, 7.0, 10.0, 15.0, 20.0, 30.0, 45.0, 60.0, 90.0, 120.0, 180.0, 240.0,
        360.0, 480.0, 720.0,
    ];
    let n = time_s.len();
    let span = time_s[n - 1] - time_s[0];
    let mut dts: Vec<f64> = time_s.windows(2).map(|w| w[1] - w[0]).collect();
    dts.sort_by(f64::total_cmp);
    let dt = dts.get(dts.len() / 2).copied().unwrap_or(1.0);
    MINUTES
        .iter()
        .map(|m| m * 60.0)
        .filter(|&t| t >= 2.0 * dt && t <= span / 2.0)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn column_cache_keeps_the_grid_and_the_latest_off_grid_columns() {
        let time_s: Vec<f64> = (0..2000).map(|i| 60.0 * i as f64).collect();
        let mut cache = ColumnCache::new(&time_s);
        let on = Spec::symmetric(Src::Sensor(0), tau_grid(&time_s)[0]).key();
        let col = Rc::new(vec![1.0]);
        cache.insert(on, Rc::clone(&col));
        let off = |k: usize| Spec::symmetric(Src::Sensor(0), 61.5 + k as f64).key();
        for k in 0..=OFF_GRID_KEPT {
            cache.insert(off(k), Rc::clone(&col));
        }
        assert!(cache.get(&on).is_some(), "a grid column is kept");
        assert!(
            cache.get(&off(0)).is_none(),
            "the oldest off-grid column is dropped"
        );
        assert!(cache.get(&off(1)).is_some() && cache.get(&off(OFF_GRID_KEPT)).is_some());
        assert_eq!(cache.columns.len(), OFF_GRID_KEPT + 1);
    }
}
