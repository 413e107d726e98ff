//! A LinuxCNC comp file loaded into the simulated X axis moves the reflector by the trim of the
//! direction of approach (`sim::axis_comp`): a table holding −(the axis model's systematic
//! deviation) at the targets leaves nothing of it, the same table with its sign turned doubles
//! it. The per-pose truth is the one a run's `Record::truth` holds (same function).

use std::fmt::Write as _;
use std::sync::Arc;

use positioning::axis_model::Direction;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use sim::physics::World;
use sim::{CapballTruth, PoseTruth, Scenario, ScrewComp};

fn truth_of(sc: &Scenario) -> Vec<PoseTruth> {
    let model: Arc<dyn CapballTruth> = Arc::new(sc.capball.truth.clone());
    let mut rng = ChaCha8Rng::seed_from_u64(sc.seed);
    World::new(sc.clone(), model, &mut rng).truth()
}

/// The demo's axis without its time effects and noise: only the systematic table.
fn static_axis() -> Scenario {
    let mut sc = Scenario::demo();
    sc.program.poses.truncate(60);
    sc.axis.effects.clear();
    sc.axis.noise_um = 0.0;
    sc
}

/// A comp file with trims = −systematic deviation at each target, 0 at home (0 mm).
fn exact_table(sc: &Scenario) -> String {
    let mut s = String::from("0.0 0.0 0.0\n");
    let a = &sc.axis;
    for ((x, u), d) in a
        .targets_mm
        .iter()
        .zip(&a.systematic_up_um)
        .zip(&a.systematic_down_um)
    {
        let _ = writeln!(s, "{x} {} {}", -u * 1e-3, -d * 1e-3);
    }
    s
}

fn largest(truth: &[PoseTruth], sc: &Scenario) -> f64 {
    // The measured poses of the ISO run (reversals have no dwell).
    truth
        .iter()
        .zip(&sc.program.poses)
        .filter(|(_, p)| p.dwell_s != Some(0.0))
        .map(|(t, _)| t.deviation_um.abs())
        .fold(0.0, f64::max)
}

#[test]
fn the_trim_of_the_direction_moves_the_axis() {
    let sc = static_axis();
    let before = largest(&truth_of(&sc), &sc);
    assert!((before - 4.1).abs() < 1e-9, "{before}");
    let table = ScrewComp::from_linuxcnc(&exact_table(&sc)).expect("valid table");

    let mut on = sc.clone();
    on.axis_comp = Some(table.clone());
    let truth = truth_of(&on);
    assert!(largest(&truth, &on) < 1e-9, "{}", largest(&truth, &on));
    // Reversal poses (404.05 and −2.688 mm) lie outside the table: the end trims are held.
    let rev = &truth[5];
    assert!((rev.x_mm - 404.05).abs() < 1e-9 && rev.direction == Direction::Up);
    let plain = &truth_of(&sc)[5];
    assert!((rev.deviation_um - (plain.deviation_um - 4.1)).abs() < 1e-9);

    let mut wrong = sc.clone();
    wrong.axis_comp = Some(table.negated());
    let doubled = largest(&truth_of(&wrong), &wrong);
    assert!((doubled - 2.0 * before).abs() < 1e-9, "{doubled}");
}

#[test]
fn the_datum_at_home_takes_the_trim_there() {
    let mut sc = static_axis();
    // A table that is 1 µm everywhere (a constant a pitch table cannot correct) shifts
    // nothing the interferometer sees from its datum at home.
    sc.axis_comp =
        Some(ScrewComp::from_linuxcnc("-10 0.001 0.001\n500 0.001 0.001\n").expect("table"));
    let with = truth_of(&sc);
    sc.axis_comp = None;
    let without = truth_of(&sc);
    for (a, b) in with.iter().zip(&without) {
        assert!((a.deviation_um - b.deviation_um).abs() < 1e-12);
    }
}
