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
use protocol::convert::{CapBallPoly, CapBallTransform};

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

struct Cb3 {
    cfg: Config,
    acq: Acq,
    poly: [CapBallPoly; 3],
    transform: CapBallTransform,
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
                let d_um: [f64; 3] = std::array::from_fn(|i| self.poly[i].distance_um(volts[i]));
                let e_um = self.transform.apply(d_um);
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
    async fn stop(&mut self, link: &mut Link<Decoder>) -> Result<(), SessionError> {
        link.expect(self, "STOP\n", crate::link::is_ok)
            .await
            .map(drop)
    }

    async fn setup(&mut self, link: &mut Link<Decoder>) -> Result<String, SessionError> {
        self.acq.set_rate(self.cfg.rate_hz);
        link.expect(self, "STOP\n", crate::link::is_ok).await?;
        link.reset_decoder();
        let id = link
            .expect(self, "ID?\n", |a| a.starts_with("CB-3,"))
            .await?;
        link.expect(
            self,
            &format!("RATE {}\n", self.cfg.rate_hz),
            crate::link::is_ok,
        )
        .await?;
        self.acq.accepting = true;
        link.expect(self, "START\n", crate::link::is_ok).await?;
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
    let poly = cfg.poly.map(|c| CapBallPoly { c });
    let transform = CapBallTransform { t: cfg.transform };
    tokio::spawn(crate::link::run(
        Cb3 {
            cfg,
            acq,
            poly,
            transform,
        },
        cancel,
    ))
}
