//! `metrolog thermal`: the thermal model of a machine tool from a thermal test (issue 25) —
//! [`fit`] the model (chosen sensors through lags, spindle heat), [`predict`] displacements from
//! temperatures and speed, [`diagnose`] what the static all-temperature regression misses. The
//! ISO 230-3 evaluation of a test is `metrolog analyze thermal` ([`iso230_3`]).

pub mod diagnose;
pub mod fit;
pub mod from_log;
pub mod iso230_3;
pub mod predict;

#[derive(Debug, clap::Subcommand)]
pub enum Command {
    /// Fit the thermal model of a test's displacements and write it as JSON.
    Fit(fit::Args),
    /// Predict displacements (with intervals) from temperatures and spindle speed.
    Predict(predict::Args),
    /// Name what the static all-temperature regression gets wrong (lags, unseen spindle heat,
    /// heating/cooling asymmetry, collinear or noisy sensors), with held-out evidence.
    Diagnose(diagnose::Args),
}

pub fn run(c: Command) -> anyhow::Result<()> {
    match c {
        Command::Fit(a) => fit::run(a),
        Command::Predict(a) => predict::run(a),
        Command::Diagnose(a) => diagnose::run(a),
    }
}
