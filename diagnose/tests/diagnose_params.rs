//! Diagnosis details: fitted parameters against the generating truth (within their stated
//! uncertainties), the temperature-explained scale change, the extended model reproducing the
//! run, and the caveats for runs without times.

use diagnose::axis::{Options, diagnose, reproduction_check};
use positioning::axis_model::{AxisModel, Effect};
use positioning::positioning_data::{simulate, standard_schedule};

fn axis(m: usize, noise_um: f64, effects: Vec<Effect>) -> AxisModel {
    AxisModel {
        axis: "X".into(),
        targets_mm: (0..m).map(|i| 25.0 * i as f64 + (i % 3) as f64).collect(),
        systematic_up_um: (0..m).map(|i| (i as f64 * 0.9).sin() * 2.0).collect(),
        systematic_down_um: (0..m).map(|i| (i as f64 * 0.9).sin() * 2.0 - 1.5).collect(),
        noise_um,
        effects,
    }
}

#[test]
fn cyclic_drift_parameters_within_their_uncertainty() {
    let truth = Effect::CyclicDrift {
        period_s: 1500.0,
        amplitude_um: 1.2,
        phase_rad: 0.7,
    };
    let m = axis(11, 0.4, vec![truth]);
    let d = simulate(&m, &standard_schedule(11, 20, 10.0), 3);
    let r = diagnose(&d, &Options::default()).unwrap();
    let f = &r.report.findings[0];
    assert_eq!(f.effect.name(), "cyclic_drift");
    let (p, up) = (f.params()["period_s"], f.params_u["period_s"]);
    let (a, ua) = (f.params()["amplitude_um"], f.params_u["amplitude_um"]);
    assert!((p - 1500.0).abs() < 4.0 * up, "period {p} ± {up}");
    assert!((a - 1.2).abs() < 4.0 * ua, "amplitude {a} ± {ua}");
    assert!(f.heldout_rms_after_um < f.heldout_rms_before_um);
    assert!(
        f.cause.contains(&format!("{:.1} min", p / 60.0)) && f.cause.contains("coolant"),
        "{}",
        f.cause
    );
    // The extended model carries the effect and the baseline fitted from the data.
    let Effect::CyclicDrift { period_s, .. } = r.model.effects[0] else {
        panic!()
    };
    assert!((period_s - 1500.0).abs() < 4.0 * up);
    for (a, b) in r.model.systematic_up_um.iter().zip(&m.systematic_up_um) {
        assert!((a - b).abs() < 0.5, "{a} vs {b}");
    }
    assert!((r.model.noise_um - 0.4).abs() < 0.05);
}

#[test]
fn warmup_and_linear_drift_parameters() {
    let m = axis(
        9,
        0.3,
        vec![Effect::ExponentialWarmup {
            amplitude_um: -2.0,
            tau_s: 1800.0,
        }],
    );
    let d = simulate(&m, &standard_schedule(9, 20, 20.0), 4);
    let r = diagnose(&d, &Options::default()).unwrap();
    let f = &r.report.findings[0];
    assert_eq!(f.effect.name(), "exponential_warmup");
    assert!((f.params()["amplitude_um"] + 2.0).abs() < 4.0 * f.params_u["amplitude_um"]);
    assert!((f.params()["tau_s"] - 1800.0).abs() < 4.0 * f.params_u["tau_s"]);

    let m = axis(9, 0.3, vec![Effect::LinearDrift { rate_um_per_h: 0.8 }]);
    let d = simulate(&m, &standard_schedule(9, 20, 20.0), 5);
    let r = diagnose(&d, &Options::default()).unwrap();
    let f = &r.report.findings[0];
    assert_eq!(f.effect.name(), "linear_drift");
    assert!((f.params()["rate_um_per_h"] - 0.8).abs() < 4.0 * f.params_u["rate_um_per_h"]);
}

#[test]
fn uncompensated_material_temperature_gives_the_expansion_coefficient() {
    // The material warms by 1.5 K with τ = 1 h; readings not normalised to 20 °C, so they
    // carry α·x·ΔT with α = 11.7 µm/(m·K).
    let (alpha, dt_k, tau_s) = (11.7, 1.5, 3600.0);
    let m = axis(
        11,
        0.3,
        vec![Effect::ThermalExpansion {
            scale_ppm: alpha * dt_k,
            tau_s,
        }],
    );
    let mut sched = standard_schedule(11, 15, 20.0);
    for s in &mut sched {
        s.material_c = Some(20.0 + dt_k * (1.0 - (-s.time_s / tau_s).exp()));
    }
    let mut d = simulate(&m, &sched, 9);
    d.material_compensation = false;
    d.alpha_um_per_m_k = Some(11.7);
    let r = diagnose(&d, &Options::default()).unwrap();
    let f = &r.report.findings[0];
    assert_eq!(f.effect.name(), "thermal_expansion");
    let (a, u) = (
        f.params()["alpha_um_per_m_k"],
        f.params_u["alpha_um_per_m_k"],
    );
    assert!((a - alpha).abs() < 4.0 * u + 0.3, "alpha {a} ± {u}");
    assert!(f.cause.contains("material_compensation"), "{}", f.cause);
    let end = alpha * dt_k * (1.0 - (-sched.last().unwrap().time_s / tau_s).exp());
    assert!((f.params()["scale_ppm"] - end).abs() < 4.0 * f.params_u["scale_ppm"] + 0.5);
}

#[test]
fn the_extended_model_reproduces_the_run_better_than_the_baseline() {
    let m = axis(
        11,
        0.3,
        vec![
            Effect::ExponentialWarmup {
                amplitude_um: 3.0,
                tau_s: 2400.0,
            },
            Effect::LocalAnomaly {
                index: 4,
                std_ratio: 4.0,
            },
        ],
    );
    let d = simulate(&m, &standard_schedule(11, 20, 15.0), 21);
    let r = diagnose(&d, &Options::default()).unwrap();
    let names = r.report.effects();
    assert!(
        names.contains(&"exponential_warmup") && names.contains(&"local_anomaly"),
        "{names:?}"
    );
    let rep = reproduction_check(&d, &r.model, 8);
    // The baseline reproduces the means by construction but not the scatter the drift and the
    // anomaly add; the extended model reproduces both.
    assert!(rep.s_rms_um < 0.5 * rep.baseline_s_rms_um, "{rep:?}");
    assert!(rep.s_rms_um < 0.15, "{rep:?}");
    assert!(rep.mean_rms_um < 0.25, "{rep:?}");
    // The model written is what the simulator reads.
    let text = toml::to_string(&r.model).unwrap();
    let back: AxisModel = toml::from_str(&text).unwrap();
    assert_eq!(back.effects.len(), 2);
}

#[test]
fn without_times_the_report_says_so() {
    let m = axis(6, 0.3, vec![]);
    let mut d = simulate(&m, &standard_schedule(6, 6, 1.0), 2);
    d.has_times = false;
    let r = diagnose(&d, &Options::default()).unwrap();
    assert!(r.report.findings.is_empty());
    assert!(r.report.notes.iter().any(|n| n.contains("no time_s")));
}

#[test]
fn too_small_a_run_is_a_clear_error() {
    let m = axis(2, 0.3, vec![]);
    let d = simulate(&m, &standard_schedule(2, 2, 1.0), 2);
    let e = diagnose(&d, &Options::default()).unwrap_err().to_string();
    assert!(e.contains("at least 3 cycles"), "{e}");
}

#[test]
fn axis_model_reads_from_an_axis_table_or_bare() {
    use diagnose::axis::{AxisTable, axis_model_from_toml};
    let m = axis(4, 0.3, vec![Effect::LinearDrift { rate_um_per_h: 1.0 }]);
    let table = toml::to_string(&AxisTable { axis: m.clone() }).unwrap();
    assert!(table.contains("[axis]"));
    assert_eq!(axis_model_from_toml(&table).unwrap(), m);
    let scenario = format!("seed = 3\n[program]\nx = 1\n{table}");
    assert_eq!(axis_model_from_toml(&scenario).unwrap(), m);
    assert_eq!(
        axis_model_from_toml(&toml::to_string(&m).unwrap()).unwrap(),
        m
    );
    assert!(axis_model_from_toml("axis = 3").is_err());
}
