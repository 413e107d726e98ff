//! Machine geometry, pure maths with no I/O (papers 001, 003, 004):
//!
//! - [`kinematics`]: machine poses, axes and the kinematic chain with its link errors;
//! - [`capball`]: the CapBall model, its identification, sensor-frame calibration,
//!   trajectories and dataset;
//! - [`capball_effects`]: the CapBall effects beyond its 14 parameters (drifts of the
//!   measuring loop, sensor gains, motion errors of the rotary axes);
//! - [`linalg`]: a singular value decomposition that always ends (finite input, capped
//!   iterations), for every SVD of measured data;
//! - [`psd_frame`]: the PSD laser frame and its 13 errors;
//! - [`volumetric`]: volumetric errors of a machine from its error model.

pub mod capball;
pub mod capball_effects;
pub mod kinematics;
pub mod linalg;
pub mod psd_frame;
pub mod volumetric;
