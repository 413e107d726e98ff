//! metrolog's thermal model of a machine tool, pure maths with no I/O.
//!
//! A thermal test logs displacements (µm) at a spindle or tool, temperatures (°C) and the spindle
//! speed. This crate reads such a test ([`ThermalDataset`]), fits the static least-squares
//! reference ([`static_fit`]), fits a model an engineer can check in physical terms — chosen
//! sensors through first-order lags, spindle heat through its own heating and cooling time
//! constants, judged on held-out time blocks ([`fit`], [`ThermalModel::predict`]) — diagnoses
//! what the static regression gets wrong ([`diagnose`]), and evaluates ISO 230-3 results
//! ([`iso230_3`]).
#![warn(unreachable_pub)]

mod baseline;
mod cv;
mod dataset;
mod diagnose;
mod error;
mod filter;
mod inputs;
pub mod iso230_3;
mod model;
mod predict;
mod select;
mod sensors;

pub use baseline::{StaticChannel, StaticFit, static_fit};
pub use cv::{GainRule, HeldOutGain};
pub use dataset::ThermalDataset;
pub use diagnose::{
    ChannelDiagnosis, DiagnoseOptions, Finding, Rung, ThermalDiagnosis, describe, diagnose,
};
pub use error::ThermalError;
pub use model::{
    ChannelModel, FitOptions, Input, Interval, MAX_SIZE, MIN_BLOCK_SAMPLES, Term, ThermalModel, fit,
};
pub use predict::{ChannelPrediction, Prediction};
