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

/// `println!` for a report's text: the line reaches the terminal without control characters
/// (a name read from an input cannot move the cursor or recolour it) and a stdout that cannot
/// be written is an error, not a panic ([`input::print_out`]). Evaluates to `anyhow::Result`.
macro_rules! outln {
    ($($arg:tt)*) => {
        $crate::cmd::input::print_out(&format!("{}\n", format_args!($($arg)*)))
    };
}

/// `print!` as [`outln!`] prints a line.
macro_rules! out {
    ($($arg:tt)*) => {
        $crate::cmd::input::print_out(&format!($($arg)*))
    };
}

/// `eprintln!` for notes and warnings that quote an input: without control characters.
macro_rules! errln {
    ($($arg:tt)*) => {
        $crate::cmd::input::print_err(&format!($($arg)*))
    };
}

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
