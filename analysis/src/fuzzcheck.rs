//! The check shared by the `positioning_path` cargo-fuzz target (`protocol/fuzz`) and the
//! generated-input tests (`analysis/tests/hostile_path.rs`): it panics when the analysis path
//! of a positioning CSV breaks a promise on the input. Not part of the API.

use positioning::positioning_data::PositioningData;
use positioning::standards::{Standard, evaluate};

use crate::export::{render_standards, results_csv, targets_csv};
use crate::html_report::{ReportHeader, positioning_html};
use crate::positioning_report::{analyze_positioning, render_text};

/// A NaN or an infinity written as a number: a word `nan`, `inf` or `infinity` (any case).
pub fn non_finite_word(text: &str) -> Option<&str> {
    non_finite_word_except(text, &[])
}

/// [`non_finite_word`], except the words in `echoed`: words of the input's own free text (a
/// title, a sensor's name) that an output repeats are not numbers the analysis wrote.
pub fn non_finite_word_except<'a>(text: &'a str, echoed: &[&str]) -> Option<&'a str> {
    words(text).find(|w| {
        matches!(w.to_ascii_lowercase().as_str(), "nan" | "inf" | "infinity") && !echoed.contains(w)
    })
}

/// The non-finite words of free texts an output may repeat.
pub fn echoed_words<'a>(texts: impl IntoIterator<Item = &'a str>) -> Vec<&'a str> {
    texts
        .into_iter()
        .flat_map(words)
        .filter(|w| non_finite_word_except(w, &[]).is_some())
        .collect()
}

fn words(text: &str) -> impl Iterator<Item = &str> {
    text.split(|c: char| !c.is_alphanumeric() && c != '_')
}

/// CSV text → the positioning reader → ISO 230-2, drift elimination and the standards → the
/// text report, the CSV tables and the HTML report. Never panics; what the reader accepts is
/// reported without a NaN or an infinity in any output. Returns the outputs (`None`: the
/// reader refused the text).
pub fn positioning_path(text: &str) -> Option<Vec<String>> {
    let (data, _notes) = PositioningData::from_csv_str_noted(text).ok()?;
    let an = analyze_positioning(&data, None);
    let standards: Vec<_> = [
        Standard::Iso230_2_2014,
        Standard::Iso230_2_1988,
        Standard::Vdi3441,
        Standard::AsmeB5_54,
        Standard::JisB6192,
        Standard::Gb17421_2_2016,
    ]
    .into_iter()
    .map(|s| evaluate(&data, s))
    .collect();
    let h = ReportHeader::from_metadata(&data);
    let outputs = vec![
        render_text(&an),
        render_standards(&standards),
        targets_csv(&an.targets),
        results_csv(&standards),
        positioning_html(&data, &an, &standards, &h),
    ];
    // A word of the file's own `# key: value` lines is echoed (the sensor's reference, a key
    // shown as a label): it is not a number the analysis wrote.
    let echoed = echoed_words(
        data.metadata
            .iter()
            .flat_map(|(k, v)| [k.as_str(), v.as_str()]),
    );
    for o in &outputs {
        if let Some(w) = non_finite_word_except(o, &echoed) {
            panic!("`{w}` in an output of an accepted file:\n{o}\n--- input:\n{text}");
        }
        if let Some(l) = o
            .lines()
            .find(|l| l.chars().any(|c| c.is_control() && c != '\t' && c != '\r'))
        {
            panic!("a control character in an output line {l:?} of an accepted file:\n{text}");
        }
    }
    Some(outputs)
}

/// CSV text → the positioning reader → a compensation table in every dialect and mode the
/// dialect takes → the controller files and the before/after verification. Never panics; for
/// an accepted file, no file text holds a NaN or an infinity, every file name is a plain name
/// (no path), and no file line holds a control character (a newline in a name would inject a
/// line). Returns the files written (`None`: the reader refused the text).
pub fn compensation_path(text: &str) -> Option<Vec<(String, String)>> {
    use positioning::compensation::{Dialect, Mode, Options, build, verify};
    let (data, _notes) = PositioningData::from_csv_str_noted(text).ok()?;
    let mut files = vec![];
    for dialect in [
        Dialect::LinuxCnc,
        Dialect::Sinumerik,
        Dialect::Fanuc,
        Dialect::Heidenhain,
    ] {
        for mode in [Mode::Mean, Mode::Backlash, Mode::Bidirectional] {
            let o = Options {
                dialect,
                mode,
                spacing_mm: None,
                reference_mm: None,
                axis_name: None,
                axis_number: 1,
                point_limit: None,
            };
            let Ok(t) = build(&data, &o) else { continue };
            let v = verify(&data, &t);
            let summary = format!("{v:?}");
            for (name, body) in &t.files {
                check_controller_file(name, body, text);
            }
            if let Some(w) = non_finite_word(&summary) {
                panic!(
                    "`{w}` in the verification of an accepted file:\n{summary}\n--- input:\n{text}"
                );
            }
            files.extend(t.files);
        }
    }
    Some(files)
}

fn check_controller_file(name: &str, body: &str, input: &str) {
    let plain = !name.is_empty()
        && !name.contains(['/', '\\'])
        && name != ".."
        && name.chars().all(|c| !c.is_control());
    assert!(plain, "file name {name:?} of an accepted file:\n{input}");
    if let Some(w) = non_finite_word(body) {
        panic!("`{w}` in {name} of an accepted file:\n{body}\n--- input:\n{input}");
    }
    if let Some(l) = body
        .lines()
        .find(|l| l.chars().any(|c| c.is_control() && c != '\t' && c != '\r'))
    {
        panic!("a control character in {name}: {l:?}\n--- input:\n{input}");
    }
}
