//! What a run counts, kept in one place: each driver's latest counters and the pose values by
//! instrument and status. The event sink that sees the events owns the one [`RunCounts`] (the
//! [`Recorder`](super::recorder::Recorder) in a run); the log's `/status` record and the
//! pipeline's [`Status`](super::pipeline::Status) are both read from it.

use std::collections::BTreeMap;

use drivers::{Counters, DriverEvent, Instrument};
use metrolog_log::topics::{PoseMsg, StatusMsg};
use types::PoseStatus;

/// The counts of a run (see the module's doc).
#[derive(Debug, Clone, Default)]
pub struct RunCounts {
    /// Each driver's latest counters snapshot (the drivers count; this keeps the last one), for
    /// the instruments that have sent one.
    pub drivers: BTreeMap<Instrument, Counters>,
    /// Pose values emitted, by instrument and status name ([`PoseStatus::name`]).
    pub poses: BTreeMap<Instrument, BTreeMap<&'static str, u64>>,
}

impl RunCounts {
    /// Takes a driver's counters snapshot; other events count nothing here.
    pub fn on_event(&mut self, ev: &DriverEvent) {
        if let DriverEvent::Counters {
            instrument,
            counters,
        } = ev
        {
            self.drivers.insert(*instrument, counters.clone());
        }
    }

    /// Counts one pose value.
    pub fn on_pose(&mut self, p: &PoseMsg) {
        *self
            .poses
            .entry(p.instrument)
            .or_default()
            .entry(p.status.name())
            .or_default() += 1;
    }

    /// Pose values emitted, all instruments and statuses.
    pub fn poses_total(&self) -> u64 {
        self.poses.values().flat_map(|m| m.values()).sum()
    }

    /// Pose values emitted with status `ok`.
    pub fn poses_ok(&self) -> u64 {
        self.poses
            .values()
            .filter_map(|m| m.get(PoseStatus::Ok.name()))
            .sum()
    }

    /// Pose values by status, all instruments together.
    pub fn poses_by_status(&self) -> BTreeMap<String, u64> {
        let mut m = BTreeMap::new();
        for (status, n) in self.poses.values().flatten() {
            *m.entry(status.to_string()).or_default() += n;
        }
        m
    }

    /// The `/status` record of these counts; `log_messages`: messages written to the log so far.
    pub fn status_msg(&self, log_messages: u64) -> StatusMsg {
        StatusMsg {
            instruments: self
                .drivers
                .iter()
                .map(|(i, c)| (i.name().to_string(), c.into()))
                .collect(),
            log_messages,
            poses: self.poses_by_status(),
        }
    }
}
