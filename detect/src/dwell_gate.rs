//! The other instruments' values of a pose wait for the interferometer's (docs/design.md,
//! "Values off their target").
//!
//! Only the interferometer has an absolute target per pose. When its value of pose k is
//! `off_target`, the dwell was placed on another pose's samples or the zero was not the datum,
//! and the log cannot tell which: the CapBall's and the PSD's values of pose k came from the
//! same triggers' window, so they are not `ok` either. Each instrument's detector decides on
//! its own and in its own time, so a CapBall or PSD value is held here until the
//! interferometer has decided the same pose, or has moved past its dwell (a later value), or
//! the run ends. It goes at once, as it is, when the interferometer's own samples during its
//! window already read within the tolerance of the pose's target: the dwell was where the
//! pose is (the common case, which then costs no latency).

use std::collections::{BTreeMap, VecDeque};

use types::{Instrument, PoseMsg, PoseStatus, PositionTargets};

/// How many interferometer verdicts are remembered (a run visits poses in order; the values
/// waiting here are of the last few).
const VERDICTS_KEPT: usize = 64;
/// Most values held: past it the oldest goes unjudged (an interferometer that never decides
/// must not make the others' values pile up for the length of a run).
const WAITING_MAX: usize = 1024;
/// The interferometer's valid samples are summed in bins this long, for the mean over another
/// instrument's window.
const BIN_NS: u64 = 1_000_000;
/// How much of the interferometer's recent past the bins cover.
const BINS_KEPT_NS: u64 = 5_000_000_000;

/// The interferometer's valid samples of one bin: (bin index, sum, count).
type Bin = (u64, f64, u32);

/// Values waiting for the interferometer's verdict on their pose.
#[derive(Debug, Clone)]
pub(crate) struct DwellGate {
    /// Where the interferometer must read at each pose.
    targets: PositionTargets,
    /// The interferometer's recent valid samples, binned.
    bins: VecDeque<Bin>,
    /// Time of the newest interferometer sample (valid or not).
    newest_ns: u64,
    /// The front waiting value's early check failed: it waits for the verdict.
    front_checked: bool,
    /// Pose → whether the interferometer's value of it was `off_target`.
    verdicts: BTreeMap<u32, bool>,
    /// Order the verdicts came in, to forget the oldest.
    order: VecDeque<u32>,
    /// Start of the interferometer's newest dwell: a value that ended before it is released.
    passed_ns: u64,
    waiting: VecDeque<PoseMsg>,
}

impl DwellGate {
    pub(crate) fn new(targets: PositionTargets) -> Self {
        DwellGate {
            targets,
            bins: VecDeque::new(),
            newest_ns: 0,
            front_checked: false,
            verdicts: BTreeMap::new(),
            order: VecDeque::new(),
            passed_ns: 0,
            waiting: VecDeque::new(),
        }
    }

    /// An interferometer sample (its fitted time): the bins of the early check.
    pub(crate) fn observe(&mut self, t_ns: u64, position_um: f64, valid: bool) {
        self.newest_ns = self.newest_ns.max(t_ns);
        if !valid || !position_um.is_finite() {
            return;
        }
        let bin = t_ns / BIN_NS;
        match self.bins.back_mut() {
            Some(b) if b.0 == bin => {
                b.1 += position_um;
                b.2 += 1;
            }
            Some(b) if b.0 > bin => {} // out of order: not used
            _ => self.bins.push_back((bin, position_um, 1)),
        }
        let oldest = self.newest_ns.saturating_sub(BINS_KEPT_NS) / BIN_NS;
        while self.bins.front().is_some_and(|b| b.0 < oldest) {
            self.bins.pop_front();
        }
    }

    /// Whether the interferometer's samples during `m`'s window read within the tolerance of
    /// its pose's target (`None`: they have not all come, or there are none).
    fn reads_on_target(&self, m: &PoseMsg) -> Option<bool> {
        if self.newest_ns < m.t_last_ns {
            return None;
        }
        let (first, last) = (m.t_first_ns / BIN_NS, m.t_last_ns / BIN_NS);
        let (sum, n) = self
            .bins
            .iter()
            .filter(|b| b.0 >= first && b.0 <= last)
            .fold((0.0, 0u32), |(s, n), b| (s + b.1, n + b.2));
        let want = self.targets.target_um(m.pose)?;
        let tol = self.targets.tolerance_um(m.pose)?;
        (n > 0).then(|| (sum / f64::from(n) - want).abs() <= tol)
    }

    /// The values of `out` that may go now, in order, with those released by it.
    pub(crate) fn pass(&mut self, out: Vec<PoseMsg>) -> Vec<PoseMsg> {
        let mut released = Vec::with_capacity(out.len());
        for m in out {
            if m.instrument == Instrument::Interferometer {
                self.decide(&m);
                released.push(m);
            } else {
                self.waiting.push_back(m);
            }
        }
        self.release(false, &mut released);
        released
    }

    /// End of the run: every value still waiting goes, judged if its pose was decided.
    pub(crate) fn flush(&mut self, mut out: Vec<PoseMsg>) -> Vec<PoseMsg> {
        out = self.pass(out);
        self.release(true, &mut out);
        out
    }

    /// Whether `m` (the front waiting value) may go as it is before the verdict: a value that
    /// is not `ok` (the verdict changes only `ok` ones), or one whose window the interferometer
    /// read on target. `None`: not yet known (its samples have not all come).
    fn early(&self, m: &PoseMsg) -> Option<bool> {
        if m.status != PoseStatus::Ok {
            return Some(true);
        }
        if self.front_checked {
            return Some(false);
        }
        self.reads_on_target(m)
    }

    fn decide(&mut self, m: &PoseMsg) {
        if self
            .verdicts
            .insert(m.pose, m.status == PoseStatus::OffTarget)
            .is_none()
        {
            self.order.push_back(m.pose);
        }
        if self.order.len() > VERDICTS_KEPT
            && let Some(old) = self.order.pop_front()
        {
            self.verdicts.remove(&old);
        }
        self.passed_ns = self.passed_ns.max(m.t_first_ns);
    }

    /// Moves the waiting values whose pose is decided (or passed, or all with `all`) to `out`,
    /// in order: a value waits behind an earlier one still waiting.
    fn release(&mut self, all: bool, out: &mut Vec<PoseMsg>) {
        while let Some(m) = self.waiting.front() {
            let verdict = self.verdicts.get(&m.pose).copied();
            let full = self.waiting.len() > WAITING_MAX;
            let decided = all || full || verdict.is_some() || m.t_last_ns < self.passed_ns;
            if !decided {
                // The check is made once: a value that read off target waits for the verdict.
                match self.early(m) {
                    Some(true) => {}
                    Some(false) => {
                        self.front_checked = true;
                        break;
                    }
                    None => break,
                }
            }
            self.front_checked = false;
            let Some(mut m) = self.waiting.pop_front() else {
                break;
            };
            if verdict == Some(true) && m.status == PoseStatus::Ok {
                m.status = PoseStatus::OffTarget;
            }
            out.push(m);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Pose k's target: k mm.
    fn targets() -> PositionTargets {
        PositionTargets {
            targets_um: (1..=10_000).map(|k| f64::from(k) * 1000.0).collect(),
            tol_um: 2000.0,
            floor_um: None,
        }
    }

    fn value(instrument: Instrument, pose: u32, status: PoseStatus) -> PoseMsg {
        let t = u64::from(pose) * 1_000_000_000;
        PoseMsg {
            instrument,
            pose,
            status,
            n: 150,
            mean: Default::default(),
            std: Default::default(),
            t_first_ns: t,
            t_last_ns: t + 500_000_000,
            datum_epoch: 0,
        }
    }

    #[test]
    fn a_value_waits_for_the_interferometers_verdict_on_its_pose() {
        use Instrument::{Capball, Interferometer, Psd};
        use PoseStatus::{DeviceAway, OffTarget, Ok};
        let mut g = DwellGate::new(targets());
        // The CapBall decides pose 1 first: it waits.
        assert!(g.pass(vec![value(Capball, 1, Ok)]).is_empty());
        // The interferometer's pose 1 is right: the CapBall's goes as it was.
        let got = g.pass(vec![value(Interferometer, 1, Ok), value(Psd, 1, Ok)]);
        let st: Vec<_> = got
            .iter()
            .map(|m| (m.instrument, m.pose, m.status))
            .collect();
        assert_eq!(
            st,
            [(Interferometer, 1, Ok), (Capball, 1, Ok), (Psd, 1, Ok)]
        );
        // Pose 2's interferometer value is off its target: the others' ok values are not ok;
        // one that already failed keeps its own status.
        g.pass(vec![value(Capball, 2, Ok), value(Psd, 2, DeviceAway)]);
        let got = g.pass(vec![value(Interferometer, 2, OffTarget)]);
        let st: Vec<_> = got.iter().map(|m| (m.instrument, m.status)).collect();
        assert_eq!(
            st,
            [
                (Interferometer, OffTarget),
                (Capball, OffTarget),
                (Psd, DeviceAway)
            ]
        );
        // Pose 3 never gets an interferometer value, pose 4 does: pose 3's CapBall value goes
        // unjudged once the interferometer is past its dwell.
        assert!(g.pass(vec![value(Capball, 3, Ok)]).is_empty());
        let got = g.pass(vec![value(Interferometer, 4, Ok)]);
        assert_eq!(got.len(), 2);
        assert_eq!((got[1].pose, got[1].status), (3, Ok));
        // The run ends with a value still waiting: it goes.
        assert!(g.pass(vec![value(Psd, 5, Ok)]).is_empty());
        let got = g.flush(Vec::new());
        assert_eq!((got[0].pose, got[0].status), (5, Ok));
    }

    /// A value whose window the interferometer read on target goes before the verdict; one it
    /// read off target waits for it.
    #[test]
    fn a_value_whose_window_read_on_target_goes_at_once() {
        use Instrument::{Capball, Interferometer, Psd};
        use PoseStatus::{OffTarget, Ok};
        let mut g = DwellGate::new(targets());
        // Pose 3 (target 3000 µm): the interferometer reads 3000.4 µm through the window.
        let m = value(Capball, 3, Ok);
        for i in 0..=100u64 {
            g.observe(m.t_first_ns + i * 5_000_000, 3000.4, true);
        }
        let got = g.pass(vec![m]);
        assert_eq!(got.len(), 1, "went before the interferometer's value");
        assert_eq!(got[0].status, Ok);
        // Pose 4 (4000 µm): it reads pose 9's position: the PSD's value waits, then is judged.
        let m = value(Psd, 4, Ok);
        for i in 0..=100u64 {
            g.observe(m.t_first_ns + i * 5_000_000, 9000.0, true);
        }
        assert!(g.pass(vec![m]).is_empty());
        // Invalid samples do not count: still waiting.
        g.observe(4_600_000_000, 4000.0, false);
        assert!(g.pass(Vec::new()).is_empty());
        let got = g.pass(vec![value(Interferometer, 4, OffTarget)]);
        let st: Vec<_> = got.iter().map(|m| (m.instrument, m.status)).collect();
        assert_eq!(st, [(Interferometer, OffTarget), (Psd, OffTarget)]);
    }

    #[test]
    fn the_verdicts_kept_are_bounded() {
        let mut g = DwellGate::new(targets());
        for pose in 0..1000 {
            g.pass(vec![value(
                Instrument::Interferometer,
                pose,
                PoseStatus::Ok,
            )]);
        }
        assert_eq!(g.verdicts.len(), VERDICTS_KEPT);
        assert_eq!(g.order.len(), VERDICTS_KEPT);
        // The interferometer decides nothing more: the others' values do not pile up.
        let mut g = DwellGate::new(targets());
        let mut out = 0;
        for pose in 0..5000 {
            out += g
                .pass(vec![value(Instrument::Capball, pose, PoseStatus::Ok)])
                .len();
        }
        assert_eq!(g.waiting.len(), WAITING_MAX);
        assert_eq!(out, 5000 - WAITING_MAX);
        // Ten minutes of interferometer samples at 10 kHz keep 5 s of bins.
        let mut g = DwellGate::new(targets());
        for i in 0..6_000_000u64 {
            g.observe(i * 100_000, 1.0, true);
        }
        assert!(g.bins.len() <= (BINS_KEPT_NS / BIN_NS) as usize + 1);
    }
}
