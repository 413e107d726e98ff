//! The `metrolog` binary's library: the acquisition service ([`acquire`]) and the
//! command-line commands ([`cmd`], one module per command). The log format is the crate
//! `metrolog-log`, the analyses `metrolog-analysis`.

pub mod acquire;
pub mod cli;
pub mod cmd;
pub mod exit;
pub mod live;
