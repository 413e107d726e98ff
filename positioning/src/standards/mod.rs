//! Evaluation of one positioning run by the standard a customer names (`docs/methods.md`,
//! "Positioning standards"). Every standard works from the same per-target statistics —
//! mean unidirectional deviations x̄↑, x̄↓ and their estimators s↑, s↓ (n − 1) — and defines
//! its own parameters, names and coverage from them. One file per standard; the shared
//! statistics come from [`crate::iso230::evaluate`].

mod asme_b5_54;
mod gb17421_2;
mod iso230_2;
mod jis_b6192;
mod vdi3441;

use serde::{Deserialize, Serialize};

use crate::iso230::{TargetStats, evaluate as iso_evaluate};
use crate::positioning_data::PositioningData;

/// A standard (and edition) by which a run can be evaluated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Standard {
    /// ISO 230-2:2014 (fourth edition).
    Iso230_2_2014,
    /// ISO 230-2:2006 (third edition).
    Iso230_2_2006,
    /// ISO 230-2:1997 (second edition).
    Iso230_2_1997,
    /// ISO 230-2:1988 (first edition, ±3 s bands).
    Iso230_2_1988,
    /// VDI/DGQ 3441:1977.
    Vdi3441,
    /// ASME B5.54-2005.
    AsmeB5_54,
    /// JIS B 6192:1999.
    JisB6192,
    /// GB/T 17421.2-2016 (and the -2000 edition, `gb17421.2:2000`).
    Gb17421_2_2016,
    /// GB/T 17421.2-2000.
    Gb17421_2_2000,
}

/// The names accepted on the command line, with the standard each selects.
pub const STANDARD_NAMES: &[(&str, Standard)] = &[
    ("iso230-2:2014", Standard::Iso230_2_2014),
    ("iso230-2", Standard::Iso230_2_2014),
    ("iso230-2:2006", Standard::Iso230_2_2006),
    ("iso230-2:1997", Standard::Iso230_2_1997),
    ("iso230-2:1988", Standard::Iso230_2_1988),
    ("vdi3441", Standard::Vdi3441),
    ("asme-b5.54", Standard::AsmeB5_54),
    ("jis-b6192", Standard::JisB6192),
    ("gb17421.2", Standard::Gb17421_2_2016),
    ("gb17421.2:2016", Standard::Gb17421_2_2016),
    ("gb17421.2:2000", Standard::Gb17421_2_2000),
];

impl std::str::FromStr for Standard {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let key = s.trim().to_ascii_lowercase();
        STANDARD_NAMES
            .iter()
            .find(|(n, _)| *n == key)
            .map(|(_, st)| *st)
            .ok_or_else(|| {
                let names: Vec<&str> = STANDARD_NAMES.iter().map(|(n, _)| *n).collect();
                format!("unknown standard `{s}` (known: {})", names.join(", "))
            })
    }
}

/// One parameter of a standard, µm.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Parameter {
    /// The standard's symbol, e.g. `A`, `R↑`, `Ps max`.
    pub symbol: String,
    /// The standard's name for it (in the standard's language where it is not English,
    /// followed by the English name).
    pub name: String,
    /// Value, µm; `None` when the run cannot give it (e.g. one reading per target).
    pub value_um: Option<f64>,
}

/// A run evaluated by one standard.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StandardResult {
    pub standard: Standard,
    /// Full designation with edition, e.g. `ISO 230-2:2014`.
    pub designation: String,
    /// How the bands are formed (coverage factor of s), e.g. `±2 s`.
    pub coverage: String,
    pub parameters: Vec<Parameter>,
    /// What the reader should know: equivalences, what could not be computed.
    pub notes: Vec<String>,
}

impl StandardResult {
    /// The value of the parameter with this symbol.
    pub fn value(&self, symbol: &str) -> Option<f64> {
        self.parameters
            .iter()
            .find(|p| p.symbol == symbol)
            .and_then(|p| p.value_um)
    }
}

fn param(symbol: &str, name: &str, value_um: Option<f64>) -> Parameter {
    Parameter {
        symbol: symbol.to_string(),
        name: name.to_string(),
        value_um,
    }
}

/// Evaluates a run by one standard.
pub fn evaluate(data: &PositioningData, standard: Standard) -> StandardResult {
    let targets = iso_evaluate(data).targets;
    let mut r = match standard {
        Standard::Iso230_2_2014 => iso230_2::evaluate(&targets, iso230_2::Edition::E2014),
        Standard::Iso230_2_2006 => iso230_2::evaluate(&targets, iso230_2::Edition::E2006),
        Standard::Iso230_2_1997 => iso230_2::evaluate(&targets, iso230_2::Edition::E1997),
        Standard::Iso230_2_1988 => iso230_2::evaluate(&targets, iso230_2::Edition::E1988),
        Standard::Vdi3441 => vdi3441::evaluate(&targets),
        Standard::AsmeB5_54 => asme_b5_54::evaluate(&targets),
        Standard::JisB6192 => jis_b6192::evaluate(&targets),
        Standard::Gb17421_2_2016 => gb17421_2::evaluate(&targets, gb17421_2::Edition::E2016),
        Standard::Gb17421_2_2000 => gb17421_2::evaluate(&targets, gb17421_2::Edition::E2000),
    };
    let n_short = targets
        .iter()
        .filter(|t| t.s_up_um.is_none() || t.s_down_um.is_none())
        .count();
    if n_short > 0 {
        r.notes.push(format!(
            "{n_short} of {} targets have fewer than two readings in a direction: the parameters that need a scatter are taken over the others or not given",
            targets.len()
        ));
    }
    r
}

/// Per-target band values of the ISO family: `(x̄↑ ± k s↑, x̄↓ ± k s↓)` flattened to
/// `(highs, lows)` over both directions (or one).
pub(crate) fn bands(targets: &[TargetStats], k: f64, up: bool, down: bool) -> (Vec<f64>, Vec<f64>) {
    let mut hi = Vec::new();
    let mut lo = Vec::new();
    for t in targets {
        let dirs = [
            (up, t.mean_up_um, t.s_up_um),
            (down, t.mean_down_um, t.s_down_um),
        ];
        for (use_it, m, s) in dirs {
            if let (true, Some(m), Some(s)) = (use_it, m, s) {
                hi.push(m + k * s);
                lo.push(m - k * s);
            }
        }
    }
    (hi, lo)
}

/// `max(hi) − min(lo)`, `None` when empty.
pub(crate) fn span(hi: &[f64], lo: &[f64]) -> Option<f64> {
    let h = hi.iter().copied().reduce(f64::max)?;
    let l = lo.iter().copied().reduce(f64::min)?;
    Some(h - l)
}

/// Largest of the present values.
pub(crate) fn max_present(v: impl Iterator<Item = Option<f64>>) -> Option<f64> {
    v.flatten().reduce(f64::max)
}

/// `max − min` of the present values.
pub(crate) fn range_present(v: impl Iterator<Item = Option<f64>> + Clone) -> Option<f64> {
    let h = v.clone().flatten().reduce(f64::max)?;
    let l = v.flatten().reduce(f64::min)?;
    Some(h - l)
}
