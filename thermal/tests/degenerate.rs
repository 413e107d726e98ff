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

/// A fit never lists a term twice, and never a sensor (or a spindle speed) that does not
/// change: it is the intercept again, and it was chosen once per selection step (the same
/// zero-coefficient term of a constant sensor listed six times). A sensor that changes and
/// explains the displacement is kept.
#[test]
fn a_fit_holds_no_term_of_a_constant_input_and_no_term_twice() {
    let mut csv = String::from("time_s,spindle_rpm,ch1_um,ch2_um,t1_c,t2_c,t3_c\n");
    for k in 0..200 {
        let t3 = 20.0 + 2.0 * (k as f64 / 40.0).sin();
        let noise = 0.01 * ((k * 7919) % 13) as f64;
        csv += &format!("{},0,1,{},20,20,{t3}\n", 60 * k, 3.0 * (t3 - 20.0) + noise);
    }
    let ds = ThermalDataset::from_csv(&csv).expect("reads");
    let m = thermal::fit(&ds, &thermal::FitOptions::default()).expect("fits");
    for ch in &m.channels {
        let names: Vec<String> = ch
            .terms
            .iter()
            .map(|t| serde_json::to_string(&(&t.input, t.tau_heat_s, t.tau_cool_s)).unwrap())
            .collect();
        let mut uniq = names.clone();
        uniq.sort();
        uniq.dedup();
        assert_eq!(uniq.len(), names.len(), "{}: {names:?}", ch.channel);
        for n in &names {
            assert!(
                !n.contains("\"t1\"") && !n.contains("\"t2\"") && !n.contains("spindle"),
                "{}: a constant input in {n}",
                ch.channel
            );
        }
    }
    assert!(m.channels[0].terms.is_empty(), "{:?}", m.channels[0].terms);
    assert!(
        m.channels[1]
            .terms
            .iter()
            .any(|t| serde_json::to_string(&t.input).unwrap().contains("\"t3\"")),
        "{:?}",
        m.channels[1].terms
    );
}

/// Two sensors, one beside a heat source whose readings step with the spindle and one in calm
/// air, and a channel with no thermal response: "noisier than the median sensor" needs more
/// than one other sensor to compare with, so no sensor is called noisy (the demo's thermal run
/// named the head sensor "only adds noise" on its flat channel).
#[test]
fn with_two_sensors_none_is_called_noisy_for_its_real_steps() {
    let mut csv = String::from("time_s,spindle_rpm,flat_um,head_c,air_c\n");
    let mut head = 20.2;
    for k in 0..160 {
        let rpm = if (k / 20) % 2 == 0 { 0 } else { 4000 };
        // The head warms and cools towards its level with a time constant of 12 samples (36 min).
        let level = 20.0 + if rpm > 0 { 1.5 } else { 0.2 };
        head += (level - head) / 12.0;
        let head = head + 0.01 * (k % 3) as f64;
        let flat = 3.0 + 0.1 * ((k * 7919) % 11) as f64 / 11.0;
        csv += &format!(
            "{},{rpm},{flat},{head},{}\n",
            180 * k,
            20.0 + 0.001 * k as f64
        );
    }
    let ds = ThermalDataset::from_csv(&csv).expect("reads");
    let d = diagnose(&ds, &DiagnoseOptions::default()).expect("diagnoses");
    let text = d.render();
    assert!(!text.contains("noisy"), "{text}");
    assert!(!text.contains("only adds noise"), "{text}");
}
