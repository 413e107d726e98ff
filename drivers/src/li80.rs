//! LI-80 laser interferometer driver.
//!
//! Session: `STREAM OFF` (the device may be streaming from an earlier run), `*IDN?`,
//! `RATE <hz>`, `DATUM`, `ENV?` (so the very first reading is air-compensated), `STREAM ON`.
//! `$POS` lines become [`SampleValues::Position`] with the compensated length at 20 °C,
//! `$ENV` lines become [`SampleValues::Environment`] and update the compensation, `$ERR`
//! lines are counted as device errors and reported.

use std::time::Duration;

use protocol::Decoded;
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

/// CO2 content assumed for the refractive index (instruments.md §1).
pub const CO2_PPM: f64 = 450.0;

/// The air and material state the compensation uses, from the latest `$ENV`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Compensation {
    pub n_air: f64,
    /// Mean of the material sensors, °C.
    pub material_c: f64,
}

impl Compensation {
    /// From an `$ENV` record: Edlén (Birch & Downs) index at 632.991 nm, mean material
    /// temperature. `None` when the record has no material sensor or a nonsensical index.
    pub fn from_env(air_c: f64, air_pa: f64, rh_pct: f64, material_c: &[f64]) -> Option<Self> {
        if material_c.is_empty() {
            return None;
        }
        let n_air = protocol::edlen::refractive_index(
            protocol::edlen::LI80_VACUUM_WAVELENGTH_NM,
            air_c,
            air_pa,
            rh_pct,
            CO2_PPM,
        );
        let material_c = material_c.iter().sum::<f64>() / material_c.len() as f64;
        (n_air.is_finite() && n_air > 0.9 && n_air < 1.1)
            .then_some(Compensation { n_air, material_c })
    }

    /// Length at 20 °C, µm: `L = raw / n`, `L20 = L·(1 − α·(T_mat − 20 °C))`.
    pub fn position_um(&self, raw_nm: i64, alpha_um_per_m_k: f64) -> f64 {
        let l_um = raw_nm as f64 / self.n_air * 1e-3;
        l_um * (1.0 - alpha_um_per_m_k * 1e-6 * (self.material_c - 20.0))
    }
}

struct Li80 {
    cfg: Config,
    acq: Acq,
    comp: Option<Compensation>,
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
                    Some(c) => (c.position_um(p.raw_nm, self.cfg.alpha_um_per_m_k), true),
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
                let comp = Compensation::from_env(e.air_c, e.air_pa, e.rh_pct, &e.material_c);
                if comp.is_some() {
                    self.comp = comp;
                }
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

fn is_ok(a: &str) -> bool {
    a.trim() == "OK"
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
    fn stop_line(&self) -> &'static str {
        "STREAM OFF\n"
    }

    async fn setup(&mut self, link: &mut Link<Decoder>) -> Result<String, SessionError> {
        self.acq.set_rate(self.cfg.rate_hz);
        link.expect(self, "STREAM OFF\n", is_ok).await?;
        link.reset_decoder();
        let idn = link
            .expect(self, "*IDN?\n", |a| a.starts_with("LI-80,"))
            .await?;
        link.expect(self, &format!("RATE {}\n", self.cfg.rate_hz), is_ok)
            .await?;
        link.expect(self, "DATUM\n", is_ok).await?;
        self.env_seen = false;
        self.env_seq.reset();
        link.send("ENV?\n").await?;
        link.wait_for(self, "`$ENV` line in answer to `ENV?`", |h| h.env_seen)
            .await?;
        self.acq.accepting = true;
        link.expect(self, "STREAM ON\n", is_ok).await?;
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn material_compensation_by_hand() {
        // n = 1 so only the material term acts: 100 mm of steel at 25 °C, α = 11.7 µm/(m·K),
        // reads 100 mm · (1 − 11.7e-6·5) = 99.99415 mm at 20 °C.
        let c = Compensation {
            n_air: 1.0,
            material_c: 25.0,
        };
        let l = c.position_um(100_000_000, 11.7);
        assert!((l - 99_994.15).abs() < 1e-6, "{l}");
        // Air only: n = 1.00027 shortens 1 m by 269.93 µm.
        let c = Compensation {
            n_air: 1.00027,
            material_c: 20.0,
        };
        let l = c.position_um(1_000_000_000, 11.7);
        assert!(
            (l - 1e6 / 1.00027).abs() < 1e-6 && (1e6 - l - 269.927).abs() < 1e-3,
            "{l}"
        );
    }
}
