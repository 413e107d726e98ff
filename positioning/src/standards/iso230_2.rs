//! ISO 230-2 (editions 1988, 1997, 2006, 2014): parameters of clause 3 from the per-target
//! statistics. The 1997, 2006 and 2014 editions share the estimators (s with n − 1) and the
//! ±2 s coverage; they differ in how measurement uncertainty is stated (2006 and 2014 refer to
//! ISO/TR 230-9), not in the numbers computed here. The 1988 edition formed its bands with
//! ±3 s (repeatability 6 s). `docs/methods.md` "Positioning standards" says where each
//! definition comes from and how it is verified.

use super::{Parameter, StandardResult, bands, max_present, param, range_present, span};
use crate::iso230::TargetStats;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Edition {
    E1988,
    E1997,
    E2006,
    E2014,
}

impl Edition {
    fn year(self) -> u16 {
        match self {
            Edition::E1988 => 1988,
            Edition::E1997 => 1997,
            Edition::E2006 => 2006,
            Edition::E2014 => 2014,
        }
    }

    /// Coverage factor of the bands x̄ ± k s.
    pub(crate) fn k(self) -> f64 {
        match self {
            Edition::E1988 => 3.0,
            _ => 2.0,
        }
    }
}

/// The ISO parameter set with bands x̄ ± k s; `names` gives the name of each symbol in the
/// order A, A↑, A↓, R, R↑, R↓, B, B̄, E, E↑, E↓, M (shared with the standards that adopt
/// ISO 230-2 under their own names: JIS B 6192, GB/T 17421.2).
pub(crate) fn parameters(t: &[TargetStats], k: f64, names: &[&str; 12]) -> Vec<Parameter> {
    let (hi, lo) = bands(t, k, true, true);
    let (hi_u, lo_u) = bands(t, k, true, false);
    let (hi_d, lo_d) = bands(t, k, false, true);
    let r_i = t.iter().map(|x| match (x.s_up_um, x.s_down_um, x.b_um) {
        (Some(su), Some(sd), Some(b)) => Some(
            (k * su + k * sd + b.abs())
                .max(2.0 * k * su)
                .max(2.0 * k * sd),
        ),
        _ => None,
    });
    let n_b = t.iter().filter(|x| x.b_um.is_some()).count();
    let b_mean = (n_b > 0).then(|| t.iter().filter_map(|x| x.b_um).sum::<f64>() / n_b as f64);
    let values = [
        span(&hi, &lo),
        span(&hi_u, &lo_u),
        span(&hi_d, &lo_d),
        max_present(r_i),
        max_present(t.iter().map(|x| x.s_up_um.map(|s| 2.0 * k * s))),
        max_present(t.iter().map(|x| x.s_down_um.map(|s| 2.0 * k * s))),
        max_present(t.iter().map(|x| x.b_um.map(f64::abs))),
        b_mean,
        range_present(t.iter().flat_map(|x| [x.mean_up_um, x.mean_down_um])),
        range_present(t.iter().map(|x| x.mean_up_um)),
        range_present(t.iter().map(|x| x.mean_down_um)),
        range_present(t.iter().map(|x| x.mean_um)),
    ];
    let symbols = [
        "A", "A↑", "A↓", "R", "R↑", "R↓", "B", "B̄", "E", "E↑", "E↓", "M",
    ];
    symbols
        .iter()
        .zip(names)
        .zip(values)
        .map(|((s, n), v)| param(s, n, v))
        .collect()
}

/// The English names of ISO 230-2:2014 clause 3 (also used by 1997 and 2006).
pub(crate) const ISO_NAMES: [&str; 12] = [
    "bidirectional accuracy of positioning of an axis",
    "unidirectional accuracy of positioning of an axis (↑)",
    "unidirectional accuracy of positioning of an axis (↓)",
    "bidirectional repeatability of positioning of an axis",
    "unidirectional repeatability of positioning (↑)",
    "unidirectional repeatability of positioning (↓)",
    "reversal value of an axis",
    "mean reversal value of an axis",
    "bidirectional systematic positional deviation of an axis",
    "unidirectional systematic positional deviation of an axis (↑)",
    "unidirectional systematic positional deviation of an axis (↓)",
    "range of the mean bidirectional positional deviation of an axis",
];

pub(crate) fn evaluate(t: &[TargetStats], ed: Edition) -> StandardResult {
    let k = ed.k();
    let mut notes = Vec::new();
    match ed {
        Edition::E2014 => {}
        Edition::E1997 | Edition::E2006 => notes.push(format!(
            "ISO 230-2:{} computes these parameters as the 2014 edition does (s with n − 1, ±2 s); the editions differ in the statement of measurement uncertainty",
            ed.year()
        )),
        Edition::E1988 => notes.push(
            "ISO 230-2:1988 forms its bands with ±3 s: accuracy and repeatability are larger than by the later editions for the same readings".to_string(),
        ),
    }
    StandardResult {
        standard: match ed {
            Edition::E1988 => super::Standard::Iso230_2_1988,
            Edition::E1997 => super::Standard::Iso230_2_1997,
            Edition::E2006 => super::Standard::Iso230_2_2006,
            Edition::E2014 => super::Standard::Iso230_2_2014,
        },
        designation: format!("ISO 230-2:{}", ed.year()),
        coverage: format!("±{k} s (s with n − 1)"),
        parameters: parameters(t, k, &ISO_NAMES),
        notes,
    }
}
