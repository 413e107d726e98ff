//! PSD-2 transimpedance board driver.

#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
pub struct Config {
    pub port: String,
    pub baud: u32,
    pub rate_hz: u32,
    /// Below this summed photocurrent (x1+x2 or y1+y2), pA, a sample is invalid.
    pub min_sum_pa: f64,
}

pub fn spawn(
    _cfg: Config,
    _clock: crate::HostClock,
    _tx: crate::EventSender,
    _cancel: tokio_util::sync::CancellationToken,
) -> tokio::task::JoinHandle<()> {
    todo!()
}
