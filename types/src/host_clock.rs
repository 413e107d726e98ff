//! The host clock every driver stamps arrival times with.

/// The host clock: monotonic, expressed as ns since the Unix epoch (wall time read once at
/// start, then advanced by the monotonic clock, so it never jumps).
#[derive(Debug, Clone, Copy)]
pub struct HostClock {
    start_mono: std::time::Instant,
    start_unix_ns: u64,
}

impl HostClock {
    pub fn new() -> Self {
        let start_unix_ns = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos() as u64)
            .unwrap_or(0);
        HostClock {
            start_mono: std::time::Instant::now(),
            start_unix_ns,
        }
    }
    /// Now, ns since the Unix epoch along the monotonic clock.
    pub fn now_ns(&self) -> u64 {
        self.start_unix_ns + self.start_mono.elapsed().as_nanos() as u64
    }
}

impl Default for HostClock {
    fn default() -> Self {
        Self::new()
    }
}
