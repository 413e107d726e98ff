//! Pose detection, with no I/O: the same code live (the acquisition service) and in replay.
//!
//! - [`PoseEngine`]: fed every sample and trigger in log order, gives the `/pose` records
//!   ([`types::PoseMsg`]) of each pose-valued instrument;
//! - [`SteadyDetector`]: one instrument's steady-value detection (150 steady samples after the
//!   axis settled, docs/design.md);
//! - [`ClockFit`], [`NcClock`], [`Unwrap`]: device and NC clocks fitted against the host clock
//!   (the timing model), used by the drivers to stamp samples and by the engine to place
//!   triggers.
#![warn(unreachable_pub)]

mod clock;
mod dwell_gate;
mod engine;
mod steady;

pub use clock::{
    ClockFit, MAX_DRIFT_PPM, MIN_WINDOWS, NC_MAX_DELAY_NS, NC_MAX_LEAD_NS, NcClock, NcPoint, Unwrap,
};
pub use engine::{HOLD_NS, PoseEngine};
pub use steady::{LATE_MARGIN_NS, SteadyDetector};
