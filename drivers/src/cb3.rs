//! CB-3 CapBall ADC driver.
//!
//! Session: `STOP`, `ID?`, `RATE <hz>`, `START`; every command is answered by a text frame.
//! Sample frames become [`SampleValues::Capball`]: volts, the per-channel polynomial distance
//! change, and the machine-frame error through the cube-calibration transform. A sample with
//! an over-range flag is invalid. `seq` (u16) and `t_us` (u32) wrap; both are unwrapped, the
//! sequence with the device clock as a hint so a gap longer than 32768 samples is still
//! counted right.

use std::time::Duration;

use protocol::cb3::{Decoder, Frame};
use protocol::convert::{CapBallCalibration, CapBallPoly, CapBallTransform};

use crate::sample_path::{FrameConverter, Reading, SamplePath};
use crate::serial_driver::{SerialDriver, SerialSession, idle_timeout, is_ok};
use crate::serial_link::Port;
use crate::stamper::SampleStamper;
use crate::{DriverError, Instrument, SampleValues};

/// What the daemon configures for the CB-3.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
pub struct Cb3Config {
    pub port: String,
    pub rate_hz: u32,
    /// Per channel `[c1, c2, c3]`: `d = c1·V + c2·V² + c3·V³`, µm.
    pub poly: [[f64; 3]; 3],
    /// Sensor-to-machine homogeneous transform, row-major (identity when not calibrated).
    pub transform: [[f64; 4]; 4],
}

impl Cb3Config {
    /// The conversion of every sample (the log stores it with the codes).
    pub fn calibration(&self) -> CapBallCalibration {
        CapBallCalibration {
            poly: self.poly.map(|c| CapBallPoly { c }),
            transform: CapBallTransform { t: self.transform },
        }
    }
}

/// CB-3 frames to readings: volts → distance changes → machine-frame error.
struct Cb3Frames {
    cal: CapBallCalibration,
}

impl FrameConverter for Cb3Frames {
    type Decoder = Decoder;

    fn new_decoder(&self) -> Decoder {
        Decoder::new()
    }

    fn convert(&mut self, frame: Frame, _host_ns: u64, out: &mut impl FnMut(Reading)) {
        match frame {
            Frame::Text(t) => out(Reading::Answer(t)),
            Frame::Sample(f) => {
                let v = self.cal.convert(f.ch);
                out(Reading::Data {
                    raw_seq: f.seq as u64,
                    raw_t_us: f.t_us as u64,
                    valid: f.flags & 0b111 == 0,
                    values: SampleValues::Capball {
                        volts: v.volts,
                        d_um: v.d_um,
                        e_um: v.e_um,
                        flags: f.flags,
                    },
                });
            }
        }
    }
}

/// The CB-3's session: commands and their expected answers.
struct Cb3Driver {
    rate_hz: u32,
}

impl SerialDriver for Cb3Driver {
    type Converter = Cb3Frames;

    fn baud(&self) -> u32 {
        115_200
    }
    fn idle_timeout(&self) -> Duration {
        idle_timeout(self.rate_hz)
    }
    async fn stop<P: Port>(
        &self,
        s: &mut SerialSession<'_, Cb3Frames, P>,
    ) -> Result<(), DriverError> {
        s.expect("STOP\n", is_ok).await.map(drop)
    }

    async fn setup<P: Port>(
        &self,
        s: &mut SerialSession<'_, Cb3Frames, P>,
    ) -> Result<String, DriverError> {
        s.path.stamper.set_rate(self.rate_hz);
        s.expect("STOP\n", is_ok).await?;
        s.reset_decoder();
        let id = s.expect("ID?\n", |a| a.starts_with("CB-3,")).await?;
        s.expect(&format!("RATE {}\n", self.rate_hz), is_ok).await?;
        s.start_accepting();
        s.expect("START\n", is_ok).await?;
        Ok(id.trim().to_string())
    }
}

/// Start the CB-3 driver task. It runs until `cancel` fires, reconnecting with backoff.
pub fn spawn_cb3(
    cfg: Cb3Config,
    clock: crate::HostClock,
    tx: crate::EventSender,
    cancel: tokio_util::sync::CancellationToken,
) -> tokio::task::JoinHandle<()> {
    let frames = Cb3Frames {
        cal: cfg.calibration(),
    };
    let path = SamplePath::new(
        frames,
        SampleStamper::new(16, 32),
        Instrument::Capball,
        &cfg.port,
        clock,
        tx,
    );
    let driver = Cb3Driver {
        rate_hz: cfg.rate_hz,
    };
    crate::serial_driver::spawn(driver, path, cancel)
}
