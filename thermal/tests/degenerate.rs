//! Degenerate but readable thermal tests: the diagnosis names nothing the data cannot support.

use thermal::{DiagnoseOptions, ThermalDataset, diagnose};

/// Every column constant (the hostile corpus' `thermal-constant.csv`, longer): no sensor
/// changes, so none can be collinear with another (their variance inflation is only the
/// clamp of a singular matrix), and no effect can be seen.
#[test]
fn constant_temperatures_name_no_collinear_sensors() {
    let mut csv = String::from("time_s,spindle_rpm,ch1_um,t1_c,t2_c,t3_c\n");
    for k in 0..200 {
        // The displacement moves a little; the temperatures stand still.
        let d = 1.0 + 0.01 * ((k * 7919) % 13) as f64;
        csv += &format!("{},0,{d},20,20,21.5\n", 60 * k);
    }
    let ds = ThermalDataset::from_csv(&csv).expect("reads");
    let d = diagnose(&ds, &DiagnoseOptions::default()).expect("diagnoses");
    let kinds: Vec<&str> = d.channels[0].findings.iter().map(|f| f.kind()).collect();
    assert!(
        !kinds.contains(&"collinear sensors"),
        "{kinds:?}\n{}",
        d.render()
    );
}
