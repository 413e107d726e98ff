//! Prints what the dataset reader notes about each CSV given: `cargo run -p
//! metrolog-positioning --example dataset_notes -- FILE...`
fn main() {
    for path in std::env::args().skip(1) {
        match positioning::positioning_data::PositioningData::from_csv_path_noted(path.as_ref()) {
            Ok((d, notes)) => println!("{path}: {} readings, notes {notes:?}", d.readings.len()),
            Err(e) => println!("{path}: error {e}"),
        }
    }
}
