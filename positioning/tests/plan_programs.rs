//! Planned positioning tests (`docs/methods.md` "Planning a positioning test"): the targets
//! follow ISO 230-2's P_i = (i − 1)p + r; the part program of each dialect is read back with a
//! syntax-level reader written here (every line must be one of the dialect's known forms) and
//! its moves, pose indices, triggers and dwells are checked against the trajectory CSV, read
//! back on its own.

use positioning::plan::{Dialect, PlanOptions, plan};

#[derive(Debug, Clone, PartialEq)]
enum Ev {
    Move(f64),
    Pose(usize),
    Trigger,
    Dwell(f64),
}

fn num(s: &str) -> f64 {
    s.trim_end_matches('.')
        .parse()
        .unwrap_or_else(|_| panic!("not a number: {s}"))
}

/// `G1 SUPA X12.345 F1000` (SINUMERIK), `G53 G1 X12.345 F1000` (LinuxCNC): the words
/// before the axis word given, then the axis and the feed; `G90 G53 X12.345` (FANUC: G53
/// moves at rapid traverse, no feed).
fn gmove(l: &str, words: &[&str], axis: char, feed: bool) -> Option<f64> {
    let f: Vec<&str> = l.split_whitespace().collect();
    let n = words.len();
    (f.len() == n + 1 + feed as usize
        && f[..n] == *words
        && f[n].starts_with(axis)
        && (!feed || f[n + 1].starts_with('F')))
    .then(|| num(&f[n][1..]))
}

fn read_sinumerik(text: &str) -> Vec<Ev> {
    let mut ev = vec![];
    for l in text.lines() {
        let code = l.split(';').next().unwrap().trim();
        if code.is_empty() || code == "G90 G71 G60 G601" {
            continue;
        } else if let Some(p) = gmove(code, &["G1", "SUPA"], 'X', true) {
            ev.push(Ev::Move(p));
        } else if let Some(n) = code.strip_prefix("R100=") {
            ev.push(Ev::Pose(n.parse().unwrap()));
        } else if code == "M101" {
            ev.push(Ev::Trigger);
        } else if let Some(s) = code.strip_prefix("G4 F") {
            ev.push(Ev::Dwell(num(s)));
        } else if code == "M30" {
            break;
        } else {
            panic!("SINUMERIK: unknown line `{l}`");
        }
    }
    ev
}

fn read_fanuc(text: &str) -> Vec<Ev> {
    let mut ev = vec![];
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines[0], "%");
    assert!(lines[1].starts_with('O') && lines[1][1..5].chars().all(|c| c.is_ascii_digit()));
    assert_eq!(*lines.last().unwrap(), "%");
    for l in &lines[2..lines.len() - 1] {
        assert!(
            !l.chars().any(|c| c.is_ascii_lowercase()),
            "FANUC: lower case in `{l}`"
        );
        if l.starts_with('(') {
            assert!(
                l.ends_with(')') && l.matches('(').count() == 1,
                "FANUC comment `{l}`"
            );
            continue;
        }
        if *l == "G21 G90 G61" {
        } else if let Some(p) = gmove(l, &["G90", "G53"], 'X', false) {
            ev.push(Ev::Move(p));
        } else if let Some(n) = l.strip_prefix("#100=") {
            ev.push(Ev::Pose(n.parse().unwrap()));
        } else if *l == "M101" {
            ev.push(Ev::Trigger);
        } else if let Some(ms) = l.strip_prefix("G04 P") {
            ev.push(Ev::Dwell(num(ms) / 1000.0));
        } else if *l == "M30" {
        } else {
            panic!("FANUC: unknown line `{l}`");
        }
    }
    ev
}

fn read_heidenhain(text: &str) -> Vec<Ev> {
    let mut ev = vec![];
    let mut pending_dwell = false;
    for (n, l) in text.lines().enumerate() {
        let (no, code) = l.split_once(' ').unwrap();
        assert_eq!(no.parse::<usize>().unwrap(), n, "block numbers run from 0");
        if n == 0 {
            assert_eq!(code, "BEGIN PGM ISO230X MM");
            continue;
        }
        if code.starts_with(';') {
            continue;
        }
        if let Some(rest) = code.strip_prefix("L X") {
            let f: Vec<&str> = rest.split_whitespace().collect();
            assert!(f[0].starts_with(['+', '-']), "sign required: `{l}`");
            assert!(
                f[1] == "R0" && f[2].starts_with('F') && f[3] == "M91",
                "`{l}`"
            );
            ev.push(Ev::Move(num(f[0])));
            match f.get(4) {
                Some(&"M101") => ev.push(Ev::Trigger),
                None => {}
                Some(m) => panic!("unexpected {m}"),
            }
        } else if let Some(q) = code.strip_prefix("FN 0: Q100 = +") {
            ev.push(Ev::Pose(q.parse().unwrap()));
        } else if code == "CYCL DEF 9.0 DWELL TIME" {
            pending_dwell = true;
        } else if let Some(s) = code.strip_prefix("CYCL DEF 9.1 DWELL ") {
            assert!(std::mem::take(&mut pending_dwell), "9.1 without 9.0");
            ev.push(Ev::Dwell(num(s)));
        } else if code == "END PGM ISO230X MM" {
            assert_eq!(n + 1, text.lines().count());
        } else {
            panic!("HEIDENHAIN: unknown block `{l}`");
        }
    }
    ev
}

fn read_linuxcnc(text: &str) -> Vec<Ev> {
    let mut ev = vec![];
    let mut out_on = false;
    for l in text.lines() {
        if l.starts_with('(') {
            assert!(l.ends_with(')'), "`{l}`");
            continue;
        }
        if l == "G21 G90 G61.1" {
        } else if let Some(p) = gmove(l, &["G53", "G1"], 'X', true) {
            ev.push(Ev::Move(p));
        } else if let Some(q) = l.strip_prefix("M68 E0 Q") {
            ev.push(Ev::Pose(q.parse().unwrap()));
        } else if l == "M64 P0" {
            assert!(!out_on);
            out_on = true;
            ev.push(Ev::Trigger);
        } else if l == "M65 P0" {
            assert!(out_on, "M65 without M64");
            out_on = false;
        } else if let Some(s) = l.strip_prefix("G4 P") {
            ev.push(Ev::Dwell(num(s)));
        } else if l == "M2" {
        } else {
            panic!("LinuxCNC: unknown line `{l}`");
        }
    }
    assert!(!out_on, "trigger output left on");
    ev
}

/// The x column of the trajectory rows, checking the other axes stay at 0.
fn trajectory(p: &positioning::plan::Plan) -> Vec<f64> {
    p.positions_xyz_mm()
        .iter()
        .map(|xyz| {
            assert_eq!((xyz[1], xyz[2]), (0.0, 0.0));
            xyz[0]
        })
        .collect()
}

/// Checks a program's events against the trajectory: every pose moved to in order; a
/// measured pose (reached from both sides over the run) is preceded by its index and followed
/// by a trigger and the dwell; a reversal pose by neither.
fn check(name: &str, ev: &[Ev], traj: &[f64], o: &PlanOptions) {
    let mut i = 0;
    let mut pose = 0;
    while i < ev.len() {
        let idx = match ev[i] {
            Ev::Pose(n) => {
                i += 1;
                Some(n)
            }
            _ => None,
        };
        let Ev::Move(x) = ev[i] else {
            panic!("{name}: expected a move at event {i}: {:?}", ev[i])
        };
        pose += 1;
        assert!(
            (x - traj[pose - 1]).abs() < 1e-9,
            "{name}: pose {pose} at {x}, trajectory {}",
            traj[pose - 1]
        );
        i += 1;
        match idx {
            Some(n) => {
                assert_eq!(n, pose, "{name}: trigger index");
                assert_eq!(ev[i], Ev::Trigger, "{name}");
                assert_eq!(ev[i + 1], Ev::Dwell(o.dwell_s), "{name}");
                i += 2;
            }
            None => assert!(
                !matches!(ev.get(i), Some(Ev::Trigger | Ev::Dwell(_))),
                "{name}: reversal with trigger"
            ),
        }
    }
    assert_eq!(pose, traj.len(), "{name}: all poses");
}

fn options() -> PlanOptions {
    PlanOptions {
        seed: 7,
        dwell_s: 2.0,
        overrun_mm: 5.0,
        ..PlanOptions::default()
    }
}

#[test]
fn targets_follow_iso_230_2_with_random_offsets() {
    let o = options();
    let p = plan(&o).unwrap();
    assert_eq!(p.targets_mm.len(), 11);
    // The targets lie inside the travel by the overrun: 5…495 mm.
    let step = 49.0;
    let mut offsets = vec![];
    for (i, t) in p.targets_mm.iter().enumerate() {
        let r = t - 5.0 - i as f64 * step;
        assert!(r.abs() <= 0.1 * step + 1e-9, "r_{i} = {r}");
        offsets.push(r);
    }
    assert!(
        offsets[0] >= 0.0 && offsets[10] <= 0.0,
        "targets stay within the travel"
    );
    // Offsets differ from target to target (periodic errors are not sampled at one phase).
    let distinct = offsets
        .iter()
        .map(|r| (r * 1000.0).round() as i64)
        .collect::<std::collections::BTreeSet<_>>();
    assert!(distinct.len() >= 9, "{offsets:?}");
    // Reproducible with the seed, different with another.
    assert_eq!(plan(&o).unwrap().targets_mm, p.targets_mm);
    assert_ne!(
        plan(&PlanOptions {
            seed: 8,
            ..o.clone()
        })
        .unwrap()
        .targets_mm,
        p.targets_mm
    );
    // 5 cycles × (11 up + 11 down + 2 reversals) + the start.
    assert_eq!(p.poses.len(), 1 + 5 * 24);
}

#[test]
fn trajectory_has_the_cycle_with_overrun() {
    let o = options();
    let p = plan(&o).unwrap();
    let x = trajectory(&p);
    let (first, last) = (p.targets_mm[0], p.targets_mm[10]);
    assert!((x[0] - (first - 5.0)).abs() < 1e-9);
    for c in 0..5 {
        let cyc = &x[1 + 24 * c..1 + 24 * (c + 1)];
        assert_eq!(&cyc[..11], &p.targets_mm[..], "up pass in order");
        assert!((cyc[11] - (last + 5.0)).abs() < 1e-9, "overrun above");
        let down: Vec<f64> = p.targets_mm.iter().rev().copied().collect();
        assert_eq!(&cyc[12..23], &down[..], "down pass in order");
        assert!((cyc[23] - (first - 5.0)).abs() < 1e-9, "overrun below");
    }
}

#[test]
fn every_dialect_program_reads_back_as_the_trajectory() {
    let o = options();
    let p = plan(&o).unwrap();
    let traj = trajectory(&p);
    for (d, read) in [
        (Dialect::Sinumerik, read_sinumerik as fn(&str) -> Vec<Ev>),
        (Dialect::Fanuc, read_fanuc),
        (Dialect::Heidenhain, read_heidenhain),
        (Dialect::LinuxCnc, read_linuxcnc),
    ] {
        let prog = p.part_program(d);
        let ev = read(&prog);
        check(&format!("{d:?}"), &ev, &traj, &o);
        assert_eq!(
            ev.iter().filter(|e| **e == Ev::Trigger).count(),
            110,
            "{d:?}"
        );
        assert!(
            prog.contains("cycle 5") || prog.contains("CYCLE 5"),
            "{d:?}: cycle comments"
        );
    }
}

#[test]
fn every_move_stays_inside_the_given_travel() {
    for overrun in [0.0, 5.0, 20.0] {
        let p = plan(&PlanOptions {
            overrun_mm: overrun,
            ..options()
        })
        .unwrap();
        for x in trajectory(&p) {
            assert!((0.0..=500.0).contains(&x), "overrun {overrun}: X {x}");
        }
    }
}

#[test]
fn iso_minimums_are_enforced_unless_a_reason_is_given() {
    for (o, want) in [
        (
            PlanOptions {
                targets: 3,
                ..options()
            },
            "3 targets",
        ),
        (
            PlanOptions {
                cycles: 2,
                ..options()
            },
            "2 cycles",
        ),
        (
            PlanOptions {
                targets: 5,
                to_mm: 2000.0,
                ..options()
            },
            "at least 5 per metre",
        ),
    ] {
        let e = plan(&o).unwrap_err().to_string();
        assert!(e.contains(want) && e.contains("--below-iso-minimum"), "{e}");
        let reason = "quick check after a crash".to_string();
        let p = plan(&PlanOptions {
            below_iso_minimum: Some(reason.clone()),
            ..o
        })
        .unwrap();
        for d in [
            Dialect::Sinumerik,
            Dialect::Fanuc,
            Dialect::Heidenhain,
            Dialect::LinuxCnc,
        ] {
            let prog = p.part_program(d).to_ascii_lowercase();
            assert!(
                prog.contains("below iso 230-2 minimums") && prog.contains(&reason),
                "{d:?}"
            );
        }
    }
    assert_eq!(positioning::plan::iso_minimums(2000.0), (10, 5));
    assert_eq!(positioning::plan::iso_minimums(300.0), (5, 5));
}

#[test]
fn bad_plans_say_what_to_fix() {
    for (o, want) in [
        (
            PlanOptions {
                to_mm: -1.0,
                ..options()
            },
            "--to",
        ),
        (
            PlanOptions {
                targets: 1,
                ..options()
            },
            "targets",
        ),
        (
            PlanOptions {
                axis: 'Q',
                ..options()
            },
            "--axis",
        ),
        (
            PlanOptions {
                dwell_s: -1.0,
                ..options()
            },
            "--dwell",
        ),
        (
            PlanOptions {
                max_offset_mm: Some(30.0),
                ..options()
            },
            "half",
        ),
        (
            PlanOptions {
                overrun_mm: 250.0,
                ..options()
            },
            "--overrun",
        ),
    ] {
        let e = plan(&o).unwrap_err().to_string();
        assert!(e.contains(want), "{e}");
    }
}
