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

/// The held-out blocks for a test of `n` samples: `asked`, else the library's default (8), or
/// for a shorter test as many blocks of 10 samples or more as it has (at least 3, below which
/// the fit says what is needed), with a note on stderr saying so.
pub fn blocks_for(n: usize, asked: Option<usize>) -> usize {
    if let Some(b) = asked {
        return b;
    }
    let default = thermal::FitOptions::default().blocks;
    let fit = (n / thermal::MIN_BLOCK_SAMPLES).clamp(3, default);
    if fit < default {
        errln!(
            "note: {n} samples: {fit} held-out time blocks instead of {default} (each needs 10 samples or more)"
        );
    }
    fit
}

pub fn run(c: Command) -> anyhow::Result<()> {
    match c {
        Command::Fit(a) => fit::run(a),
        Command::Predict(a) => predict::run(a),
        Command::Diagnose(a) => diagnose::run(a),
    }
}
