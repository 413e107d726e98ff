//! `metrolog identify`: machine errors from CapBall (paper 001) or PSD laser-frame (paper 003)
//! measurements, CapBall trajectories and sensor-frame calibration. One module per
//! subcommand; the Monte Carlo uncertainties of the CapBall and PSD identifications in their
//! own modules ([`capball_mc`], [`psd_mc`]). The reports' text is in
//! `metrolog_analysis::identify_text`, the inputs are read by `cmd::input`.

pub mod capball;
pub mod capball_mc;
pub mod psd;
pub mod psd_mc;
pub mod sensor_frame;
pub mod trajectory;

#[derive(Debug, clap::Subcommand)]
pub enum Command {
    /// Identify the 8 link + 6 setup errors of a five-axis machine from a CapBall dataset.
    ///
    /// DATA: CSV `run,pose,time_s,x_mm,y_mm,z_mm,a_deg,c_deg,ex_um,ey_um,ez_um` (shared
    /// dataset format; volumetric errors in the machine frame, µm). Each run is identified
    /// separately. The ball position is found from the poses (the table point under the tool).
    Capball(capball::CapballArgs),
    /// Derive 13 errors from PSD laser-frame readings, relative to a reference run.
    ///
    /// DATA: CSV `run,segment,point,r1_um,r2_um`: segment 1..5 (S1 along Y at x_lo, S2 along X
    /// at y_hi, S3 along Y at x_hi, S4 along X at y_lo, S5 along Z), point 1..n in ascending
    /// coordinate (S1: 7 points = the first 7 Y positions of S3; others 11), (r1, r2) =
    /// (ex, ez) on S1/S3, (ey, ez) on S2/S4, (ex, ey) on S5, µm. See
    /// geometry/src/psd_frame.md for the model.
    Psd(psd::PsdArgs),
    /// Write a CapBall identification trajectory (`pose,x_mm,y_mm,z_mm,a_deg,c_deg`).
    Trajectory(trajectory::TrajectoryArgs),
    /// Sensor-frame calibration `T = M S⁺` from the 5×5×5 cube of programmed moves.
    ///
    /// DATA: CSV `mx_um,my_um,mz_um,s1_um,s2_um,s3_um` (programmed displacement, sensor readings).
    SensorFrame(sensor_frame::SensorFrameArgs),
}

pub fn run(c: Command) -> anyhow::Result<()> {
    match c {
        Command::Capball(a) => capball::run(a),
        Command::Psd(a) => psd::run(a),
        Command::Trajectory(a) => trajectory::run(a),
        Command::SensorFrame(a) => sensor_frame::run(a),
    }
}
