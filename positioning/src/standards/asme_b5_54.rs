//! ASME B5.54-2005 "Methods for performance evaluation of computer numerically controlled
//! machining centers", linear displacement accuracy: the ISO 230-2:1997 statistics (±2 s)
//! reported under the ASME names. `docs/methods.md` "Positioning standards" says what of
//! this could not be checked against the standard's text.

use super::{Standard, StandardResult};
use crate::iso230::TargetStats;

const NAMES: [&str; 12] = [
    "bidirectional linear displacement accuracy",
    "unidirectional linear displacement accuracy (+)",
    "unidirectional linear displacement accuracy (−)",
    "bidirectional repeatability",
    "unidirectional repeatability (+)",
    "unidirectional repeatability (−)",
    "reversal error (largest, lost motion)",
    "mean reversal error",
    "bidirectional systematic deviation",
    "unidirectional systematic deviation (+)",
    "unidirectional systematic deviation (−)",
    "range of the mean bidirectional deviation",
];

pub(crate) fn evaluate(t: &[TargetStats]) -> StandardResult {
    StandardResult {
        standard: Standard::AsmeB5_54,
        designation: "ASME B5.54-2005".to_string(),
        coverage: "±2 s (s with n − 1)".to_string(),
        parameters: super::iso230_2::parameters(t, 2.0, &NAMES),
        notes: vec![
            "ASME B5.54 evaluates linear displacement with the ISO 230-2 statistics; its text was not available to check the coverage factor (see docs/methods.md)".to_string(),
        ],
    }
}
