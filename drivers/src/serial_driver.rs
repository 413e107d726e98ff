//! What every serial driver shares: a session on one open port (commands and their answers,
//! data handled meanwhile) and the connect / configure / stream / reconnect loop.
//!
//! A sample's way is one direction: [`SerialLink`] (port bytes → protocol decoder) →
//! [`SamplePath`] (converter → stamper → reporter → `DriverEvent`). The instrument's
//! [`SerialDriver`] only issues commands through the session; nothing calls back into it.
//!
//! Sessions and the loop are generic over the byte stream ([`Port`]); [`run`] takes the step
//! that opens it, so a driver runs unchanged over an in-memory stream in the tests. [`spawn`]
//! runs a driver on its serial port.

use std::collections::VecDeque;
use std::sync::OnceLock;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use tokio_util::sync::CancellationToken;

use crate::DriverError;
use crate::sample_path::{FrameConverter, SamplePath};
use crate::serial_link::{Port, SerialLink, open_port};

/// How long a command waits for its answer.
pub(crate) const ANSWER_TIMEOUT: Duration = Duration::from_secs(1);
/// Longest wait for an answer while the device keeps sending data (see `command`).
pub(crate) const ANSWER_TIMEOUT_BUSY: Duration = Duration::from_secs(30);
/// First and longest wait between attempts to open a vanished port.
const BACKOFF_MIN: Duration = Duration::from_millis(100);
const BACKOFF_MAX: Duration = Duration::from_secs(2);
/// Read coalescing (docs/design.md, "Where the daemon's CPU goes"): while streaming, a reader
/// that has read pauses until the next tick of the coalescing period before it reads again, so
/// one read takes everything the device sent meanwhile and a device costs about one wake-up per
/// period whatever its rate. The ticks are shared by every reader of the process (multiples of
/// the period since the first tick asked for), so the readers wake together. The default
/// period; `set_read_coalesce` changes it (the daemon's `[run] read_coalesce_ms`), zero turns
/// coalescing off.
pub const READ_COALESCE_DEFAULT: Duration = Duration::from_millis(20);
/// The coalescing period in µs (see [`READ_COALESCE_DEFAULT`]).
static READ_COALESCE_US: AtomicU64 = AtomicU64::new(READ_COALESCE_DEFAULT.as_micros() as u64);
/// A read at least this long is read again at once, without the pause: the tty layer hands
/// out at most its 4 KiB line-discipline buffer per read (N_TTY_BUF_SIZE), so a full read
/// means more is waiting (the LI-80 at 10 kHz sends 9 kB per 20 ms).
const FULL_READ: usize = 3 * 1024;
/// About this often one read waits for the next bytes without the pause: its arrival time is
/// then the write time plus the wake-up latency only, which gives the clock fit
/// ([`detect::ClockFit`], windows of 0.5 s) the least-delayed points it needs (a coalesced read
/// dates everything in it by the read, up to a period late). Ten probes per second whatever
/// the period ([`probe_every`]).
const PROBE_PERIOD: Duration = Duration::from_millis(100);

/// Reads per probe at the coalescing period `period` (at least 1: every read a probe).
fn probe_every(period: Duration) -> u32 {
    let p = period.as_micros().max(1);
    (PROBE_PERIOD.as_micros() / p).clamp(1, 1000) as u32
}

/// Sets the read coalescing period of every serial reader started from now on (zero: read as
/// soon as bytes arrive).
pub fn set_read_coalesce(period: Duration) {
    READ_COALESCE_US.store(period.as_micros() as u64, Ordering::Relaxed);
}

/// The read coalescing period in force.
pub fn read_coalesce() -> Duration {
    Duration::from_micros(READ_COALESCE_US.load(Ordering::Relaxed))
}

/// How long after a tick a consumer takes what the readers read on it
/// ([`next_read_tick`]): a read of the tick that ends later is late, and says so
/// ([`late_reads`]).
pub const TAKE_AFTER_TICK: Duration = Duration::from_millis(1);

/// Notified when a reader's read of a tick ended more than [`TAKE_AFTER_TICK`] after the tick
/// (a burst of full reads, a loaded host): its samples missed the consumer's take of that tick
/// and would wait a whole period for the next one (docs/design.md, "Where the daemon's CPU
/// goes"). One permit is kept while nobody waits.
pub fn late_reads() -> &'static tokio::sync::Notify {
    static LATE: OnceLock<tokio::sync::Notify> = OnceLock::new();
    LATE.get_or_init(tokio::sync::Notify::new)
}

/// The next tick of the read coalescing period after now (see [`READ_COALESCE_DEFAULT`]):
/// the readers read again then, so a consumer that takes their data just after it wakes once
/// for all of them. Now itself when coalescing is off.
pub fn next_read_tick() -> tokio::time::Instant {
    let period = read_coalesce();
    if period.is_zero() {
        return tokio::time::Instant::now();
    }
    next_tick(period)
}

/// The next tick of `period` after now, on the process-wide grid the readers share.
fn next_tick(period: Duration) -> tokio::time::Instant {
    static EPOCH: OnceLock<tokio::time::Instant> = OnceLock::new();
    let epoch = *EPOCH.get_or_init(tokio::time::Instant::now);
    let since = tokio::time::Instant::now().saturating_duration_since(epoch);
    let p = period.as_nanos().max(1);
    let k = since.as_nanos() / p + 1;
    epoch + Duration::from_nanos((k * p).min(u64::MAX as u128) as u64)
}

/// The LI-80 and CB-3 acknowledge a command with a plain `OK` (instruments.md §1, §2).
pub(crate) fn is_ok(answer: &str) -> bool {
    answer.trim() == "OK"
}

/// One connection: the open port and the sample path its items take.
pub(crate) struct SerialSession<'p, C: FrameConverter, P> {
    link: SerialLink<C::Decoder, P>,
    pub(crate) path: &'p mut SamplePath<C>,
    answers: VecDeque<String>,
}

impl<C: FrameConverter, P: Port> SerialSession<'_, C, P> {
    /// Read once, send every item down the sample path, keep the answers. Returns the byte
    /// count. Cancel-safe: the only await is the read itself.
    pub(crate) async fn read_once(&mut self) -> Result<usize, DriverError> {
        let SerialSession {
            link,
            path,
            answers,
        } = self;
        link.read(|item, host_ns| {
            if let Some(a) = path.take(item, host_ns) {
                answers.push_back(a);
            }
        })
        .await
    }

    /// Write a command line (with its terminator) that has no answer.
    pub(crate) async fn send(&mut self, line: &str) -> Result<(), DriverError> {
        self.link.write_line(line).await
    }

    /// Send a command and wait for its answer line, data lines being handled meanwhile.
    pub(crate) async fn command(&mut self, line: &str) -> Result<String, DriverError> {
        self.answers.clear();
        self.send(line).await?;
        // The answer comes after whatever the device sent before it. A streaming reader that
        // has fallen behind (a loaded host: seconds of samples queued in the port) still has
        // them to take, so while samples are accepted the wait restarts as data flows, up to
        // ANSWER_TIMEOUT_BUSY; a silent device, or one that sends noise during setup, times out
        // after ANSWER_TIMEOUT. (Issue 15: `STREAM OFF` at the end of a run timed out behind
        // 2 s of backlog and the backlog's samples were lost.)
        let now = tokio::time::Instant::now();
        let hard = now + ANSWER_TIMEOUT_BUSY;
        let mut deadline = now + ANSWER_TIMEOUT;
        loop {
            if let Some(a) = self.answers.pop_front() {
                return Ok(a);
            }
            match tokio::time::timeout_at(deadline, self.read_once()).await {
                Ok(r) => {
                    if r? > 0 && self.path.reporter.accepting {
                        deadline = hard.min(tokio::time::Instant::now() + ANSWER_TIMEOUT);
                    }
                }
                Err(_) => {
                    return Err(DriverError::NoAnswer {
                        port: self.link.path.clone(),
                        command: line.trim().to_string(),
                        timeout: ANSWER_TIMEOUT,
                    });
                }
            }
        }
    }

    /// Send a command whose answer must satisfy `ok`; otherwise a clear device error.
    pub(crate) async fn expect(
        &mut self,
        line: &str,
        ok: impl Fn(&str) -> bool,
    ) -> Result<String, DriverError> {
        let a = self.command(line).await?;
        if ok(&a) {
            Ok(a)
        } else {
            Err(DriverError::UnexpectedAnswer {
                port: self.link.path.clone(),
                command: line.trim().to_string(),
                answer: a,
            })
        }
    }

    /// Keep reading until `done` holds for the converter (e.g. an `$ENV` line came), or time
    /// out with an error saying that `awaited` did not come.
    pub(crate) async fn wait_for(
        &mut self,
        awaited: &'static str,
        done: impl Fn(&C) -> bool,
    ) -> Result<(), DriverError> {
        let deadline = tokio::time::Instant::now() + ANSWER_TIMEOUT;
        while !done(&self.path.converter) {
            match tokio::time::timeout_at(deadline, self.read_once()).await {
                Ok(r) => {
                    r?;
                }
                Err(_) => {
                    return Err(DriverError::NothingWithin {
                        port: self.link.path.clone(),
                        awaited,
                        timeout: ANSWER_TIMEOUT,
                    });
                }
            }
        }
        Ok(())
    }

    /// Forget partial input (after stopping a stream that was running when we opened).
    pub(crate) fn reset_decoder(&mut self) {
        self.link.reset_decoder();
        self.answers.clear();
    }

    /// From now on data frames are samples (see `EventReporter::accepting`).
    pub(crate) fn start_accepting(&mut self) {
        self.path.reporter.accepting = true;
    }

    /// The port's path.
    pub(crate) fn port(&self) -> &str {
        &self.link.path
    }
}

/// How to talk to one serial instrument: its port settings and its command sequences.
pub(crate) trait SerialDriver: Send + Sync {
    type Converter: FrameConverter;
    fn baud(&self) -> u32;
    /// Longest silence while streaming before the port is taken for lost.
    fn idle_timeout(&self) -> Duration;
    /// The read coalescing period while streaming (see [`READ_COALESCE_DEFAULT`]); zero for a
    /// sparse stream whose every arrival time counts (the triggers).
    fn coalesce(&self) -> Duration {
        read_coalesce()
    }
    /// Stop streaming and wait for the device's answer, handling every data line before it,
    /// so a run that ends on purpose loses nothing the device sent.
    fn stop<P: Port>(
        &self,
        s: &mut SerialSession<'_, Self::Converter, P>,
    ) -> impl Future<Output = Result<(), DriverError>> + Send;
    /// Stop, identify, configure and start streaming; returns the identity string.
    fn setup<P: Port>(
        &self,
        s: &mut SerialSession<'_, Self::Converter, P>,
    ) -> impl Future<Output = Result<String, DriverError>> + Send;
    /// Called after every read while streaming: commands from the daemon (the LI-80's
    /// re-reference). Nothing by default.
    fn serve<P: Port>(
        &self,
        _s: &mut SerialSession<'_, Self::Converter, P>,
    ) -> impl Future<Output = Result<(), DriverError>> + Send {
        async { Ok(()) }
    }
}

/// Silence that means the device is gone: 2 s plus five sample periods.
pub(crate) fn idle_timeout(rate_hz: u32) -> Duration {
    Duration::from_secs(2) + Duration::from_secs_f64(5.0 / rate_hz.max(1) as f64)
}

/// Streams until the port fails or falls silent for the driver's idle time, coalescing reads
/// on the driver's tick; after each read it serves the driver's commands (the LI-80's
/// re-reference `DATUM`).
async fn stream<D: SerialDriver, P: Port>(
    driver: &D,
    s: &mut SerialSession<'_, D::Converter, P>,
) -> Result<(), DriverError> {
    let idle = driver.idle_timeout();
    let coalesce = driver.coalesce();
    let probe = probe_every(coalesce);
    let mut cycle = 0u32;
    // The tick this read belongs to: the one slept until (a full read's next read too); none
    // for a probe, which reads when bytes come.
    let mut tick: Option<tokio::time::Instant> = None;
    loop {
        match tokio::time::timeout(idle, s.read_once()).await {
            Ok(Ok(n)) => {
                driver.serve(s).await?;
                s.path.tick(false);
                cycle = cycle.wrapping_add(1);
                tell_if_late(&mut tick, n, late_reads());
                if !coalesce.is_zero() && n < FULL_READ && !cycle.is_multiple_of(probe) {
                    s.link.detach();
                    let t = next_tick(coalesce);
                    tokio::time::sleep_until(t).await;
                    tick = Some(t);
                }
            }
            Ok(Err(e)) => return Err(e),
            Err(_) => return Err(DriverError::Silent { idle }),
        }
    }
}

/// After a read of `n` bytes: when it ends the reads of `tick` (it is not full) later than
/// [`TAKE_AFTER_TICK`] after it, tells `late`. A full read is read again at once, for the same
/// tick.
fn tell_if_late(tick: &mut Option<tokio::time::Instant>, n: usize, late: &tokio::sync::Notify) {
    if n < FULL_READ
        && let Some(t) = tick.take()
        && t.elapsed() > TAKE_AFTER_TICK
    {
        late.notify_one();
    }
}

/// How a session ended.
enum Ended {
    Cancelled,
    Failed(DriverError),
}

/// Start `driver` as a task on its serial port (the reporter's port path, opened at the
/// driver's baud rate, 8N1). It runs until `cancel` fires, reconnecting with backoff.
pub(crate) fn spawn<D>(
    driver: D,
    path: SamplePath<D::Converter>,
    cancel: CancellationToken,
) -> tokio::task::JoinHandle<()>
where
    D: SerialDriver + 'static,
    D::Converter: 'static,
{
    let (port, baud) = (path.reporter.port.clone(), driver.baud());
    tokio::spawn(run(driver, path, move || open_port(&port, baud), cancel))
}

/// The driver task: connect, configure, stream; on loss report, back off and start again.
/// `open` opens the port (again after every loss); an error is retried with backoff.
pub(crate) async fn run<D: SerialDriver, P: Port>(
    driver: D,
    mut path: SamplePath<D::Converter>,
    mut open: impl FnMut() -> std::io::Result<P> + Send,
    cancel: CancellationToken,
) {
    let mut backoff = BACKOFF_MIN;
    let mut open_failures = 0u32;
    let port_path = path.reporter.port.clone();
    loop {
        if cancel.is_cancelled() {
            break;
        }
        let port = match open() {
            Ok(p) => p,
            Err(e) => {
                if open_failures == 0 {
                    tracing::warn!(port = %port_path, "cannot open the port ({e}); retrying with backoff");
                }
                open_failures += 1;
                tokio::select! {
                    _ = cancel.cancelled() => break,
                    _ = tokio::time::sleep(backoff) => {}
                }
                backoff = (backoff * 2).min(BACKOFF_MAX);
                continue;
            }
        };
        open_failures = 0;
        let link = SerialLink::new(
            port,
            path.converter.new_decoder(),
            path.reporter.clock,
            &port_path,
        );
        // A new connection: the device may have restarted its sequence and clock.
        path.stamper.reset();
        path.reporter.accepting = false;
        let mut session = SerialSession {
            link,
            path: &mut path,
            answers: VecDeque::new(),
        };
        let result = tokio::select! {
            _ = cancel.cancelled() => Err(Ended::Cancelled),
            r = async {
                let identity = driver.setup(&mut session).await?;
                let p = &mut session.path;
                p.reporter.connected(identity, &p.stamper);
                stream(&driver, &mut session).await
            } => r.map_err(Ended::Failed),
        };
        match result {
            Ok(()) | Err(Ended::Cancelled) => {
                if let Err(e) = driver.stop(&mut session).await {
                    tracing::warn!(port = %port_path, "stopping the stream: {e}");
                }
                break;
            }
            Err(Ended::Failed(e)) if e.is_port_lost() => {
                let p = &mut session.path;
                let was_streaming = p.reporter.accepting;
                p.reporter.disconnected(e, &p.stamper);
                if was_streaming {
                    backoff = BACKOFF_MIN;
                }
            }
            Err(Ended::Failed(e)) => session.path.reporter.error(e),
        }
        drop(session);
        tokio::select! {
            _ = cancel.cancelled() => break,
            _ = tokio::time::sleep(backoff) => {}
        }
        backoff = (backoff * 2).min(BACKOFF_MAX);
    }
    path.tick(true);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn probes_come_ten_times_a_second_whatever_the_period() {
        assert_eq!(probe_every(Duration::from_millis(10)), 10);
        assert_eq!(probe_every(Duration::from_millis(20)), 5);
        assert_eq!(probe_every(Duration::from_millis(150)), 1);
        assert_eq!(probe_every(Duration::from_micros(50)), 1000);
    }

    /// Whether `late` holds a notice (taking it).
    async fn noticed(late: &tokio::sync::Notify) -> bool {
        tokio::time::timeout(Duration::ZERO, late.notified())
            .await
            .is_ok()
    }

    #[tokio::test(start_paused = true)]
    async fn a_tick_read_that_ends_after_the_take_says_so_once() {
        let late = tokio::sync::Notify::new();
        let t0 = tokio::time::Instant::now();
        // On time: the tick's one read ends within TAKE_AFTER_TICK.
        let mut tick = Some(t0);
        tell_if_late(&mut tick, 100, &late);
        assert!(!noticed(&late).await, "a read on time");
        assert_eq!(tick, None, "the tick's reads are done");
        // A burst of full reads that ends 2 ms after its tick: one notice, at its last read.
        let mut tick = Some(tokio::time::Instant::now());
        tokio::time::advance(Duration::from_millis(2)).await;
        tell_if_late(&mut tick, FULL_READ, &late);
        assert!(
            !noticed(&late).await,
            "a full read is read again for the same tick"
        );
        tell_if_late(&mut tick, 10, &late);
        assert!(
            noticed(&late).await,
            "the burst's last read ended after the take"
        );
        tell_if_late(&mut tick, 10, &late);
        assert!(
            !noticed(&late).await,
            "a probe read (no tick) is not a tick's read"
        );
    }
}
