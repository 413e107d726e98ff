//! LI-80 laser interferometer driver.
//!
//! Session: `STREAM OFF` (the device may be streaming from an earlier run), `*IDN?`,
//! `RATE <hz>`, `DATUM`, `ENV?` (so the very first reading is air-compensated), `STREAM ON`.
//! `$POS` lines become [`SampleValues::Position`] with the compensated length at 20 °C,
//! `$ENV` lines become [`SampleValues::Environment`] and update the compensation, `$ERR`
//! lines are counted as device errors and reported.

use std::time::Duration;

use protocol::Decoded;
use protocol::convert::Li80Compensation;
use protocol::li80::{Decoder, Line};

use crate::link::{Acq, Device, Handler, Link, SessionError};
use crate::{Instrument, Sample, SampleValues};

/// What the daemon configures for the LI-80.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
pub struct Config {
    /// Serial port path, e.g. `/dev/metrolog-li80`.
    pub port: String,
    pub rate_hz: u32,
    /// Expansion coefficient of the measured axis, µm/(m·K), for the 20 °C compensation.
    pub alpha_um_per_m_k: f64,
}

struct Li80 {
    cfg: Config,
    acq: Acq,
    comp: Option<Li80Compensation>,
    env_seq: crate::clock::Unwrap,
    env_seen: bool,
}

impl Handler for Li80 {
    type Dec = Decoder;

    fn on_item(&mut self, item: Decoded<Line>, host_ns: u64) -> Option<String> {
        match item {
            Decoded::Reject(r) => self.acq.reject(r.kind, r.bytes),
            Decoded::Frame(Line::Answer(a)) => {
                self.acq.counters.answers += 1;
                return Some(a);
            }
            Decoded::Frame(Line::Pos(p)) => {
                if !self.acq.accepting {
                    return None;
                }
                let (seq, device_t_us, fitted_ns) = self.acq.stamp(p.seq as u64, p.t_us, host_ns);
                let (position_um, comp_ok) = match self.comp {
                    Some(c) => (c.length_at_20c_nm(p.raw_nm) * 1e-3, true),
                    None => (f64::NAN, false),
                };
                self.acq.emit_sample(Sample {
                    instrument: Instrument::Interferometer,
                    seq,
                    device_t_us,
                    host_ns,
                    fitted_ns,
                    valid: p.valid() && comp_ok,
                    values: SampleValues::Position {
                        raw_nm: p.raw_nm,
                        position_um,
                        sig: p.sig,
                        flags: p.flags.0,
                    },
                });
            }
            Decoded::Frame(Line::Env(e)) => {
                self.env_seen = true;
                let comp = match Li80Compensation::from_env(&e, self.cfg.alpha_um_per_m_k) {
                    Ok(c) => {
                        self.comp = Some(c);
                        Some(c)
                    }
                    Err(err) => {
                        // Keep compensating with the last good record; the operator must know.
                        let msg = format!("port {}: `$ENV` record unusable: {err}", self.acq.port);
                        self.acq.error(msg);
                        None
                    }
                };
                let seq = self
                    .env_seq
                    .push(e.seq as u64)
                    .unwrap_or_else(|| self.env_seq.rebase(e.seq as u64));
                let n_air = comp.map_or(f64::NAN, |c| c.n_air);
                self.acq.emit_sample(Sample {
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
                });
            }
            Decoded::Frame(Line::Err(e)) => {
                self.acq.counters.device_errors += 1;
                let msg = format!(
                    "port {}: device reports error {}: {}",
                    self.acq.port, e.code, e.text
                );
                self.acq.error(msg);
            }
        }
        None
    }
}

impl Device for Li80 {
    fn acq(&mut self) -> &mut Acq {
        &mut self.acq
    }
    fn baud(&self) -> u32 {
        // USB virtual serial port: the setting is ignored by the device.
        115_200
    }
    fn new_decoder(&self) -> Decoder {
        Decoder::new()
    }
    fn idle_timeout(&self) -> Duration {
        idle_timeout(self.cfg.rate_hz)
    }
    async fn stop(&mut self, link: &mut Link<Decoder>) -> Result<(), SessionError> {
        link.expect(self, "STREAM OFF\n", crate::link::is_ok)
            .await
            .map(drop)
    }

    async fn setup(&mut self, link: &mut Link<Decoder>) -> Result<String, SessionError> {
        self.acq.set_rate(self.cfg.rate_hz);
        link.expect(self, "STREAM OFF\n", crate::link::is_ok)
            .await?;
        link.reset_decoder();
        let idn = link
            .expect(self, "*IDN?\n", |a| a.starts_with("LI-80,"))
            .await?;
        link.expect(
            self,
            &format!("RATE {}\n", self.cfg.rate_hz),
            crate::link::is_ok,
        )
        .await?;
        link.expect(self, "DATUM\n", crate::link::is_ok).await?;
        self.env_seen = false;
        self.env_seq.reset();
        link.send("ENV?\n").await?;
        link.wait_for(self, "`$ENV` line in answer to `ENV?`", |h| h.env_seen)
            .await?;
        self.acq.accepting = true;
        link.expect(self, "STREAM ON\n", crate::link::is_ok).await?;
        Ok(idn.trim().to_string())
    }
}

/// Silence that means the device is gone: 2 s plus five sample periods.
pub(crate) fn idle_timeout(rate_hz: u32) -> Duration {
    Duration::from_secs(2) + Duration::from_secs_f64(5.0 / rate_hz.max(1) as f64)
}

/// Start the driver task. It runs until `cancel` fires, reconnecting with backoff.
pub fn spawn(
    cfg: Config,
    clock: crate::HostClock,
    tx: crate::EventSender,
    cancel: tokio_util::sync::CancellationToken,
) -> tokio::task::JoinHandle<()> {
    let acq = Acq::new(Instrument::Interferometer, &cfg.port, 32, 64, clock, tx);
    let dev = Li80 {
        cfg,
        acq,
        comp: None,
        env_seq: crate::clock::Unwrap::new(32),
        env_seen: false,
    };
    tokio::spawn(crate::link::run(dev, cancel))
}
