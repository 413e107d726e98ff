//! What the simulation sent, exactly, and the truth behind it: for tests and the demo report.

use std::collections::BTreeMap;

use positioning::axis_model::Direction;
use protocol::can::TriggerEvent;
use serde::Serialize;

use crate::instrument::Device;

/// Everything sent so far (a snapshot from [`crate::SimHandle::record`]).
#[derive(Debug, Clone, Default, Serialize)]
pub struct Record {
    pub interferometer: DeviceRecord,
    pub capball: DeviceRecord,
    pub psd: DeviceRecord,
    pub trigger: TriggerRecord,
    /// True values per pose, filled when the program starts.
    pub truth: Vec<PoseTruth>,
    /// Real seconds after simulation start at which the program started.
    pub program_started_s: Option<f64>,
    /// Real seconds after simulation start at which the program-end frame was due.
    pub program_ended_s: Option<f64>,
}

impl Record {
    pub fn device(&self, d: Device) -> &DeviceRecord {
        match d {
            Device::Interferometer => &self.interferometer,
            Device::Capball => &self.capball,
            Device::Psd => &self.psd,
            Device::Trigger => &self.trigger.device,
        }
    }
    pub(crate) fn device_mut(&mut self, d: Device) -> &mut DeviceRecord {
        match d {
            Device::Interferometer => &mut self.interferometer,
            Device::Capball => &mut self.capball,
            Device::Psd => &mut self.psd,
            Device::Trigger => &mut self.trigger.device,
        }
    }
}

/// One streaming device's record.
#[derive(Debug, Clone, Default, Serialize)]
pub struct DeviceRecord {
    /// Every sample generated while streaming, in order, with its fate.
    pub samples: Vec<SentSample>,
    /// `$ENV` lines of the LI-80 (periodic and answers to `ENV?`).
    pub env: Vec<SentEnv>,
    /// Exact counts of everything injected or lost on the device side.
    pub faults: FaultCounts,
    /// Commands received and the answers given, in order.
    pub commands: Vec<(String, String)>,
    /// Power-ups (1 after start, +1 per replug).
    pub power_ups: u32,
    /// `DATUM` commands, as real seconds since simulation start.
    pub datums_s: Vec<f64>,
    /// Samples generated beyond the scenario's `record_max_samples` (counted, not kept; their
    /// faults are still in `faults`).
    pub unrecorded: u64,
}

impl DeviceRecord {
    /// Samples with the given fate.
    pub fn count(&self, fate: Fate) -> usize {
        self.samples.iter().filter(|s| s.fate == fate).count()
    }
}

/// Exact counts of the injected faults of one device.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct FaultCounts {
    /// Garbage bursts, each one rejected line or frame at the host.
    pub garbage: u64,
    pub bad_checksum: u64,
    pub truncated: u64,
    /// Samples not sent (sequence gaps at the host).
    pub dropped: u64,
    pub beam_interruptions: u64,
    pub unplugs: u64,
    /// Samples generated while no host had the port open (nothing written).
    pub not_connected: u64,
    /// Samples discarded because the host did not read and the device buffer was full.
    pub overflow: u64,
    /// Connects that began with the tail of a missed sample (`mid_frame_on_open`).
    pub partial_on_open: u64,
}

/// What became of a generated sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Fate {
    /// Written intact.
    Sent,
    /// Written with a wrong checksum / CRC.
    BadChecksum,
    /// Written cut short.
    Truncated,
    /// Not written (a sequence gap).
    Dropped,
    /// Not written: no host had the port open.
    NotConnected,
    /// Not written: the host did not read and the device buffer was full.
    Overflow,
}

/// One sample as generated.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SentSample {
    /// Power cycle (1-based) the sample belongs to.
    pub power_up: u32,
    /// Sequence number, unwrapped (the wire carries it modulo 2^32 or 2^16).
    pub seq: u64,
    /// Device clock, µs, unwrapped (the CB-3 wire carries it modulo 2^32).
    pub t_us: u64,
    /// True time of the sample, real seconds since simulation start.
    pub true_s: f64,
    pub values: SentValues,
    pub fate: Fate,
    /// A garbage burst was written just before this sample.
    pub garbage_before: bool,
}

/// The values a sample carries, as sent (before any corruption).
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum SentValues {
    Pos {
        raw_nm: i64,
        sig: u8,
        flags: u32,
    },
    Capball {
        ch: [i32; 3],
        flags: u8,
    },
    Psd {
        x1_pa: u64,
        x2_pa: u64,
        y1_pa: u64,
        y2_pa: u64,
        head_mc: i32,
    },
}

/// One `$ENV` line as sent.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SentEnv {
    pub power_up: u32,
    pub seq: u64,
    pub t_us: u64,
    pub true_s: f64,
    pub air_c: f64,
    pub air_pa: f64,
    pub rh_pct: f64,
    pub material_c: Vec<f64>,
    pub fate: Fate,
}

/// The SLCAN adapter's record.
#[derive(Debug, Clone, Default, Serialize)]
pub struct TriggerRecord {
    /// Commands and answers, power-ups, unplugs.
    pub device: DeviceRecord,
    /// Every trigger event of the CNC program, in order.
    pub events: Vec<SentTrigger>,
}

/// One trigger event of the CNC program.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SentTrigger {
    pub event: TriggerEvent,
    pub pose: u16,
    pub nc_ms: u32,
    /// Real seconds since simulation start.
    pub true_s: f64,
    pub fate: TriggerFate,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum TriggerFate {
    /// Delivered as a `t` frame.
    Sent,
    /// Left out of the program by fault injection.
    Missing,
    /// The adapter's CAN channel was not open (`O`), or no host had the port open.
    ChannelClosed,
}

/// The true values at one pose (what a perfect host would report).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PoseTruth {
    /// 1-based pose index.
    pub pose: u16,
    pub x_mm: f64,
    pub y_mm: f64,
    pub z_mm: f64,
    pub a_deg: f64,
    pub c_deg: f64,
    /// Real seconds after the program start.
    pub motion_start_s: f64,
    pub exact_stop_s: f64,
    pub dwell_end_s: f64,
    /// Instant the values below are evaluated at: middle of the settled part of the dwell
    /// (exact stop + ringing settle time .. dwell end), real seconds after the program start.
    pub eval_s: f64,
    /// Interferometer: 1-based target index of the axis model nearest `x_mm`, the approach
    /// direction, and the deviation (indicated minus programmed length at 20 °C), µm.
    pub target_index: usize,
    pub direction: Direction,
    pub deviation_um: f64,
    /// Change of the deviation per second of real time at `eval_s` (slow drift), µm/s.
    pub deviation_rate_um_per_s: f64,
    /// CapBall: the volumetric error in the machine frame, µm.
    pub capball_e_um: [f64; 3],
    /// PSD: spot position, µm.
    pub psd_x_um: f64,
    pub psd_y_um: f64,
    /// Mean material temperature at `eval_s`, °C.
    pub material_c: f64,
    /// Air temperature at `eval_s`, °C.
    pub air_c: f64,
}

/// Count of samples by fate.
pub fn fates(r: &DeviceRecord) -> BTreeMap<Fate, usize> {
    let mut m = BTreeMap::new();
    for s in &r.samples {
        *m.entry(s.fate).or_insert(0) += 1;
    }
    m
}
