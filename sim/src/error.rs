//! Why the simulation could not do what was asked.

use crate::scenario::ScenarioError;

/// Why the simulation could not do what was asked.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// invalid scenario: {0}
    #[error("invalid scenario: {0}")]
    Scenario(#[from] ScenarioError),
    /// cannot create the simulation directory {path}: {source}
    #[error("cannot create the simulation directory {path}: {source}")]
    Dir {
        path: String,
        source: std::io::Error,
    },
    /// cannot create the pseudo-terminal for {path}: {source}
    #[error("cannot create the pseudo-terminal for {path}: {source}")]
    Pty {
        path: String,
        source: std::io::Error,
    },
    /// the simulation is not running inside a tokio runtime
    #[error(
        "the simulation is not running inside a tokio runtime: call Sim::start from async code"
    )]
    NoRuntime,
    /// the device task of {0} has ended (the simulation was shut down)
    #[error("the device task of {0} has ended (the simulation was shut down)")]
    Stopped(&'static str),
}
