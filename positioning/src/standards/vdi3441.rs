//! VDI/DGQ 3441:1977 "Statistical testing of the operational and positional accuracy of
//! machine tools": position uncertainty P, position deviation Pa, position scatter Ps and
//! reversal span U from the same per-target statistics as ISO 230-2, with ±3 s bands and the
//! scatter taken from the mean of the two directions' s. `docs/methods.md`
//! "Positioning standards".

use super::{Standard, StandardResult, max_present, param, range_present};
use crate::iso230::TargetStats;

/// Per-target VDI quantities: mean position deviation x̄_j, reversal span U_j, scatter Ps_j.
struct Position {
    mean: Option<f64>,
    u: Option<f64>,
    ps: Option<f64>,
}

fn position(t: &TargetStats) -> Position {
    Position {
        mean: t.mean_um,
        u: t.b_um.map(f64::abs),
        ps: match (t.s_up_um, t.s_down_um) {
            (Some(a), Some(b)) => Some(6.0 * 0.5 * (a + b)),
            _ => None,
        },
    }
}

fn mean_present(v: impl Iterator<Item = Option<f64>>) -> Option<f64> {
    let v: Vec<f64> = v.flatten().collect();
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

pub(crate) fn evaluate(t: &[TargetStats]) -> StandardResult {
    let p: Vec<Position> = t.iter().map(position).collect();
    // P = max_j(x̄_j + (U_j + Ps_j)/2) − min_j(x̄_j − (U_j + Ps_j)/2)
    let half = |q: &Position| Some(0.5 * (q.u? + q.ps?));
    let hi = max_present(p.iter().map(|q| Some(q.mean? + half(q)?)));
    let lo = p
        .iter()
        .filter_map(|q| Some(q.mean? - half(q)?))
        .reduce(f64::min);
    let pos_unc = match (hi, lo) {
        (Some(h), Some(l)) => Some(h - l),
        _ => None,
    };
    StandardResult {
        standard: Standard::Vdi3441,
        designation: "VDI/DGQ 3441:1977".to_string(),
        coverage: "±3 s (Ps = 6 s̄, s̄ = (s↑ + s↓)/2, s with n − 1)".to_string(),
        parameters: vec![
            param("P", "Positionsunsicherheit (position uncertainty)", pos_unc),
            param(
                "Pa",
                "Positionsabweichung (position deviation)",
                range_present(p.iter().map(|q| q.mean)),
            ),
            param(
                "Ps max",
                "größte Positionsstreubreite (largest position scatter)",
                max_present(p.iter().map(|q| q.ps)),
            ),
            param(
                "P̄s",
                "mittlere Positionsstreubreite (mean position scatter)",
                mean_present(p.iter().map(|q| q.ps)),
            ),
            param(
                "U max",
                "größte Umkehrspanne (largest reversal span)",
                max_present(p.iter().map(|q| q.u)),
            ),
            param(
                "Ū",
                "mittlere Umkehrspanne (mean reversal span)",
                mean_present(p.iter().map(|q| q.u)),
            ),
        ],
        notes: vec![
            "VDI/DGQ 3441 was withdrawn in favour of ISO 230-2; it is still quoted in acceptance reports".to_string(),
        ],
    }
}
