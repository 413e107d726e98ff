//! SLCAN (Lawicel) adapter on the CNC's CAN bus, delivering the exact-stop trigger frames
//! (instruments.md §4).

use std::sync::Arc;
use std::time::Duration;

use protocol::can::{TriggerEvent, TriggerFrame};
use protocol::slcan::{CanFrame, Command, Message};

use crate::device::{Ctx, Model};
use crate::instrument::Device;
use crate::record::{SentTrigger, TriggerFate};
use crate::scenario::{MissingTrigger, ProgramStart, TriggerAdapter};
use crate::shared::Shared;

pub(crate) struct Slcan {
    cfg: TriggerAdapter,
    start: ProgramStart,
    start_delay_s: f64,
    nc_start_ms: u32,
    missing: Vec<MissingTrigger>,
    events: Vec<(f64, TriggerEvent, u16)>,
    next_event: usize,
    open: bool,
    bitrate: Option<u8>,
    timestamps: bool,
}

impl Slcan {
    pub(crate) fn new(shared: &Arc<Shared>) -> Slcan {
        let sc = &shared.world.scenario;
        Slcan {
            cfg: sc.trigger.clone(),
            start: sc.program.start,
            start_delay_s: sc.program.start_delay_s,
            nc_start_ms: sc.program.nc_clock_start_ms,
            missing: sc.faults.missing_triggers.clone(),
            events: shared.world.trigger_events(),
            next_event: 0,
            open: false,
            bitrate: None,
            timestamps: false,
        }
    }

    /// Deliver (or not) every trigger event that is due.
    fn events(&mut self, ctx: &mut Ctx, plugged: bool) {
        let Some(sp) = ctx.program_s(ctx.now) else {
            return;
        };
        let Some(started) = ctx.shared.program.borrow().started else {
            return;
        };
        let mut sent = Vec::new();
        let mut done = false;
        while let Some(&(at_s, event, pose)) = self.events.get(self.next_event) {
            if at_s > sp {
                break;
            }
            self.next_event += 1;
            let at = started + Duration::from_secs_f64(at_s);
            let true_s = ctx.sim_s(at);
            // The NC clock runs from the simulation start, ms, wrapping.
            let nc_ms = self
                .nc_start_ms
                .wrapping_add((true_s * 1e3).round() as u64 as u32);
            let fate = if self
                .missing
                .iter()
                .any(|m| m.pose == pose && m.event == event)
            {
                TriggerFate::Missing
            } else if !plugged || !self.open || ctx.link_fate().is_some() {
                TriggerFate::ChannelClosed
            } else {
                let data = TriggerFrame { event, pose, nc_ms }.encode().to_vec();
                let timestamp_ms = self.timestamps.then(|| {
                    let ms = (ctx.clock.dev_us(at) / 1e3).floor() as u64;
                    (ms % 60_000) as u16
                });
                let f = CanFrame {
                    id: self.cfg.can_id,
                    extended: false,
                    data,
                    timestamp_ms,
                };
                protocol::slcan::encode_frame(&f, ctx.out);
                TriggerFate::Sent
            };
            sent.push(SentTrigger {
                event,
                pose,
                nc_ms,
                true_s,
                fate,
            });
            if event == TriggerEvent::ProgramEnd {
                done = true;
            }
        }
        if !sent.is_empty() {
            let mut r = ctx.shared.lock_record();
            if done {
                r.program_ended_s = sent.last().map(|s| s.true_s);
            }
            r.trigger.events.extend(sent);
        }
        if done {
            ctx.shared.program.send_modify(|p| p.done = true);
        }
    }
}

impl Model for Slcan {
    const DEVICE: Device = Device::Trigger;

    fn activity(&self) -> (bool, u32) {
        (self.open, 0)
    }

    fn power_up(&mut self, _ctx: &mut Ctx) {
        self.open = false;
        self.bitrate = None;
        self.timestamps = false;
    }

    fn command(&mut self, line: &str, ctx: &mut Ctx) {
        if line.is_empty() {
            return;
        }
        let reply = match (Command::parse(line), line) {
            (Some(Command::Close), _) => {
                self.open = false;
                Message::Ack
            }
            // Lawicel: the bit rate can only be set while the channel is closed.
            (Some(Command::Bitrate(n)), _) if !self.open => {
                self.bitrate = Some(n);
                Message::Ack
            }
            (Some(Command::Open), _) | (None, "L") if !self.open => {
                self.open = true;
                if self.start == ProgramStart::OnCanOpen {
                    let at = ctx.now + Duration::from_secs_f64(self.start_delay_s);
                    ctx.shared.start_program_at(at);
                }
                Message::Ack
            }
            (Some(Command::Timestamps(on)), _) => {
                self.timestamps = on;
                Message::Ack
            }
            (None, "V") => Message::Other(format!("V{}", self.cfg.version)),
            (None, "N") => Message::Other(format!("N{}", self.cfg.serial)),
            (None, "F") => Message::Other("F00".into()),
            _ => Message::Nack,
        };
        protocol::slcan::encode_message(&reply, ctx.out);
        let text = match &reply {
            Message::Ack => "ack".to_string(),
            Message::Nack => "nack".to_string(),
            Message::Other(s) => s.clone(),
            Message::Frame(_) => String::new(),
        };
        ctx.shared
            .lock_record()
            .trigger
            .device
            .commands
            .push((line.to_string(), text));
    }

    fn tick(&mut self, ctx: &mut Ctx) {
        self.events(ctx, true);
    }

    fn tick_unplugged(&mut self, ctx: &mut Ctx) {
        self.events(ctx, false);
    }

    fn is_terminator(b: u8) -> bool {
        b == b'\r' || b == b'\n'
    }
}
