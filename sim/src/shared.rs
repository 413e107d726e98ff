//! What the device tasks share: the world, the record, the program's state and the devices'
//! states, and the control channel of each device task.

use std::path::PathBuf;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use serde::Serialize;
use tokio::sync::{mpsc, oneshot, watch};

use crate::error::SimError;
use crate::instrument::Device;
use crate::physics::World;
use crate::record::Record;

/// Requests to a device task.
pub(crate) enum Control {
    Unplug(oneshot::Sender<()>),
    Replug(oneshot::Sender<Result<PathBuf, SimError>>),
    Shutdown(oneshot::Sender<()>),
}

/// What a device is doing, as seen from the device.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
pub struct DeviceState {
    /// The device is plugged in (its link exists).
    pub plugged: bool,
    /// A host has its port open.
    pub host_connected: bool,
    /// Streaming samples (the SLCAN adapter: CAN channel open with `O`).
    pub active: bool,
    /// The configured sample rate, Hz (0 for the SLCAN adapter).
    pub rate_hz: u32,
    /// Power-ups so far (1 after start, +1 per replug).
    pub power_ups: u32,
}

/// Program state shared by the tasks.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct ProgramState {
    pub started: Option<Instant>,
    pub done: bool,
}

/// What every device task shares.
pub(crate) struct Shared {
    pub world: World,
    pub t0: Instant,
    pub program: watch::Sender<ProgramState>,
    pub states: watch::Sender<[DeviceState; 4]>,
    pub record: Mutex<Record>,
    pub controls: Vec<mpsc::Sender<Control>>,
    pub runtime: tokio::runtime::Handle,
}

impl Shared {
    pub fn lock_record(&self) -> MutexGuard<'_, Record> {
        // A panic in another task must not take the record with it.
        self.record.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Start the CNC program at `at` (once): fill in the truth and arm the timed faults.
    pub fn start_program_at(self: &Arc<Self>, at: Instant) {
        let mut first = false;
        self.program.send_if_modified(|p| {
            if p.started.is_none() {
                p.started = Some(at);
                first = true;
                true
            } else {
                false
            }
        });
        if !first {
            return;
        }
        let start_s = at.saturating_duration_since(self.t0).as_secs_f64();
        let truth = self.world.truth();
        {
            let mut r = self.lock_record();
            r.truth = truth;
            r.program_started_s = Some(start_s);
        }
        for u in self.world.scenario.faults.unplugs.clone() {
            let me = self.clone();
            self.runtime.spawn(async move {
                tokio::time::sleep_until((at + Duration::from_secs_f64(u.at_s)).into()).await;
                let _ = me.control(u.device, Control::Unplug).await;
                tokio::time::sleep(Duration::from_secs_f64(u.duration_s)).await;
                let _ = me.control(u.device, Control::Replug).await;
            });
        }
    }

    pub async fn control<T>(
        &self,
        d: Device,
        make: impl FnOnce(oneshot::Sender<T>) -> Control,
    ) -> Result<T, SimError> {
        let (tx, rx) = oneshot::channel();
        self.controls[d.index()]
            .send(make(tx))
            .await
            .map_err(|_| SimError::Stopped(d.name()))?;
        rx.await.map_err(|_| SimError::Stopped(d.name()))
    }
}
