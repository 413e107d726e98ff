//! Conformance of a result with its tolerance when the result is uncertain (ISO 14253-1:2017,
//! the default rule: the uncertainty counts against whoever has to prove something).
//!
//! - **Pass** (conformance proven): the value lies in the *conformance zone*, the tolerance zone
//!   reduced by the expanded uncertainty U at each given limit: lower + U ≤ y ≤ upper − U.
//! - **Fail** (non-conformance proven): the value lies outside the tolerance zone extended by U:
//!   y > upper + U or y < lower − U.
//! - **Not decidable**: in between, within U of a limit (the guard band on either side of it).
//!
//! ISO 230-2 results (E, M, A, B, R) are ranges with an upper limit only (`lower = None`).
//! When U is as large as the tolerance the conformance zone is empty: such a result can fail,
//! never pass, and the decision says why.

use serde::Serialize;

/// The decision for one result.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Decision {
    Pass,
    Fail,
    NotDecidable,
}

impl Decision {
    pub fn label(self) -> &'static str {
        match self {
            Decision::Pass => "pass",
            Decision::Fail => "fail",
            Decision::NotDecidable => "not decidable",
        }
    }
}

/// A tolerance zone; at least one limit.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Tolerance {
    pub lower: Option<f64>,
    pub upper: Option<f64>,
}

impl Tolerance {
    /// An upper limit only (ISO 230-2 results: E ≤ T).
    pub fn upper(t: f64) -> Tolerance {
        Tolerance {
            lower: None,
            upper: Some(t),
        }
    }
}

/// A decision with the zones it was made from.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Conformance {
    pub value: f64,
    pub tolerance: Tolerance,
    pub expanded_uncertainty: f64,
    /// The conformance zone [lower + U, upper − U] (`None` for an absent limit); empty when
    /// its ends cross.
    pub conformance_zone: [Option<f64>; 2],
    pub decision: Decision,
    /// Why, in words, for the report.
    pub reason: String,
}

/// Why a decision cannot be made from these inputs.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ConformanceError {
    #[error("the value, limits and U must be finite numbers and U ≥ 0")]
    NotFinite,
    #[error("a tolerance needs at least one limit")]
    NoLimit,
    #[error("the lower limit {0} lies above the upper limit {1}")]
    Crossed(f64, f64),
}

fn check(value: f64, tol: &Tolerance, u: f64) -> Result<(), ConformanceError> {
    let limits = [tol.lower, tol.upper];
    if !value.is_finite() || !u.is_finite() || u < 0.0 {
        return Err(ConformanceError::NotFinite);
    }
    if limits.iter().flatten().any(|l| !l.is_finite()) {
        return Err(ConformanceError::NotFinite);
    }
    match (tol.lower, tol.upper) {
        (None, None) => Err(ConformanceError::NoLimit),
        (Some(l), Some(h)) if l > h => Err(ConformanceError::Crossed(l, h)),
        _ => Ok(()),
    }
}

/// The ISO 14253-1 decision for `value` with expanded uncertainty `u_expanded`.
pub fn decide(
    value: f64,
    tolerance: Tolerance,
    u_expanded: f64,
) -> Result<Conformance, ConformanceError> {
    check(value, &tolerance, u_expanded)?;
    let u = u_expanded;
    let zone = [
        tolerance.lower.map(|l| l + u),
        tolerance.upper.map(|h| h - u),
    ];
    let outside = tolerance.upper.is_some_and(|h| value > h + u)
        || tolerance.lower.is_some_and(|l| value < l - u);
    let inside = zone[0].is_none_or(|l| value >= l) && zone[1].is_none_or(|h| value <= h);
    let empty = matches!(zone, [Some(l), Some(h)] if l > h);
    let (decision, reason) = if outside {
        (
            Decision::Fail,
            format!("{value:.3} lies outside the tolerance by more than U = {u:.3}"),
        )
    } else if inside && !empty {
        (
            Decision::Pass,
            format!("{value:.3} lies inside the tolerance by at least U = {u:.3}"),
        )
    } else if empty {
        (
            Decision::NotDecidable,
            format!("U = {u:.3} leaves no conformance zone in this tolerance"),
        )
    } else {
        (
            Decision::NotDecidable,
            format!("{value:.3} lies within U = {u:.3} of a tolerance limit (guard band)"),
        )
    };
    Ok(Conformance {
        value,
        tolerance,
        expanded_uncertainty: u,
        conformance_zone: zone,
        decision,
        reason,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn d(value: f64, t: Tolerance, u: f64) -> Decision {
        decide(value, t, u).unwrap().decision
    }

    #[test]
    fn upper_limit_zones() {
        // T = 10, U = 1: pass ≤ 9, not decidable (9, 11], fail > 11.
        let t = Tolerance::upper(10.0);
        assert_eq!(d(5.0, t, 1.0), Decision::Pass);
        assert_eq!(d(9.0, t, 1.0), Decision::Pass);
        assert_eq!(d(9.0001, t, 1.0), Decision::NotDecidable);
        assert_eq!(d(10.0, t, 1.0), Decision::NotDecidable);
        assert_eq!(d(11.0, t, 1.0), Decision::NotDecidable);
        assert_eq!(d(11.0001, t, 1.0), Decision::Fail);
        // Without uncertainty the tolerance itself decides.
        assert_eq!(d(10.0, t, 0.0), Decision::Pass);
        assert_eq!(d(10.0001, t, 0.0), Decision::Fail);
        let c = decide(9.5, t, 1.0).unwrap();
        assert_eq!(c.conformance_zone, [None, Some(9.0)]);
        assert!(c.reason.contains("guard band"), "{}", c.reason);
    }

    #[test]
    fn two_sided_and_empty_zone() {
        let t = Tolerance {
            lower: Some(-2.0),
            upper: Some(2.0),
        };
        assert_eq!(d(0.0, t, 1.0), Decision::Pass);
        assert_eq!(d(-1.5, t, 1.0), Decision::NotDecidable);
        assert_eq!(d(-3.5, t, 1.0), Decision::Fail);
        // U = 2.5 > half the zone: nothing can pass, far outside still fails.
        assert_eq!(d(0.0, t, 2.5), Decision::NotDecidable);
        assert!(
            decide(0.0, t, 2.5)
                .unwrap()
                .reason
                .contains("no conformance zone")
        );
        assert_eq!(d(5.0, t, 2.5), Decision::Fail);
        // An upper limit smaller than U: E = 0.5 against T = 1 with U = 3 is not decidable.
        assert_eq!(d(0.5, Tolerance::upper(1.0), 3.0), Decision::NotDecidable);
    }

    #[test]
    fn bad_inputs_are_refused() {
        let t = Tolerance::upper(1.0);
        assert_eq!(decide(f64::NAN, t, 1.0), Err(ConformanceError::NotFinite));
        assert_eq!(decide(0.0, t, -1.0), Err(ConformanceError::NotFinite));
        let none = Tolerance {
            lower: None,
            upper: None,
        };
        assert_eq!(decide(0.0, none, 1.0), Err(ConformanceError::NoLimit));
        let crossed = Tolerance {
            lower: Some(2.0),
            upper: Some(1.0),
        };
        assert_eq!(
            decide(0.0, crossed, 1.0),
            Err(ConformanceError::Crossed(2.0, 1.0))
        );
    }
}
