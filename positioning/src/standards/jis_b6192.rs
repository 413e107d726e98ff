//! JIS B 6192:1999, the Japanese adoption of ISO 230-2:1997: the same parameters (±2 s) under
//! their Japanese names. `docs/methods.md` "Positioning standards".

use super::{Standard, StandardResult};
use crate::iso230::TargetStats;

const NAMES: [&str; 12] = [
    "両方向位置決め正確さ (bidirectional accuracy of positioning)",
    "片方向位置決め正確さ ↑ (unidirectional accuracy)",
    "片方向位置決め正確さ ↓ (unidirectional accuracy)",
    "両方向位置決め繰返し性 (bidirectional repeatability)",
    "片方向位置決め繰返し性 ↑ (unidirectional repeatability)",
    "片方向位置決め繰返し性 ↓ (unidirectional repeatability)",
    "反転値 (reversal value)",
    "平均反転値 (mean reversal value)",
    "両方向系統的位置偏差 (bidirectional systematic positional deviation)",
    "片方向系統的位置偏差 ↑ (unidirectional systematic positional deviation)",
    "片方向系統的位置偏差 ↓ (unidirectional systematic positional deviation)",
    "平均両方向位置偏差の範囲 (range of the mean bidirectional positional deviation)",
];

pub(crate) fn evaluate(t: &[TargetStats]) -> StandardResult {
    StandardResult {
        standard: Standard::JisB6192,
        designation: "JIS B 6192:1999".to_string(),
        coverage: "±2 s (s with n − 1)".to_string(),
        parameters: super::iso230_2::parameters(t, 2.0, &NAMES),
        notes: vec![
            "JIS B 6192:1999 adopts ISO 230-2:1997: its values equal the ISO 230-2 values of the same readings".to_string(),
        ],
    }
}
