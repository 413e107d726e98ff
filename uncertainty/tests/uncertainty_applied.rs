//! The budgets applied to the measurements: LI-80 length (ISO/TR 230-9 style) and the PSD
//! laser frame of paper 003 (Table 3 GUM budget, Table 4 is in `uncertainty_psd_table4.rs`).

use uncertainty::budget::Budget;
use uncertainty::length::LengthBudget;
use uncertainty::mc::McOptions;

#[test]
fn li80_budget_file_and_function_agree() {
    // Two independent implementations of the same model: an expression in a budget file and a
    // closure; and Monte Carlo of the file, which also carries the cosine error's spread.
    let b = Budget::from_toml(include_str!(
        "../../examples/budgets/li80_length_1000mm.toml"
    ))
    .unwrap();
    let g = &b.gum().unwrap().outputs[0];
    let f = LengthBudget::default().gum(1000.0).unwrap();
    // The function adds the cosine term (0.0015 µm) in quadrature: relative effect ~1e-6.
    assert!((g.standard_uncertainty - f.standard_uncertainty).abs() < 1e-5);
    let m = b
        .monte_carlo(
            &McOptions {
                fixed_trials: Some(400_000),
                seed: 8,
                ..McOptions::default()
            },
            None,
        )
        .unwrap();
    let u = m.outputs[0].standard_uncertainty;
    assert!(
        (u / f.standard_uncertainty - 1.0).abs() < 0.006,
        "MC {u} vs {}",
        f.standard_uncertainty
    );
    // The expansion-coefficient term is rectangular and dominant, so the 95 % Monte Carlo
    // interval is narrower than ±2u.
    let half = 0.5 * (m.outputs[0].symmetric_interval[1] - m.outputs[0].symmetric_interval[0]);
    assert!(half < 2.0 * u && half > 1.6 * u, "{half} vs u {u}");
}

#[test]
fn psd_table3_budget_reproduces_the_published_combination() {
    let b =
        Budget::from_toml(include_str!("../../examples/budgets/psd_frame_table3.toml")).unwrap();
    let g = &b.gum().unwrap().outputs[0];
    // Paper 003 §4.4: u_c,max = 1.13 µm, U_max = 2.26 µm (k = 2, formed from the rounded u_c).
    assert_eq!((g.standard_uncertainty * 100.0).round() / 100.0, 1.13);
    assert_eq!(g.coverage_factor, 2.0);
    let u_rounded = (g.standard_uncertainty * 100.0).round() / 100.0;
    assert!((2.0 * u_rounded - 2.26).abs() < 1e-12);
    assert!((g.expanded_uncertainty - 2.2524).abs() < 1e-3);
}
