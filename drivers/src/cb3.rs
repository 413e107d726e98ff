//! CB-3 CapBall ADC driver.
//!
//! Session: `STOP`, `ID?`, `RATE <hz>`, `START`; every command is answered by a text frame.
//! Sample frames become [`SampleValues::Capball`]: volts, the per-channel polynomial distance
//! change, and the machine-frame error through the cube-calibration transform. A sample with
//! an over-range flag is invalid. `seq` (u16) and `t_us` (u32) wrap; both are unwrapped, the
//! sequence with the device clock as a hint so a gap longer than 32768 samples is still
//! counted right.

use std::time::Duration;

use protocol::Decoded;
use protocol::cb3::{Decoder, Frame};

use crate::link::{Acq, Device, Handler, Link, SessionError};
use crate::{Instrument, Sample, SampleValues};

#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
pub struct Config {
    pub port: String,
    pub rate_hz: u32,
    /// Per channel `[c1, c2, c3]`: `d = c1·V + c2·V² + c3·V³`, µm.
    pub poly: [[f64; 3]; 3],
    /// Sensor-to-machine homogeneous transform, row-major (identity when not calibrated).
    pub transform: [[f64; 4]; 4],
}

impl Config {
    /// Distance changes (µm) from volts, per channel polynomial (instruments.md §2 step 1).
    pub fn distances_um(&self, volts: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|i| {
            let [c1, c2, c3] = self.poly[i];
            let v = volts[i];
            v * (c1 + v * (c2 + v * c3))
        })
    }

    /// Machine-frame error (µm): `v = T · [d; 1]` (instruments.md §2 step 2).
    pub fn machine_um(&self, d: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|r| {
            let t = self.transform[r];
            t[0] * d[0] + t[1] * d[1] + t[2] * d[2] + t[3]
        })
    }
}

struct Cb3 {
    cfg: Config,
    acq: Acq,
}

impl Handler for Cb3 {
    type Dec = Decoder;

    fn on_item(&mut self, item: Decoded<Frame>, host_ns: u64) -> Option<String> {
        match item {
            Decoded::Reject(r) => self.acq.reject(r.kind, r.bytes),
            Decoded::Frame(Frame::Text(t)) => {
                self.acq.counters.answers += 1;
                return Some(t);
            }
            Decoded::Frame(Frame::Sample(f)) => {
                if !self.acq.accepting {
                    return None;
                }
                let (seq, device_t_us, fitted_ns) =
                    self.acq.stamp(f.seq as u64, f.t_us as u64, host_ns);
                let volts = f.volts();
                let d_um = self.cfg.distances_um(volts);
                let e_um = self.cfg.machine_um(d_um);
                self.acq.emit_sample(Sample {
                    instrument: Instrument::Capball,
                    seq,
                    device_t_us,
                    host_ns,
                    fitted_ns,
                    valid: f.flags & 0b111 == 0,
                    values: SampleValues::Capball {
                        volts,
                        d_um,
                        e_um,
                        flags: f.flags,
                    },
                });
            }
        }
        None
    }
}

fn is_ok(a: &str) -> bool {
    a.trim() == "OK"
}

impl Device for Cb3 {
    fn acq(&mut self) -> &mut Acq {
        &mut self.acq
    }
    fn baud(&self) -> u32 {
        115_200
    }
    fn new_decoder(&self) -> Decoder {
        Decoder::new()
    }
    fn idle_timeout(&self) -> Duration {
        crate::li80::idle_timeout(self.cfg.rate_hz)
    }
    fn stop_line(&self) -> &'static str {
        "STOP\n"
    }

    async fn setup(&mut self, link: &mut Link<Decoder>) -> Result<String, SessionError> {
        self.acq.set_rate(self.cfg.rate_hz);
        link.expect(self, "STOP\n", is_ok).await?;
        link.reset_decoder();
        let id = link
            .expect(self, "ID?\n", |a| a.starts_with("CB-3,"))
            .await?;
        link.expect(self, &format!("RATE {}\n", self.cfg.rate_hz), is_ok)
            .await?;
        self.acq.accepting = true;
        link.expect(self, "START\n", is_ok).await?;
        Ok(id.trim().to_string())
    }
}

pub fn spawn(
    cfg: Config,
    clock: crate::HostClock,
    tx: crate::EventSender,
    cancel: tokio_util::sync::CancellationToken,
) -> tokio::task::JoinHandle<()> {
    let acq = Acq::new(Instrument::Capball, &cfg.port, 16, 32, clock, tx);
    tokio::spawn(crate::link::run(Cb3 { cfg, acq }, cancel))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn polynomial_and_transform_by_hand() {
        let cfg = Config {
            port: String::new(),
            rate_hz: 1000,
            poly: [[10.0, 0.0, 0.0], [10.0, 1.0, 0.0], [10.0, 0.0, 0.5]],
            // Swap x and y, offset z by 2 µm.
            transform: [
                [0.0, 1.0, 0.0, 0.0],
                [1.0, 0.0, 0.0, 0.0],
                [0.0, 0.0, 1.0, 2.0],
                [0.0, 0.0, 0.0, 1.0],
            ],
        };
        // ch0: 10·1.5 = 15; ch1: 10·2 + 4 = 24; ch2: 10·(−1) + 0.5·(−1) = −10.5.
        let d = cfg.distances_um([1.5, 2.0, -1.0]);
        assert_eq!(d, [15.0, 24.0, -10.5]);
        assert_eq!(cfg.machine_um(d), [24.0, 15.0, -8.5]);
    }
}
