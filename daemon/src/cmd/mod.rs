//! One module per subcommand.

pub mod analyze;
pub mod compensate;
pub mod demo;
pub mod diagnose;
pub mod diagnose_capball;
pub mod identify;
pub mod identify_mc;
pub mod identify_psd_mc;
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
pub mod sim;
pub mod uncertainty;
pub mod volumetric;
