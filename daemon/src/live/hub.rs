//! What the log writer's tap and the live view's client sessions share: the [`Hub`] (the
//! channels, the lossy broadcast of every message and the latched latest ones) and the
//! [`tap`] that feeds it.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use metrolog_log::trajectory::TrajectoryRow;
use metrolog_log::{ChannelSpec, MessageTap};
use tokio::sync::broadcast;

/// Messages a client may fall behind before it starts losing the oldest (at the live rates
/// — four raw topics at 10 Hz, /status at 1 Hz, a few /pose and triggers — about 5 s).
pub const BACKLOG: usize = 256;

/// How many of the latest messages of a JSON topic a new subscriber gets at once: the current
/// pose of every instrument, the recent faults, the last counters and trigger.
fn latch_depth(topic: &str) -> usize {
    match topic {
        "/pose" => 8,
        "/event" => 16,
        "/status" | "/cnc/trigger" => 1,
        _ => 0,
    }
}

/// Which latched messages stand for the same thing: a `/pose` its instrument's (a new client
/// must get every instrument's current pose, however many poses the others finished since),
/// every other message the channel's one latest.
fn latch_key(data: &[u8]) -> Option<String> {
    #[derive(serde::Deserialize)]
    struct Key {
        instrument: String,
    }
    serde_json::from_slice::<Key>(data)
        .ok()
        .map(|k| k.instrument)
}

/// Drops the oldest latched message that a later one of the same key replaces (the oldest of
/// all when none does).
fn evict_one(q: &mut VecDeque<Arc<LiveMsg>>) {
    let keys: Vec<Option<String>> = q.iter().map(|m| latch_key(&m.data)).collect();
    let replaced = (0..keys.len()).find(|&i| keys[i + 1..].contains(&keys[i]));
    q.remove(replaced.unwrap_or(0));
}

/// One message as the log holds it: channel (index into [`Hub::channels`]), log time, bytes.
#[derive(Debug)]
pub struct LiveMsg {
    /// Order of publication (a client told the latched messages skips them in the stream).
    pub seq: u64,
    pub channel: usize,
    pub log_ns: u64,
    pub data: Vec<u8>,
}

/// What a client is told about the run when it connects (`serverInfo`).
#[derive(Debug, Clone, Default)]
pub struct RunInfo {
    pub machine: String,
    /// The log file's name.
    pub session: String,
    /// The temperature module's channel names (the page names the `/temperature` values with
    /// them).
    pub temperature_sensors: Vec<String>,
    /// The run's pose table (the page shows "pose k of N" and the pose's target).
    pub trajectory: Vec<TrajectoryRow>,
    /// Samples a steady value averages (`[detector] samples`).
    pub window_samples: usize,
}

/// What the tap and the client sessions share.
pub struct Hub {
    pub channels: Vec<ChannelSpec>,
    tx: broadcast::Sender<Arc<LiveMsg>>,
    latest: Mutex<Vec<VecDeque<Arc<LiveMsg>>>>,
    /// Messages skipped by slow clients, all clients together.
    pub dropped: AtomicU64,
    published: AtomicU64,
    /// The run, for `serverInfo`.
    pub run: RunInfo,
}

impl Hub {
    pub(crate) fn new(run: RunInfo) -> Hub {
        let channels = metrolog_log::channel_specs();
        let latest = vec![VecDeque::new(); channels.len()];
        Hub {
            channels,
            tx: broadcast::channel(BACKLOG).0,
            latest: Mutex::new(latest),
            dropped: AtomicU64::new(0),
            published: AtomicU64::new(0),
            run,
        }
    }

    /// A receiver of every message published from now on.
    pub fn subscribe(&self) -> broadcast::Receiver<Arc<LiveMsg>> {
        self.tx.subscribe()
    }

    /// The latched messages of a channel, oldest first.
    pub fn latched(&self, channel: usize) -> Vec<Arc<LiveMsg>> {
        match self.latest.lock() {
            Ok(l) => l
                .get(channel)
                .map(|q| q.iter().cloned().collect())
                .unwrap_or_default(),
            Err(_) => Vec::new(),
        }
    }

    fn publish(&self, channel: usize, log_ns: u64, data: &[u8]) {
        let depth = latch_depth(self.channels[channel].topic);
        if depth == 0 && self.tx.receiver_count() == 0 {
            return; // nobody watches: no copy
        }
        let msg = Arc::new(LiveMsg {
            seq: self.published.fetch_add(1, Ordering::Relaxed),
            channel,
            log_ns,
            data: data.to_vec(),
        });
        if depth > 0
            && let Ok(mut l) = self.latest.lock()
        {
            let q = &mut l[channel];
            q.push_back(msg.clone());
            if q.len() > depth {
                evict_one(q);
            }
        }
        // Err only when no client is connected.
        let _ = self.tx.send(msg);
    }
}

/// The tap for [`metrolog_log::LogWriter::set_tap`]: every JSON message, and at most `raw_hz`
/// raw batches per second and raw topic (by log time), go to the hub.
pub fn tap(hub: Arc<Hub>, raw_hz: u32) -> MessageTap {
    let gap_ns = 1_000_000_000 / u64::from(raw_hz.max(1));
    let mut last_raw: Vec<Option<u64>> = vec![None; hub.channels.len()];
    Box::new(move |topic, log_ns, data| {
        let Some(i) = hub.channels.iter().position(|c| c.topic == topic) else {
            return;
        };
        if hub.channels[i].message_encoding == "protobuf" {
            if raw_hz == 0 || last_raw[i].is_some_and(|t| log_ns < t.saturating_add(gap_ns)) {
                return;
            }
            last_raw[i] = Some(log_ns);
        }
        hub.publish(i, log_ns, data);
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn channel(hub: &Hub, topic: &str) -> usize {
        hub.channels.iter().position(|c| c.topic == topic).unwrap()
    }

    fn instruments(hub: &Hub, ch: usize) -> Vec<String> {
        hub.latched(ch)
            .iter()
            .filter_map(|m| latch_key(&m.data))
            .collect()
    }

    /// A PSD unplugged while the others go on: a page opened 20 poses later still gets the
    /// PSD's last pose (it was lost from a plain last-8 latch), and at most 8 are latched.
    #[test]
    fn every_instrument_s_current_pose_stays_latched() {
        let hub = Hub::new(RunInfo::default());
        let ch = channel(&hub, "/pose");
        let pose = |inst: &str, k: u32| format!(r#"{{"instrument":"{inst}","pose":{k}}}"#);
        hub.publish(ch, 1, pose("psd", 1).as_bytes());
        for k in 1..=20 {
            hub.publish(ch, 2 * k as u64, pose("capball", k).as_bytes());
            hub.publish(ch, 2 * k as u64 + 1, pose("interferometer", k).as_bytes());
        }
        let got = instruments(&hub, ch);
        assert_eq!(got.len(), 8, "{got:?}");
        assert_eq!(got[0], "psd", "{got:?}");
        let last = hub.latched(ch).last().map(|m| m.data.clone()).unwrap();
        assert_eq!(last, pose("interferometer", 20).into_bytes());
        // A channel without the key keeps its latest (one for /status).
        let st = channel(&hub, "/status");
        for k in 0..3u64 {
            hub.publish(st, k, format!(r#"{{"n":{k}}}"#).as_bytes());
        }
        let kept: Vec<Vec<u8>> = hub.latched(st).iter().map(|m| m.data.clone()).collect();
        assert_eq!(kept, vec![br#"{"n":2}"#.to_vec()]);
    }
}
