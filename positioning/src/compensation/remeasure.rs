//! The verification run: the axis measured again with the table loaded, against the run the
//! table came from. What is compared is measured on both sides (ISO 230-2 of each run and the
//! mean deviations at the targets both runs share), not the prediction of [`super::verify`].

use serde::{Deserialize, Serialize};

use crate::iso230::{AxisStats, TargetStats, evaluate};
use crate::positioning_data::PositioningData;

/// Mean deviations at one target before and after, µm (`None`: no reading that way).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TargetBeforeAfter {
    pub target_mm: f64,
    pub before_up_um: Option<f64>,
    pub before_down_um: Option<f64>,
    pub after_up_um: Option<f64>,
    pub after_down_um: Option<f64>,
}

/// ISO 230-2 of the run before and of the verification run, and the targets they share.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Remeasured {
    pub before: AxisStats,
    pub after: AxisStats,
    pub targets: Vec<TargetBeforeAfter>,
    /// Targets of the run before that the verification run did not measure, mm.
    pub unmatched_mm: Vec<f64>,
}

impl Remeasured {
    /// E after / E before: the share of the bidirectional systematic deviation (the error at
    /// the targets, both directions) the table left. `None` without both.
    pub fn e_ratio(&self) -> Option<f64> {
        match (self.before.e, self.after.e) {
            (Some(b), Some(a)) if b > 0.0 => Some(a / b),
            _ => None,
        }
    }
}

/// A target of the verification run at the same position (within 1 µm).
fn same_target<'a>(t: &TargetStats, after: &'a [TargetStats]) -> Option<&'a TargetStats> {
    after
        .iter()
        .find(|a| (a.target_mm - t.target_mm).abs() <= 1e-3)
}

/// Compares the run a table came from with the verification run measured with it loaded.
pub fn remeasured(before: &PositioningData, after: &PositioningData) -> Remeasured {
    let (b, a) = (evaluate(before), evaluate(after));
    let mut targets = Vec::new();
    let mut unmatched_mm = Vec::new();
    for t in &b.targets {
        match same_target(t, &a.targets) {
            Some(x) => targets.push(TargetBeforeAfter {
                target_mm: t.target_mm,
                before_up_um: t.mean_up_um,
                before_down_um: t.mean_down_um,
                after_up_um: x.mean_up_um,
                after_down_um: x.mean_down_um,
            }),
            None => unmatched_mm.push(t.target_mm),
        }
    }
    Remeasured {
        before: b.axis,
        after: a.axis,
        targets,
        unmatched_mm,
    }
}
