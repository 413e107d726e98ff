//! GB/T 17421.2, the Chinese adoption of ISO 230-2 (2000 edition ≙ ISO 230-2:1997, 2016
//! edition ≙ ISO 230-2:2014): the same parameters (±2 s) under their Chinese names.
//! `docs/methods.md` "Positioning standards".

use super::{Standard, StandardResult};
use crate::iso230::TargetStats;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Edition {
    E2000,
    E2016,
}

const NAMES: [&str; 12] = [
    "轴线双向定位精度 (bidirectional accuracy of positioning)",
    "轴线单向定位精度 ↑ (unidirectional accuracy)",
    "轴线单向定位精度 ↓ (unidirectional accuracy)",
    "轴线双向重复定位精度 (bidirectional repeatability)",
    "轴线单向重复定位精度 ↑ (unidirectional repeatability)",
    "轴线单向重复定位精度 ↓ (unidirectional repeatability)",
    "轴线反向差值 (reversal value)",
    "轴线平均反向差值 (mean reversal value)",
    "轴线双向定位系统偏差 (bidirectional systematic positional deviation)",
    "轴线单向定位系统偏差 ↑ (unidirectional systematic positional deviation)",
    "轴线单向定位系统偏差 ↓ (unidirectional systematic positional deviation)",
    "轴线双向平均位置偏差范围 (range of the mean bidirectional positional deviation)",
];

pub(crate) fn evaluate(t: &[TargetStats], ed: Edition) -> StandardResult {
    let (standard, designation, iso) = match ed {
        Edition::E2000 => (
            Standard::Gb17421_2_2000,
            "GB/T 17421.2-2000",
            "ISO 230-2:1997",
        ),
        Edition::E2016 => (
            Standard::Gb17421_2_2016,
            "GB/T 17421.2-2016",
            "ISO 230-2:2014",
        ),
    };
    StandardResult {
        standard,
        designation: designation.to_string(),
        coverage: "±2 s (s with n − 1)".to_string(),
        parameters: super::iso230_2::parameters(t, 2.0, &NAMES),
        notes: vec![format!(
            "{designation} is an identical adoption of {iso}: its values equal the ISO 230-2 values of the same readings"
        )],
    }
}
