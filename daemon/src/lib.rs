//! The `metrolog` binary's library: configuration, acquisition pipeline, MCAP log, replay and
//! the command-line commands (one module per command under [`cmd`]).

pub mod analysis;
pub mod cli;
pub mod cmd;
pub mod config;
pub mod log;
pub mod pipeline;
pub mod plot;
pub mod service;
