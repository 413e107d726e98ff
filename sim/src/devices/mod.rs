//! The four simulated devices.

mod cb3;
mod li80;
mod psd;
mod slcan;

use std::path::PathBuf;
use std::sync::Arc;

use rand_chacha::ChaCha8Rng;
use tokio::sync::mpsc;

use crate::device::{Model, Runner};
use crate::error::SimError;
use crate::instrument::Device;
use crate::shared::{Control, Shared};

#[allow(clippy::too_many_arguments)] // one call site per device, all arguments distinct
fn start<M: Model>(
    model: M,
    shared: Arc<Shared>,
    link: PathBuf,
    rng: ChaCha8Rng,
    ctl: mpsc::Receiver<Control>,
    rt: &tokio::runtime::Handle,
    ppm: f64,
    start_us: u64,
) -> Result<tokio::task::JoinHandle<()>, SimError> {
    let mid_frame = match M::DEVICE {
        Device::Interferometer => {
            shared
                .world
                .scenario
                .faults
                .interferometer
                .mid_frame_on_open
        }
        Device::Capball => shared.world.scenario.faults.capball.mid_frame_on_open,
        Device::Psd => shared.world.scenario.faults.psd.mid_frame_on_open,
        Device::Trigger => false,
    };
    let mut r = Runner::new(model, shared, link, rng, ppm, start_us);
    r.set_mid_frame_on_open(mid_frame);
    r.plug()?;
    r.publish();
    Ok(rt.spawn(r.run(ctl)))
}

pub(crate) fn spawn(
    d: Device,
    shared: Arc<Shared>,
    link: PathBuf,
    rng: ChaCha8Rng,
    ctl: mpsc::Receiver<Control>,
    rt: &tokio::runtime::Handle,
) -> Result<tokio::task::JoinHandle<()>, SimError> {
    let sc = &shared.world.scenario;
    match d {
        Device::Interferometer => {
            let id = sc.interferometer.identity.clone();
            let m = li80::Li80::new(&shared);
            start(
                m,
                shared,
                link,
                rng,
                ctl,
                rt,
                id.clock_ppm,
                id.clock_start_us,
            )
        }
        Device::Capball => {
            let id = sc.capball.identity.clone();
            let m = cb3::Cb3::new(&shared);
            start(
                m,
                shared,
                link,
                rng,
                ctl,
                rt,
                id.clock_ppm,
                id.clock_start_us,
            )
        }
        Device::Psd => {
            let id = sc.psd.identity.clone();
            let m = psd::Psd2::new(&shared);
            start(
                m,
                shared,
                link,
                rng,
                ctl,
                rt,
                id.clock_ppm,
                id.clock_start_us,
            )
        }
        Device::Trigger => {
            let ppm = sc.trigger.clock_ppm;
            let m = slcan::Slcan::new(&shared);
            start(m, shared, link, rng, ctl, rt, ppm, 0)
        }
    }
}
