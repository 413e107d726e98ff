//! Diagnoses positioning CSV files and prints the ISO 230-2 summary and the report as JSON:
//! `cargo run --release -p metrolog-metrology --example diagnose_file -- FILE...`.

use diagnose::axis::{Options, diagnose};
use positioning::iso230;
use positioning::positioning_data::PositioningData;

fn main() {
    for path in std::env::args().skip(1) {
        println!("== {path}");
        let data = match PositioningData::from_csv_path(std::path::Path::new(&path)) {
            Ok(d) => d,
            Err(e) => {
                println!("cannot read: {e}");
                continue;
            }
        };
        let iso = iso230::evaluate(&data);
        println!(
            "targets {} cycles {} B {:?} B_mean {:?} E {:?} R {:?}",
            data.n_targets(),
            data.n_cycles(),
            iso.axis.b,
            iso.axis.b_mean,
            iso.axis.e,
            iso.axis.r
        );
        match diagnose(&data, &Options::default()) {
            Ok(d) => println!(
                "{}",
                serde_json::to_string_pretty(&d.report).unwrap_or_default()
            ),
            Err(e) => println!("diagnose: {e}"),
        }
    }
}
