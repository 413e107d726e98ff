//! CNC exact-stop triggers from SLCAN (serial) or SocketCAN, decoded by the same code.

#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
pub struct SlcanConfig {
    pub port: String,
    pub can_id: u32,
}

#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
pub struct SocketCanConfig {
    pub interface: String,
    pub can_id: u32,
}

pub fn spawn_slcan(
    _cfg: SlcanConfig,
    _clock: crate::HostClock,
    _tx: crate::EventSender,
    _cancel: tokio_util::sync::CancellationToken,
) -> tokio::task::JoinHandle<()> {
    todo!()
}

pub fn spawn_socketcan(
    _cfg: SocketCanConfig,
    _clock: crate::HostClock,
    _tx: crate::EventSender,
    _cancel: tokio_util::sync::CancellationToken,
) -> tokio::task::JoinHandle<()> {
    todo!()
}
