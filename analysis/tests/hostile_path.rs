//! The analysis path a positioning CSV takes (issue 27), attacked with generated files: CSV text
//! → the positioning reader → ISO 230-2 and drift elimination → every standard → the text
//! report, the CSV tables and the HTML report. Whatever the file holds (huge, non-finite, empty
//! or non-numeric cells, missing rows, one cycle, coincident targets), nothing panics, and what
//! the reader accepts is reported without a NaN or an infinity anywhere. The same path is the
//! `positioning_path` cargo-fuzz target (`protocol/fuzz`), through
//! `metrolog_analysis::fuzzcheck::positioning_path`.

use metrolog_analysis::fuzzcheck::{non_finite_word, positioning_path};
use proptest::prelude::*;

/// A cell of a deviation or a position: mostly plausible numbers, sometimes hostile text.
fn cell(plausible: std::ops::Range<f64>) -> impl Strategy<Value = String> {
    prop_oneof![
        8 => plausible.prop_map(|v| format!("{v}")),
        1 => prop::sample::select(vec![
            "NaN", "inf", "-inf", "1e308", "-1e308", "1e155", "1e-320", "", "x", "0", "-0",
            "1e5", "999999",
        ])
        .prop_map(str::to_string),
    ]
}

/// A positioning CSV of `cycles` × `targets`, bidirectional, with generated cells, rows
/// sometimes dropped or repeated.
fn csv() -> impl Strategy<Value = String> {
    (1usize..5, 2usize..7).prop_flat_map(|(cycles, targets)| {
        let n = cycles * targets * 2;
        (
            Just((cycles, targets)),
            prop::collection::vec(cell(-50.0..50.0), n),
            prop::collection::vec(cell(-1000.0..1000.0), targets),
            prop::collection::vec(
                prop::sample::select(vec![0u8, 0, 0, 0, 0, 0, 0, 0, 1, 2]),
                n,
            ),
            any::<bool>(),
        )
            .prop_map(|((cycles, targets), dev, pos, edit, times)| {
                let mut t = String::from("cycle,direction,index,target_mm,deviation_um");
                t += if times { ",time_s\n" } else { "\n" };
                let mut k = 0;
                for c in 1..=cycles {
                    for (dir, up) in [("+", true), ("-", false)] {
                        for j in 0..targets {
                            let i = if up { j } else { targets - 1 - j };
                            let time = if times {
                                format!(",{}", k * 30)
                            } else {
                                String::new()
                            };
                            let row = format!("{c},{dir},{},{},{}{time}\n", i + 1, pos[i], dev[k]);
                            match edit[k] {
                                1 => {}
                                2 => {
                                    t += &row;
                                    t += &row;
                                }
                                _ => t += &row,
                            }
                            k += 1;
                        }
                    }
                }
                t
            })
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(400))]

    #[test]
    fn the_path_never_panics_nor_reports_a_non_finite_number(text in csv()) {
        // Panics (the property fails) on a non-finite word in an output.
        let _ = positioning_path(&text);
    }
}

/// Runs without scatter (every deviation equal) or with one cycle: the ratios over a zero
/// scatter are "not determined", never NaN (the issue saw "s_diff ratio = NaN").
#[test]
fn a_flat_run_reports_no_non_finite_number() {
    let mut t = String::from("cycle,direction,index,target_mm,deviation_um,time_s\n");
    let mut k = 0;
    for c in 1..=5 {
        for (d, order) in [("+", [1, 2, 3, 4, 5]), ("-", [5, 4, 3, 2, 1])] {
            for i in order {
                k += 1;
                t += &format!("{c},{d},{i},{},2.5,{}\n", (i - 1) * 100, k * 60);
            }
        }
    }
    let outputs = positioning_path(&t).expect("a flat run reads");
    assert!(outputs[0].contains("not determined"), "{}", outputs[0]);
}

#[test]
fn the_check_finds_non_finite_words() {
    assert_eq!(non_finite_word("ratio = NaN"), Some("NaN"));
    assert_eq!(non_finite_word("noise inf µm"), Some("inf"));
    assert_eq!(non_finite_word("x -inf"), Some("inf"));
    assert_eq!(non_finite_word("info infinite nano"), None);
}
