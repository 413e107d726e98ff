//! One module per subcommand.

pub mod analyze;
pub mod demo;
pub mod diagnose;
pub mod identify;
pub mod info;
pub mod input;
pub mod parts;
pub mod plots;
pub mod replay;
pub mod run;
pub mod sim;
pub mod uncertainty;
pub mod volumetric;
