//! LI-80 laser interferometer driver.
//!
//! Session: `STREAM OFF` (the device may be streaming from an earlier run), `*IDN?`,
//! `RATE <hz>`, `DATUM`, `ENV?` (so the very first reading is air-compensated), `STREAM ON`.
//! `$POS` lines become [`SampleValues::Position`] with the compensated length at 20 °C,
//! `$ENV` lines become [`SampleValues::Environment`] and update the compensation, `$ERR`
//! lines are counted as device errors and reported.

use std::time::Duration;

use protocol::convert::Li80Compensation;
use protocol::li80::{Decoder, Line};

use crate::sample_path::{FrameConverter, Reading, SamplePath};
use crate::serial_driver::{SerialDriver, SerialSession, idle_timeout, is_ok};
use crate::serial_link::Port;
use crate::stamper::SampleStamper;
use crate::{DriverError, Instrument, Sample, SampleValues};
use detect::Unwrap;

/// What the daemon configures for the LI-80.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
pub struct Li80Config {
    /// Serial port path, e.g. `/dev/metrolog-li80`.
    pub port: String,
    pub rate_hz: u32,
    /// Expansion coefficient of the measured axis, µm/(m·K), for the 20 °C compensation
    /// (default: `protocol::convert::ALPHA_STEEL_UM_PER_M_K`).
    pub alpha_um_per_m_k: f64,
}

/// The device's own bits of the `$POS` flags (instruments.md §1 uses bits 0–2); the host's
/// bits above them hold the datum epoch ([`types::DATUM_EPOCH_MASK`], [`types::DATUM_NOT_RUNS`]).
const DEVICE_FLAGS: u32 = 0xFFFF;

/// What the daemon asks of the LI-80 driver while it streams (docs/design.md, "Datum epochs").
#[derive(Debug, Clone, PartialEq)]
pub enum Li80Command {
    /// The exact stop of the run's reference pose, whose target is the datum position: when
    /// the epoch is not against the run's zero, send `DATUM` once the axis has stood `settle`.
    Reference { pose: u32, settle: Duration },
    /// The axis moves again (a motion start): a `DATUM` still waiting is not sent.
    Moving,
    /// The zero the device counts from is not the run's (the service started mid-program):
    /// a new epoch begins.
    LoseDatum { reason: String },
}

/// How the daemon steers the LI-80's datum: its commands (None: no reference pose, nothing
/// is ever re-referenced).
#[derive(Debug, Default)]
pub struct Li80Control {
    pub commands: Option<tokio::sync::mpsc::UnboundedReceiver<Li80Command>>,
}

/// LI-80 lines to readings: `$POS` compensated with the last good `$ENV`.
struct Li80Frames {
    port: String,
    alpha_um_per_m_k: f64,
    comp: Option<Li80Compensation>,
    env_seq: Unwrap,
    /// An `$ENV` line came since the last `setup`.
    env_seen: bool,
    /// `DATUM` was sent once (on the first connection of the run).
    datum_taken: bool,
    /// The datum epoch of the readings: 0 from the `DATUM` of the first connection; each
    /// reconnect (a power-cycled LI-80 counts from wherever it stood), beam loss (the
    /// device's "datum lost" flag) or [`Li80Command::LoseDatum`] begins the next.
    epoch: u32,
    /// The readings are against the run's zero: epoch 0, or an epoch re-referenced by
    /// `DATUM` at the reference pose. Otherwise they are flagged [`types::DATUM_NOT_RUNS`]
    /// and invalid.
    clean: bool,
    /// A re-reference waiting for the axis to settle: the pose and when to send `DATUM`.
    reference: Option<(u32, tokio::time::Instant)>,
    commands: Option<tokio::sync::mpsc::UnboundedReceiver<Li80Command>>,
}

impl Li80Frames {
    /// A new epoch begins: its readings are not against the run's zero.
    fn new_epoch(&mut self, why: &str) -> crate::DatumChange {
        self.epoch += 1;
        self.clean = false;
        self.reference = None;
        crate::DatumChange {
            epoch: self.epoch,
            referenced: false,
            pose: None,
            text: format!(
                "{why}: the interferometer's datum is lost; datum epoch {} begins and its \
                 lengths are datum_lost until re-referenced (DATUM at the run's reference pose)",
                self.epoch
            ),
        }
    }

    fn next_command(&mut self) -> Option<Li80Command> {
        self.commands.as_mut().and_then(|r| r.try_recv().ok())
    }

    /// Takes one command; returns the datum change it makes.
    fn obey(&mut self, cmd: Li80Command) -> Option<crate::DatumChange> {
        match cmd {
            Li80Command::Reference { pose, settle } => {
                if !self.clean && self.datum_taken {
                    tracing::info!(
                        port = %self.port,
                        "pose {pose}: reference pose reached with datum epoch {} not the run's; \
                         DATUM in {settle:?} if the axis stands until then",
                        self.epoch
                    );
                    self.reference = Some((pose, tokio::time::Instant::now() + settle));
                }
                None
            }
            Li80Command::Moving => {
                if let Some((pose, _)) = self.reference.take() {
                    tracing::warn!(
                        port = %self.port,
                        "pose {pose}: the axis moved before DATUM could be sent (dwell shorter \
                         than the reference settle time): not re-referenced"
                    );
                }
                None
            }
            Li80Command::LoseDatum { reason } => self.clean.then(|| self.new_epoch(&reason)),
        }
    }

    /// The host's flag bits for the readings now.
    fn host_flags(&self) -> u32 {
        types::datum_epoch_bits(self.epoch) | if self.clean { 0 } else { types::DATUM_NOT_RUNS }
    }
}

impl FrameConverter for Li80Frames {
    type Decoder = Decoder;

    fn new_decoder(&self) -> Decoder {
        Decoder::new()
    }

    fn convert(&mut self, line: Line, host_ns: u64, out: &mut impl FnMut(Reading)) {
        match line {
            Line::Answer(a) => out(Reading::Answer(a)),
            Line::Pos(p) => {
                if p.flags.datum_lost() && self.clean && self.datum_taken {
                    out(Reading::Datum(self.new_epoch("interferometer beam lost")));
                }
                let (position_um, comp_ok) = match self.comp {
                    Some(c) => (c.length_at_20c_nm(p.raw_nm) * 1e-3, true),
                    None => (f64::NAN, false),
                };
                out(Reading::Data {
                    raw_seq: p.seq as u64,
                    raw_t_us: p.t_us,
                    valid: p.valid() && comp_ok && self.clean,
                    values: SampleValues::Position {
                        raw_nm: p.raw_nm,
                        position_um,
                        sig: p.sig,
                        flags: (p.flags.0 & DEVICE_FLAGS) | self.host_flags(),
                    },
                });
            }
            Line::Env(e) => {
                self.env_seen = true;
                let comp = match Li80Compensation::from_env(&e, self.alpha_um_per_m_k) {
                    Ok(c) => {
                        self.comp = Some(c);
                        Some(c)
                    }
                    Err(cause) => {
                        // Keep compensating with the last good record; the operator must know.
                        out(Reading::Problem(DriverError::UnusableEnvironment {
                            port: self.port.clone(),
                            cause,
                        }));
                        None
                    }
                };
                let seq = self
                    .env_seq
                    .push(e.seq as u64)
                    .unwrap_or_else(|| self.env_seq.rebase(e.seq as u64));
                let n_air = comp.map_or(f64::NAN, |c| c.n_air);
                out(Reading::Timed(Sample {
                    instrument: Instrument::Interferometer,
                    seq,
                    device_t_us: e.t_us,
                    host_ns,
                    fitted_ns: host_ns,
                    valid: comp.is_some(),
                    values: SampleValues::Environment {
                        air_c: e.air_c,
                        air_pa: e.air_pa,
                        rh_pct: e.rh_pct,
                        material_c: e.material_c,
                        n_air,
                    },
                }));
            }
            Line::Err(e) => out(Reading::DeviceError(DriverError::DeviceReported {
                port: self.port.clone(),
                code: e.code,
                text: e.text,
            })),
        }
    }
}

/// The LI-80's session: commands and their expected answers.
struct Li80Driver {
    rate_hz: u32,
}

impl SerialDriver for Li80Driver {
    type Converter = Li80Frames;

    fn baud(&self) -> u32 {
        // USB virtual serial port: the setting is ignored by the device.
        115_200
    }
    fn idle_timeout(&self) -> Duration {
        idle_timeout(self.rate_hz)
    }
    async fn stop<P: Port>(
        &self,
        s: &mut SerialSession<'_, Li80Frames, P>,
    ) -> Result<(), DriverError> {
        s.expect("STREAM OFF\n", is_ok).await.map(drop)
    }

    async fn setup<P: Port>(
        &self,
        s: &mut SerialSession<'_, Li80Frames, P>,
    ) -> Result<String, DriverError> {
        s.path.stamper.set_rate(self.rate_hz);
        s.expect("STREAM OFF\n", is_ok).await?;
        s.reset_decoder();
        let idn = s.expect("*IDN?\n", |a| a.starts_with("LI-80,")).await?;
        s.expect(&format!("RATE {}\n", self.rate_hz), is_ok).await?;
        take_datum_once(s).await?;
        s.path.converter.env_seen = false;
        s.path.converter.env_seq.reset();
        s.send("ENV?\n").await?;
        s.wait_for("`$ENV` line in answer to `ENV?`", |c| c.env_seen)
            .await?;
        s.start_accepting();
        s.expect("STREAM ON\n", is_ok).await?;
        Ok(idn.trim().to_string())
    }

    async fn serve<P: Port>(
        &self,
        s: &mut SerialSession<'_, Li80Frames, P>,
    ) -> Result<(), DriverError> {
        while let Some(cmd) = s.path.converter.next_command() {
            if let Some(change) = s.path.converter.obey(cmd) {
                s.path.reporter.datum(change);
            }
        }
        match s.path.converter.reference {
            Some((pose, due)) if tokio::time::Instant::now() >= due => re_reference(s, pose).await,
            _ => Ok(()),
        }
    }
}

/// `DATUM` while the axis stands at the reference pose: from its answer on, the epoch is
/// against the run's zero again. A refused `DATUM` is reported and the epoch stays lost.
async fn re_reference<P: Port>(
    s: &mut SerialSession<'_, Li80Frames, P>,
    pose: u32,
) -> Result<(), DriverError> {
    s.path.converter.reference = None;
    match s.expect("DATUM\n", is_ok).await {
        Ok(_) => {}
        Err(e) if e.is_port_lost() => return Err(e),
        Err(e) => {
            s.path.reporter.error(e);
            return Ok(());
        }
    }
    let c = &mut s.path.converter;
    c.clean = true;
    let change = crate::DatumChange {
        epoch: c.epoch,
        referenced: true,
        pose: Some(pose),
        text: format!(
            "interferometer re-referenced at pose {pose}: DATUM taken while the axis stood at \
             the reference pose; datum epoch {} is against the run's zero again (pose {pose}'s \
             own value is the reference visit, not a measurement)",
            c.epoch
        ),
    };
    s.path.reporter.datum(change);
    Ok(())
}

/// `DATUM` on the run's first connection only: a later one would silently move the zero of
/// every later length (a reconnect re-zeroed the interferometer wherever the axis stood). A
/// reconnect begins a new datum epoch instead, its readings flagged, and the operator told.
async fn take_datum_once<P: Port>(
    s: &mut SerialSession<'_, Li80Frames, P>,
) -> Result<(), DriverError> {
    if s.path.converter.datum_taken {
        let change = s.path.converter.new_epoch("interferometer reconnected");
        s.path.reporter.datum(change);
        return Ok(());
    }
    s.expect("DATUM\n", is_ok).await?;
    s.path.converter.datum_taken = true;
    s.path.converter.clean = true;
    Ok(())
}

/// Start the LI-80 driver task. It runs until `cancel` fires, reconnecting with backoff.
pub fn spawn_li80(
    cfg: Li80Config,
    clock: crate::HostClock,
    tx: crate::EventSender,
    cancel: tokio_util::sync::CancellationToken,
) -> tokio::task::JoinHandle<()> {
    spawn_li80_with(cfg, clock, tx, cancel, Li80Control::default())
}

/// [`spawn_li80`] steered by the daemon through `control` (the re-reference).
pub fn spawn_li80_with(
    cfg: Li80Config,
    clock: crate::HostClock,
    tx: crate::EventSender,
    cancel: tokio_util::sync::CancellationToken,
    control: Li80Control,
) -> tokio::task::JoinHandle<()> {
    let (driver, mut path) = li80(&cfg, clock, tx);
    path.converter.commands = control.commands;
    crate::serial_driver::spawn(driver, path, cancel)
}

/// The LI-80's session and sample path for `cfg`.
fn li80(
    cfg: &Li80Config,
    clock: crate::HostClock,
    tx: crate::EventSender,
) -> (Li80Driver, SamplePath<Li80Frames>) {
    let frames = Li80Frames {
        port: cfg.port.clone(),
        alpha_um_per_m_k: cfg.alpha_um_per_m_k,
        comp: None,
        env_seq: Unwrap::new(32),
        env_seen: false,
        datum_taken: false,
        epoch: 0,
        clean: false,
        reference: None,
        commands: None,
    };
    let path = SamplePath::new(
        frames,
        SampleStamper::new(32, 64),
        Instrument::Interferometer,
        &cfg.port,
        clock,
        tx,
    );
    let driver = Li80Driver {
        rate_hz: cfg.rate_hz,
    };
    (driver, path)
}

#[cfg(test)]
mod tests;
