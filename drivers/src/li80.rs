//! LI-80 laser interferometer driver.

/// What the daemon configures for the LI-80.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
pub struct Config {
    /// Serial port path, e.g. `/dev/metrolog-li80`.
    pub port: String,
    pub rate_hz: u32,
    /// Expansion coefficient of the measured axis, µm/(m·K), for the 20 °C compensation.
    pub alpha_um_per_m_k: f64,
}

/// Start the driver task. It runs until `cancel` fires, reconnecting with backoff.
pub fn spawn(
    _cfg: Config,
    _clock: crate::HostClock,
    _tx: crate::EventSender,
    _cancel: tokio_util::sync::CancellationToken,
) -> tokio::task::JoinHandle<()> {
    todo!()
}
