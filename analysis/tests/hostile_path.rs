//! The analysis path a positioning CSV takes (issue 27), attacked with generated files: CSV text
//! → the positioning reader → ISO 230-2 and drift elimination → every standard → the text
//! report, the CSV tables and the HTML report. Whatever the file holds (huge, non-finite, empty
//! or non-numeric cells, missing rows, one cycle, coincident targets), nothing panics, and what
//! the reader accepts is reported without a NaN or an infinity anywhere. The same path is the
//! `positioning_path` cargo-fuzz target (`protocol/fuzz`), through
//! `metrolog_analysis::fuzzcheck::positioning_path`.

use metrolog_analysis::fuzzcheck::{compensation_path, non_finite_word, positioning_path};
use proptest::prelude::*;

/// A cell of a deviation or a position: mostly plausible numbers, sometimes extreme ones the
/// reader accepts (its range ends, subnormals, zeros), rarely text it must refuse.
fn cell(plausible: std::ops::Range<f64>) -> impl Strategy<Value = String> {
    prop_oneof![
        100 => plausible.prop_map(|v| format!("{v}")),
        4 => prop::sample::select(vec![
            "999999.999", "-999999.999", "1e6", "-1e6", "5e-324", "1e-300", "0", "-0", "",
            "123456.789", "-0.000001",
        ])
        .prop_map(str::to_string),
        1 => prop::sample::select(vec!["NaN", "inf", "-inf", "1e308", "-1e308", "1e155", "x", "1e7"])
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
            // Per row: 1 dropped (a lost reading), 2 repeated (refused: given twice), 0 kept.
            prop::collection::vec(
                prop_oneof![97 => Just(0u8), 2 => Just(1u8), 1 => Just(2u8)],
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

static ACCEPTED: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
static TRIED: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

/// The generated files reach the analysis, not only the reader's refusals: at least a quarter
/// of them are accepted (run with the property, in the same process).
#[test]
fn most_generated_files_reach_the_analysis() {
    let mut runner = proptest::test_runner::TestRunner::new(ProptestConfig::with_cases(200));
    runner
        .run(&csv(), |text| {
            if positioning_path(&text).is_some() {
                ACCEPTED.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            }
            TRIED.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            Ok(())
        })
        .expect("the path holds");
    let (a, t) = (
        ACCEPTED.load(std::sync::atomic::Ordering::Relaxed),
        TRIED.load(std::sync::atomic::Ordering::Relaxed),
    );
    assert!(4 * a >= t, "{a} of {t} generated files accepted");
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(400))]

    #[test]
    fn the_path_never_panics_nor_reports_a_non_finite_number(text in csv()) {
        // Panics (the property fails) on a non-finite word in an output.
        if positioning_path(&text).is_some() {
            ACCEPTED.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        }
        TRIED.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    }

    /// The same files to the controller tables of every dialect and mode (the
    /// `compensation_path` fuzz target): no NaN or infinity, no path in a file name, no
    /// control character in a line of a file a control loads.
    #[test]
    fn controller_files_of_accepted_runs_hold_finite_numbers_only(text in csv()) {
        let _ = compensation_path(&text);
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

/// The seeds of the `positioning_path` and `compensation_path` fuzz targets, and the inputs
/// they found (`protocol/fuzz/corpus/positioning_csv`), through both paths.
#[test]
fn the_fuzz_corpus_passes_both_paths() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../protocol/fuzz/corpus/positioning_csv");
    let mut n = 0;
    for e in std::fs::read_dir(&dir).expect("the positioning_csv corpus") {
        let path = e.expect("a directory entry").path();
        let text =
            String::from_utf8_lossy(&std::fs::read(&path).expect("a corpus file")).into_owned();
        let out = positioning_path(&text);
        compensation_path(&text);
        // Control characters in a `# reference:` line (found by the fuzzer): replaced, and the
        // report still names the sensor.
        if path.ends_with("crash-control-characters-in-metadata") {
            let reports = out.expect("the file is read");
            assert!(reports[0].contains("laser triang"), "{}", reports[0]);
        }
        n += 1;
    }
    assert!(n >= 5, "{n} corpus files");
}
