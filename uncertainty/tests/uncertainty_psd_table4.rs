//! Paper 003 Table 4 (PSD laser frame, U of the 13 errors) against our Monte Carlo with the
//! position-dependent reading budget (Tables 2–3) and all 21 errors randomised
//! (docs/methods.md, "PSD frame Monte Carlo", where the table and every difference are
//! discussed). The published values are independent of this project; the check is the per-error
//! pattern, and the single-σ approach that preceded the budget fails it.

use geometry::psd_frame::{PsdLayout, derive_uncertainty};
use uncertainty::mc::McOptions;
use uncertainty::psd::{Table4Row, table4, table4_with_reading_u};
use uncertainty::psd_budget::PsdBudget;

/// 10 000 trials: the Monte Carlo error of a 95 % half-width is about 1.5 %, far inside the
/// tolerances below (the paper ran 30 000).
const TRIALS: usize = 10_000;
/// Lever of the angles as lengths: the largest travel of the measured volume (Z, 350 mm).
const LEVER_MM: f64 = 350.0;

fn example() -> PsdBudget {
    PsdBudget::from_toml(include_str!(
        "../../examples/budgets/psd_frame_readings.toml"
    ))
    .unwrap()
}

fn opts(seed: u64) -> McOptions {
    McOptions {
        fixed_trials: Some(TRIALS),
        seed,
        ..McOptions::default()
    }
}

fn row<'a>(rows: &'a [Table4Row], e: &str) -> &'a Table4Row {
    rows.iter().find(|r| r.error == e).unwrap()
}

/// The pattern check against Table 4. Returns what fails (empty: the pattern is reproduced).
fn pattern_failures(rows: &[Table4Row]) -> Vec<String> {
    let mut f = Vec::new();
    let ratio = |e: &str| row(rows, e).expanded_um / row(rows, e).published_um;
    // 1. Straightnesses in the table plane (S2–S4 readings): within ±35 %. The tolerance covers
    //    what the paper does not give: the beam path of each point (our frame geometry), the
    //    exact course of the PSD linearity along a segment, the meaning of "noise doubled".
    for e in ["EYX", "EZX", "EXY"] {
        if !(0.65..=1.35).contains(&ratio(e)) {
            f.push(format!("{e}: {:.2} of the published", ratio(e)));
        }
    }
    // 2. The vertical segment's straightnesses are larger than those in the plane (largest PSD
    //    range in Table 2, longest beam path): the paper's ratio of the means is 2.45/1.47 =
    //    1.67; ours within ±25 % of it.
    let mean = |es: &[&str], published: bool| {
        es.iter()
            .map(|e| {
                let r = row(rows, e);
                if published {
                    r.published_um
                } else {
                    r.expanded_um
                }
            })
            .sum::<f64>()
            / es.len() as f64
    };
    let (s5, plane) = (["EXZ", "EYZ"], ["EYX", "EZX", "EXY"]);
    let ours = mean(&s5, false) / mean(&plane, false);
    let published = mean(&s5, true) / mean(&plane, true);
    if !(0.75..=1.25).contains(&(ours / published)) {
        f.push(format!(
            "S5/plane straightness ratio {ours:.2}, published {published:.2}"
        ));
    }
    // 3. Squarenesses as lengths over 350 mm within a factor 1.5: wider, because their spread
    //    also depends on the amplitudes of the unmeasured yaws and tilts, which the paper takes
    //    from a source we do not have (without them: 5.0, 4.8, 4.0 µm).
    for e in ["EA0Z", "EB0Z", "EC0Y"] {
        if !(1.0 / 1.5..=1.5).contains(&ratio(e)) {
            f.push(format!("{e}: {:.2} of the published", ratio(e)));
        }
    }
    f
}

#[test]
fn reading_budget_gives_tables_2_and_3() {
    let b = example();
    let l = PsdLayout::paper();
    // Table 2, max. u_PSD per segment and reading (published, rounded to 0.01 µm): the value at
    // the ends of a segment.
    let table2 = [
        (1, [0.13, 0.18]),
        (2, [0.13, 0.35]),
        (3, [0.13, 0.18]),
        (4, [0.15, 0.21]),
        (5, [0.75, 0.35]),
    ];
    for (seg, want) in table2 {
        let n = if seg == 1 { l.n_s1 } else { l.n_points };
        for (k, w) in want.iter().enumerate() {
            let end = b.reading_terms(seg, n - 1, n, k).psd;
            assert_eq!((end * 100.0).round() / 100.0, *w, "S{seg} r{}", k + 1);
            // The spot is centred in the middle of the segment: only the repeatability is left.
            let mid = b.reading_terms(seg, (n - 1) / 2, n, k).psd;
            assert!((mid - 0.05).abs() < 1e-12, "S{seg} middle {mid}");
        }
    }
    // Table 3: u_c,max = 1.13 µm at the worst point (S5's last point, X reading).
    let u = b.reading_u_um(&l);
    let max = u.iter().cloned().fold(0.0, f64::max);
    assert_eq!((max * 100.0).round() / 100.0, 1.13);
    assert_eq!(u.iter().position(|v| *v == max), Some(u.len() - 2));
    // Table 3 without the two position-dependent terms: √Σu² of the seven others, 0.379 µm.
    let min = u.iter().cloned().fold(f64::INFINITY, f64::min);
    assert!(min > 0.378 && min < 0.40, "{min}");
}

#[test]
fn the_measured_errors_cancel_and_the_noise_propagates_exactly() {
    // With the unmeasured errors (pitch, yaw, Z angles, EZZ) set to zero and no reading noise,
    // the 13 randomised measured errors must come out exactly (first-order model; the second-order terms of 15 µrad over
    // 350 mm are ~1e-4 µm).
    let mut b = example();
    b.thermal_errors.angular_urad = 0.0;
    b.thermal_errors.ezz_um = 0.0;
    let l = PsdLayout::paper();
    let n = b.reading_u_um(&l).len();
    let opts = McOptions {
        fixed_trials: Some(2_000),
        ..opts(11)
    };
    let s = table4_with_reading_u(&l, &b, vec![0.0; n], &opts, LEVER_MM, None).unwrap();
    for o in &s.monte_carlo.outputs {
        assert!(
            o.standard_uncertainty < 1e-3,
            "{} {}",
            o.name,
            o.standard_uncertainty
        );
    }
    // Reading noise only, one σ for all: the Monte Carlo u equals the exact linear propagation
    // of `psd_frame::derive_uncertainty` (a separate computation), with σ·√2 for the reference
    // subtraction the Monte Carlo performs by drawing a noisy reference run.
    let sigma = 0.7;
    let s = table4_with_reading_u(&l, &b, vec![sigma; n], &opts, LEVER_MM, None).unwrap();
    let exact = derive_uncertainty(&l, sigma * 2f64.sqrt()).unwrap();
    for (o, u) in s.monte_carlo.outputs.iter().zip(&exact) {
        if *u > 0.0 {
            assert!(
                (o.standard_uncertainty / u - 1.0).abs() < 0.05,
                "{}: {} vs {u}",
                o.name,
                o.standard_uncertainty
            );
        }
    }
}

#[test]
fn table4_pattern_is_reproduced_and_single_sigma_fails_it() {
    let b = example();
    let l = PsdLayout::paper();
    let s = table4(&l, &b, &opts(3), LEVER_MM, None).unwrap();
    for r in &s.rows {
        eprintln!(
            "{:5} ours {:6.2} µm ({:6.2} {})  published {:4.1}",
            r.error, r.expanded_um, r.expanded, r.unit, r.published_um
        );
    }
    let failures = pattern_failures(&s.rows);
    assert!(failures.is_empty(), "{failures:?}");

    // The remaining differences, stated in docs/methods.md; asserted so that a change of the
    // model that removes (or worsens) one of them is noticed and the text updated.
    let ratio = |e: &str| row(&s.rows, e).expanded_um / row(&s.rows, e).published_um;
    // EZY: the paper's 3.9 µm is not explained by the reading budget: the Z readings of S3
    // have the small PSD ranges of Table 2 and EZY comes from S3 alone in our model, so it is
    // as uncertain as EZX (1.2–1.6 µm). The paper's model ([Brecher 2021], not in reach) must
    // combine more readings for EZY, or its thermal errors alias into it; unexplained.
    assert!(ratio("EZY") < 0.5, "EZY {}", ratio("EZY"));
    // EXZ > EYZ here (Table 2: S5 X range ±1.3 mm against Y ±0.6), the paper has EYZ > EXZ.
    // If the S5 PSD's X axis were the machine's Y the order would agree; the paper does not
    // say. Both together are checked by the S5/plane ratio above.
    assert!(row(&s.rows, "EXZ").expanded > row(&s.rows, "EYZ").expanded);
    // Positioning (change over the travel, from 7 resp. 11 averaged readings): ours 1.5–2.5×
    // the published 0.4 µm. With Table 3's seven constant terms alone (0.379 µm per reading)
    // the floor is 2·√2·0.379/√7 = 0.41 µm for X: the paper's value sits at that floor, i.e.
    // it seems to leave out the position-dependent terms and the aliasing of the unmeasured
    // yaw of X through the Y lever (ECX·y), which ours includes.
    for e in ["EXX", "EYY"] {
        assert!((1.2..3.0).contains(&ratio(e)), "{e} {}", ratio(e));
    }
    // Rolls: about half the published lengths over 350 mm (the roll of X over the 167 mm
    // between S2 and S4 in µrad matches a ~700 mm lever): the lever of the paper's "linear
    // uncertainty with respect to the measurement volume" is not stated; EAX > EBY agrees.
    for e in ["EAX", "EBY"] {
        assert!((0.35..0.7).contains(&ratio(e)), "{e} {}", ratio(e));
    }
    assert!(row(&s.rows, "EAX").expanded > row(&s.rows, "EBY").expanded);

    // The check can fail: one σ for all 102 readings (Table 3's u_c,max, as before the
    // budget) gives ±3.0 µm for every straightness and fails it.
    let one = vec![1.13; b.reading_u_um(&l).len()];
    let single = table4_with_reading_u(&l, &b, one, &opts(3), LEVER_MM, None).unwrap();
    let failures = pattern_failures(&single.rows);
    assert!(
        failures.iter().any(|f| f.starts_with("EYX"))
            && failures.iter().any(|f| f.starts_with("S5/plane"))
            && failures.iter().any(|f| f.starts_with("EA0Z")),
        "{failures:?}"
    );
}
