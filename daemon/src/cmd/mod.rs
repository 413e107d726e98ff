//! The subcommands: one module per command, a folder per command family with a module per
//! subcommand or input kind; a command module takes its arguments and does the I/O, the maths
//! is in the maths crates and every report's text in `metrolog-analysis`.
//!
//! - acquisition: [`run`] (the service), [`demo`] and [`sim`] (the simulator, feature `sim`);
//! - logs: [`info`], [`replay`], [`recover`];
//! - analyses: [`analyze`], [`diagnose`] (positioning or CapBall), [`identify`] (CapBall, PSD,
//!   trajectories, sensor frame), [`volumetric`], [`parts`], [`uncertainty`], [`plan`],
//!   [`compensate`], [`report`] (with [`pdf`]), [`thermal`] (thermal model: fit, predict,
//!   diagnose; `analyze thermal` for ISO 230-3);
//! - shared by the commands, importing none of them: [`input`] (the one place that decides
//!   how an input is read: CSV or log), [`plots`] (the one place commands draw from),
//!   [`progress`] (progress bars).

pub mod analyze;
pub mod compensate;
#[cfg(feature = "sim")]
pub mod demo;
pub mod diagnose;
pub mod identify;
pub mod info;
pub mod input;
pub mod parts;
pub mod pdf;
pub mod plan;
pub mod plots;
pub mod progress;
pub mod recover;
pub mod replay;
pub mod report;
pub mod run;
#[cfg(feature = "sim")]
pub mod sim;
#[cfg(feature = "sim")]
pub mod sim_config;
pub mod thermal;
pub mod uncertainty;
pub mod volumetric;
