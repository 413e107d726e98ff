//! Parts check: Welch t-test and reject rates against hand-worked values.

// Parallel arrays indexed together read more plainly with an index.
#![allow(clippy::needless_range_loop)]

use positioning::parts::*;

#[test]
fn welch_t_test_hand_worked() {
    // before: mean 3, s² = 2.5; after: mean 6, s² = 10 (n = 5 each).
    // t = 3 / sqrt(0.5 + 2) = 1.897367; ν = 2.5² / (0.5²/4 + 2²/4) = 5.882353;
    // two-sided p = 0.107531 (numerical integration of the t density, done independently).
    let r = compare(
        &[1.0, 2.0, 3.0, 4.0, 5.0],
        &[2.0, 4.0, 6.0, 8.0, 10.0],
        0.0,
        20.0,
    )
    .unwrap();
    assert!((r.t - 1.897_366_6).abs() < 1e-6);
    assert!((r.dof - 5.882_352_9).abs() < 1e-6);
    assert!((r.p_value - 0.107_531).abs() < 1e-4, "{}", r.p_value);
    assert!(!r.significant);
    assert!((r.variance_ratio.unwrap() - 4.0).abs() < 1e-12);
}

#[test]
fn reject_rate_under_normal_fit() {
    // A sample with mean 0 and s = 1 exactly: ±1.959964 holds 95 %, so 5 % reject.
    let x = [-1.0, 1.0, -1.0, 1.0, 0.0];
    // mean 0, s² = 4/4 = 1.
    let r = compare(&x, &x, -1.959_964, 1.959_964).unwrap();
    assert!(
        (r.before.predicted_reject_pct - 5.0).abs() < 1e-4,
        "{}",
        r.before.predicted_reject_pct
    );
    // One-sided: limits at mean − 1.2816 s and far above: 10.0 % reject.
    let r = compare(&x, &x, -1.281_552, 100.0).unwrap();
    assert!((r.before.predicted_reject_pct - 10.0).abs() < 1e-4);
    assert_eq!(r.before.observed_reject_pct, 0.0);
}

#[test]
fn paper_like_mean_shift_is_significant() {
    // Paper 004 in spirit: the correction moves the mean to the tolerance centre, scatter kept.
    let base: Vec<f64> = (0..50).map(|i| ((i as f64 * 0.61).sin()) * 2.0).collect();
    let before: Vec<f64> = base.iter().map(|v| v - 4.0).collect();
    let after = base.clone();
    let r = compare(&before, &after, -6.0, 6.0).unwrap();
    assert!(r.significant && r.p_value < 1e-10);
    assert!((r.mean_shift - 4.0).abs() < 1e-12);
    assert!((r.variance_ratio.unwrap() - 1.0).abs() < 1e-12);
    assert!(r.after.predicted_reject_pct < r.before.predicted_reject_pct);
}

#[test]
fn bad_inputs() {
    assert!(matches!(
        compare(&[1.0], &[1.0, 2.0], 0.0, 3.0),
        Err(PartsError::TooFew { .. })
    ));
    assert!(matches!(
        compare(&[1.0, 2.0], &[1.0, 2.0], 3.0, 0.0),
        Err(PartsError::BadTolerance { .. })
    ));
    assert!(matches!(
        compare(&[1.0, f64::NAN], &[1.0, 2.0], 0.0, 3.0),
        Err(PartsError::NonFinite { index: 2, .. })
    ));
    assert!(matches!(
        compare(&[1.0, 1.0], &[1.0, 1.0], 0.0, 3.0),
        Err(PartsError::NoScatter)
    ));
    // A before sample without scatter has no variance ratio (it printed "inf").
    let r = compare(&[1.0, 1.0], &[1.0, 2.0], 0.0, 3.0).unwrap();
    assert_eq!(r.variance_ratio, None);
    let r = compare(&[0.0, 1e-90], &[0.0, 1e70], -1e71, 1e71).unwrap();
    assert_eq!(
        r.variance_ratio, None,
        "an overflowing ratio is not a number either"
    );
    assert_eq!(
        parse_sample("b", "# gauges\ndiameter_mm\n1.5\n2.5\n").unwrap(),
        vec![1.5, 2.5]
    );
    assert_eq!(
        parse_sample("b", "id,value\n1,3.0\n2,4.0\n").unwrap(),
        vec![3.0, 4.0]
    );
    assert!(parse_sample("b", "1.0\nabc\n").is_err());
}
