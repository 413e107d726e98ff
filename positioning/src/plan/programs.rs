//! Part programs for a [`Plan`] in each controller dialect (`docs/methods.md` "Planning a
//! positioning test" lists each dialect's words and their sources). One generic writer: the
//! dialects differ only in the words below.
//!
//! Per measured stop the program sets the pose index where the PLC (or HAL) finds it, moves
//! in exact stop to the target, pulses the trigger and dwells; a reversal (overrun) stop is a
//! plain move.

use std::fmt::Write;

use super::{Dialect, POSE_PARAMETER, Plan};

/// The words of a dialect.
struct Words {
    /// A comment line's text (without block number).
    comment: fn(&str) -> String,
    /// Lines before the first move (after the header comments).
    setup: fn(&Plan) -> Vec<String>,
    /// Linear move at feed to an absolute position of the axis.
    mov: fn(char, f64, f64) -> String,
    /// Sets the pose index for the trigger.
    pose: fn(usize) -> String,
    /// Pulses the trigger after the move, `None` when it rides on the move block.
    trigger: fn(u32) -> Option<String>,
    /// Appended to the move block of a measured stop.
    on_move: fn(u32) -> String,
    dwell: fn(f64) -> Vec<String>,
    end: fn(&Plan) -> Vec<String>,
    /// Block numbers from 0 on every line (HEIDENHAIN conversational).
    numbered: bool,
}

fn fmt_mm(v: f64) -> String {
    let s = format!("{v:.3}");
    if s == "-0.000" { "0.000".into() } else { s }
}

fn signed_mm(v: f64) -> String {
    let s = fmt_mm(v);
    if s.starts_with('-') {
        s
    } else {
        format!("+{s}")
    }
}

fn none(_: u32) -> String {
    String::new()
}

fn words(d: Dialect) -> Words {
    match d {
        // SINUMERIK 840D sl / 828D (Programming Manual Fundamentals): `;` comments, G90 G71
        // absolute metric, G60 G601 modal exact stop (fine window), SUPA per block (machine
        // coordinates: all frames and offsets suppressed), G4 F<s> dwell in seconds, R
        // parameters, user M function, M30.
        Dialect::Sinumerik => Words {
            comment: |t| format!("; {t}"),
            setup: |_| vec!["G90 G71 G60 G601 ; absolute, mm, exact stop fine".into()],
            mov: |a, p, f| format!("G1 SUPA {a}{} F{f:.0}", fmt_mm(p)),
            pose: |n| format!("R{POSE_PARAMETER}={n}"),
            trigger: |m| Some(format!("M{m}")),
            on_move: none,
            dwell: |s| vec![format!("G4 F{s}")],
            end: |_| vec!["M30".into()],
            numbered: false,
        },
        // FANUC Series 0i/30i (Operator's Manual): `%` and O number, `( )` comments, G21 G90
        // metric absolute, G61 exact stop mode, G53 per block (machine coordinate system;
        // one-shot, moves at rapid traverse, so no feed is given), #100 common variable,
        // G04 P<ms> dwell, M30.
        Dialect::Fanuc => Words {
            comment: |t| format!("({})", t.to_ascii_uppercase().replace(['(', ')'], "")),
            setup: |_| vec!["G21 G90 G61".into()],
            mov: |a, p, _| format!("G90 G53 {a}{}", fmt_mm(p)),
            pose: |n| format!("#{POSE_PARAMETER}={n}"),
            trigger: |m| Some(format!("M{m}")),
            on_move: none,
            dwell: |s| vec![format!("G04 P{}", (s * 1000.0).round() as u64)],
            end: |_| vec!["M30".into(), "%".into()],
            numbered: false,
        },
        // HEIDENHAIN TNC conversational (User's Manual): numbered blocks, BEGIN/END PGM,
        // `;` comment blocks, L X+… R0 F… M91 (coordinates referenced to the machine datum),
        // FN 0: Q assignment, cycle 9 DWELL TIME, the trigger M function on the positioning
        // block (executed at the block end).
        Dialect::Heidenhain => Words {
            comment: |t| format!("; {t}"),
            setup: |p| vec![format!("BEGIN PGM ISO230{} MM", p.options.axis)],
            mov: |a, p, f| format!("L {a}{} R0 F{f:.0} M91", signed_mm(p)),
            pose: |n| format!("FN 0: Q{POSE_PARAMETER} = +{n}"),
            trigger: |_| None,
            on_move: |m| format!(" M{m}"),
            dwell: |s| {
                vec![
                    "CYCL DEF 9.0 DWELL TIME".into(),
                    format!("CYCL DEF 9.1 DWELL {s}"),
                ]
            },
            end: |p| vec![format!("END PGM ISO230{} MM", p.options.axis)],
            numbered: true,
        },
        // LinuxCNC G-code (G-code and M-code reference): `( )` comments, G21 G90 G61.1
        // exact stop, G53 per block (machine coordinates, non-modal), M68 E0 Q<n> analog
        // output 0 = pose index (immediate), M64/M65 P0 digital output 0 on/off as the
        // trigger, G4 P<s> dwell in seconds, M2. Checked by running it through rs274
        // (`positioning/tests/compensation_linuxcnc.rs`).
        Dialect::LinuxCnc => Words {
            comment: |t| format!("({})", t.replace(['(', ')'], "")),
            setup: |_| vec!["G21 G90 G61.1".into()],
            mov: |a, p, f| format!("G53 G1 {a}{} F{f:.0}", fmt_mm(p)),
            pose: |n| format!("M68 E0 Q{n}"),
            trigger: |_| Some("M64 P0".into()),
            on_move: none,
            dwell: |s| vec![format!("G4 P{s}"), "M65 P0".into()],
            end: |_| vec!["M2".into()],
            numbered: false,
        },
    }
}

/// Header comments: what the program is and what the trigger does.
fn header(p: &Plan, d: Dialect) -> Vec<String> {
    let o = &p.options;
    let trig = match d {
        Dialect::LinuxCnc => {
            "digital output 0 (M64 P0) with the pose index on analog output 0".to_string()
        }
        _ => format!(
            "M{} with the pose index in parameter {POSE_PARAMETER}",
            o.trigger_m
        ),
    };
    let mut h = vec![
        format!(
            "ISO 230-2 positioning test of axis {}, {} targets, {} bidirectional cycles, written by metrolog plan (seed {})",
            o.axis, o.targets, o.cycles, o.seed
        ),
        format!(
            "targets mm: {}",
            p.targets_mm
                .iter()
                .map(|t| fmt_mm(*t))
                .collect::<Vec<_>>()
                .join(" ")
        ),
        format!(
            "overrun {} mm past the end targets before each reversal, dwell {} s at each target, feed {} mm/min",
            o.overrun_mm, o.dwell_s, o.feed_mm_min
        ),
        format!(
            "exact-stop trigger: {trig}; the PLC sends the CAN trigger frame (docs/instruments.md 4)"
        ),
        format!(
            "machine coordinates ({}); travel {} to {} mm, no move leaves it",
            machine_word(d),
            fmt_mm(o.from_mm),
            fmt_mm(o.to_mm)
        ),
    ];
    let below = super::below_minimums(o);
    if !below.is_empty() {
        h.push(format!(
            "BELOW ISO 230-2 MINIMUMS: {}; reason given: {}",
            below.join("; "),
            o.below_iso_minimum.as_deref().unwrap_or("").trim()
        ));
    }
    h
}

fn machine_word(d: Dialect) -> &'static str {
    match d {
        Dialect::Sinumerik => "SUPA on every move",
        Dialect::Fanuc => "G53 on every move, at rapid traverse: the feed does not apply",
        Dialect::Heidenhain => "M91 on every move",
        Dialect::LinuxCnc => "G53 on every move",
    }
}

pub(super) fn program(p: &Plan, d: Dialect) -> String {
    let w = words(d);
    let o = &p.options;
    let mut lines: Vec<String> = Vec::new();
    if d == Dialect::Fanuc {
        lines.push("%".into());
        lines.push(format!("O2302 (ISO 230-2 {})", o.axis));
    }
    let setup = (w.setup)(p);
    // HEIDENHAIN's BEGIN PGM must come first; the others take comments first.
    let (first, rest) = if w.numbered {
        (setup, vec![])
    } else {
        (vec![], setup)
    };
    lines.extend(first);
    lines.extend(header(p, d).iter().map(|t| (w.comment)(t)));
    lines.extend(rest);
    let mut cycle = 0;
    for pose in &p.poses {
        match pose.target {
            None => {
                lines.push((w.comment)(&format!(
                    "pose {}: reversal (overrun)",
                    pose.pose
                )));
                lines.push((w.mov)(o.axis, pose.position_mm, o.feed_mm_min));
            }
            Some((c, dir, i)) => {
                if c != cycle {
                    cycle = c;
                    lines.push((w.comment)(&format!("cycle {c}")));
                }
                let sign = if dir == crate::axis_model::Direction::Up {
                    "+"
                } else {
                    "-"
                };
                lines.push((w.comment)(&format!(
                    "pose {}: target {i}, approach {sign}",
                    pose.pose
                )));
                lines.push((w.pose)(pose.pose));
                lines.push(
                    (w.mov)(o.axis, pose.position_mm, o.feed_mm_min) + &(w.on_move)(o.trigger_m),
                );
                lines.extend((w.trigger)(o.trigger_m));
                lines.extend((w.dwell)(o.dwell_s));
            }
        }
    }
    lines.extend((w.end)(p));
    let mut s = String::new();
    for (n, l) in lines.iter().enumerate() {
        if w.numbered {
            let _ = writeln!(s, "{n} {l}");
        } else {
            let _ = writeln!(s, "{l}");
        }
    }
    s
}
