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

/// LI-80 lines to readings: `$POS` compensated with the last good `$ENV`.
struct Li80Frames {
    port: String,
    alpha_um_per_m_k: f64,
    comp: Option<Li80Compensation>,
    env_seq: Unwrap,
    /// An `$ENV` line came since the last `setup`.
    env_seen: bool,
    /// The datum was taken on this driver's first connection and the device has been
    /// connected ever since; `false` after a reconnect (a power-cycled LI-80 counts from
    /// wherever it stood), so its readings are flagged [`types::DATUM_NOT_RUNS`] and invalid.
    datum_is_runs: bool,
    /// `DATUM` was sent once (on the first connection of the run).
    datum_taken: bool,
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
                let (position_um, comp_ok) = match self.comp {
                    Some(c) => (c.length_at_20c_nm(p.raw_nm) * 1e-3, true),
                    None => (f64::NAN, false),
                };
                out(Reading::Data {
                    raw_seq: p.seq as u64,
                    raw_t_us: p.t_us,
                    valid: p.valid() && comp_ok && self.datum_is_runs,
                    values: SampleValues::Position {
                        raw_nm: p.raw_nm,
                        position_um,
                        sig: p.sig,
                        flags: p.flags.0
                            | if self.datum_is_runs {
                                0
                            } else {
                                types::DATUM_NOT_RUNS
                            },
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
}

/// `DATUM` on the run's first connection only: a later one would silently move the zero of
/// every later length (a reconnect re-zeroed the interferometer wherever the axis stood). After
/// a reconnect the readings are flagged instead, and the operator told.
async fn take_datum_once<P: Port>(
    s: &mut SerialSession<'_, Li80Frames, P>,
) -> Result<(), DriverError> {
    if s.path.converter.datum_taken {
        if s.path.converter.datum_is_runs {
            tracing::error!(
                port = %s.path.converter.port,
                "interferometer reconnected: its zero is no longer the run's datum; every later \
                 length is marked datum_lost (re-reference and start a new run)"
            );
        }
        s.path.converter.datum_is_runs = false;
        return Ok(());
    }
    s.expect("DATUM\n", is_ok).await?;
    s.path.converter.datum_taken = true;
    s.path.converter.datum_is_runs = true;
    Ok(())
}

/// Start the LI-80 driver task. It runs until `cancel` fires, reconnecting with backoff.
pub fn spawn_li80(
    cfg: Li80Config,
    clock: crate::HostClock,
    tx: crate::EventSender,
    cancel: tokio_util::sync::CancellationToken,
) -> tokio::task::JoinHandle<()> {
    let (driver, path) = li80(&cfg, clock, tx);
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
        datum_is_runs: false,
        datum_taken: false,
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
