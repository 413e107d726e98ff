//! CB-3 CapBall ADC driver.

#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
pub struct Config {
    pub port: String,
    pub rate_hz: u32,
    /// Per channel `[c1, c2, c3]`: `d = c1·V + c2·V² + c3·V³`, µm.
    pub poly: [[f64; 3]; 3],
    /// Sensor-to-machine homogeneous transform, row-major (identity when not calibrated).
    pub transform: [[f64; 4]; 4],
}

pub fn spawn(
    _cfg: Config,
    _clock: crate::HostClock,
    _tx: crate::EventSender,
    _cancel: tokio_util::sync::CancellationToken,
) -> tokio::task::JoinHandle<()> {
    todo!()
}
