//! Readers of the controllers' compensation files, written from each controller's documented
//! semantics (the manual page is named at each reader), never from metrolog's writers. Each
//! returns the *shift* the control adds to the commanded position at its points (µm), per
//! direction of approach, and [`shift_at`] applies it between points as the control does.

#![allow(dead_code)]

/// A table as a control applies it.
#[derive(Debug, Clone)]
pub struct Applied {
    pub points_mm: Vec<f64>,
    pub up_um: Vec<f64>,
    pub down_um: Vec<f64>,
}

/// Linear between points, the end values held outside (LinuxCNC `control.c`
/// `compute_screw_comp`; SINUMERIK K3 §4.4.2.3 figure "compensation curve (linear
/// interpolation between interpolation points)"). Written here, not taken from the crate.
pub fn shift_at(pts: &[f64], ys: &[f64], x: f64) -> f64 {
    if x <= pts[0] {
        return ys[0];
    }
    for i in 1..pts.len() {
        if x <= pts[i] {
            let f = (x - pts[i - 1]) / (pts[i] - pts[i - 1]);
            return ys[i - 1] + f * (ys[i] - ys[i - 1]);
        }
    }
    ys[ys.len() - 1]
}

impl Applied {
    pub fn at(&self, x: f64, up: bool) -> f64 {
        shift_at(
            &self.points_mm,
            if up { &self.up_um } else { &self.down_um },
            x,
        )
    }
}

/// LinuxCNC type-1 comp file, read as `usrmotLoadComp` (src/emc/motion/usrmotintf.cc) does:
/// three numbers per line (`%lf %lf %lf`), reading stops at the first line that is not;
/// motion adds the trim of the direction of motion to the commanded position
/// (`motor-pos-cmd = pos-cmd + trim`, src/emc/motion/control.c). Panics when a line is
/// skipped (the loader would silently drop the rest of the table).
pub fn linuxcnc(text: &str) -> Applied {
    let mut t = Applied {
        points_mm: vec![],
        up_um: vec![],
        down_um: vec![],
    };
    let lines: Vec<&str> = text.lines().collect();
    for (i, row) in lines.iter().enumerate() {
        let f: Vec<f64> = row
            .split_whitespace()
            .map_while(|x| x.parse().ok())
            .collect();
        assert!(
            f.len() >= 3,
            "line {} `{row}` is not three numbers: LinuxCNC stops reading there and ignores the remaining {} lines",
            i + 1,
            lines.len() - i
        );
        if let Some(last) = t.points_mm.last() {
            assert!(f[0] > *last, "nominals must increase (command.c)");
        }
        t.points_mm.push(f[0]);
        t.up_um.push(f[1] * 1e3);
        t.down_um.push(f[2] * 1e3);
    }
    assert!(t.points_mm.len() <= 256, "EMCMOT_COMP_SIZE is 256");
    t
}

/// SINUMERIK `%_N_AX_EEC_INI` (840D sl Function Manual Extended Functions K3 §4.4.2.3, its
/// example for X1): `$AA_ENC_COMP[0,N,axis]` in mm at `_MIN + N·_STEP`; the compensation
/// corrects the actual value, so the axis moves by −value (808D Function Manual: "a positive
/// compensation value causes the machine axis to move in the negative direction"); the
/// backlash MD32450 (mm) is added on negative moves after referencing in the positive
/// direction. Returns the table and the axis name.
pub fn sinumerik(text: &str, backlash_mm: f64) -> (Applied, String) {
    assert_eq!(text.lines().next(), Some("%_N_AX_EEC_INI"));
    assert!(text.contains("\nCHANDATA(1)\n") && text.trim_end().ends_with("M17"));
    let mut vals: Vec<(usize, f64)> = Vec::new();
    let (mut step, mut min, mut max, mut axis) = (None, None, None, None);
    for l in text.lines().filter(|l| l.starts_with('$')) {
        let code = l.split(';').next().unwrap_or("").trim();
        let (k, v) = code.split_once('=').expect("`name[...]=value`");
        let v: f64 = v.trim().parse().expect("a number");
        let open = k.find('[').expect("[");
        let idx: Vec<&str> = k[open + 1..k.len() - 1].split(',').collect();
        assert_eq!(idx[0], "0", "encoder 0");
        let ax = idx[idx.len() - 1].to_string();
        assert!(axis.get_or_insert(ax.clone()) == &ax, "one axis per table");
        match &k[..open] {
            "$AA_ENC_COMP" => vals.push((idx[1].parse().expect("point number"), v * 1e3)),
            "$AA_ENC_COMP_STEP" => step = Some(v),
            "$AA_ENC_COMP_MIN" => min = Some(v),
            "$AA_ENC_COMP_MAX" => max = Some(v),
            "$AA_ENC_COMP_IS_MODULO" => assert_eq!(v, 0.0),
            other => panic!("unexpected {other}"),
        }
    }
    let (step, min, max) = (step.unwrap(), min.unwrap(), max.unwrap());
    let last = vals.iter().map(|v| v.0).max().unwrap();
    assert!(
        (min + step * last as f64 - max).abs() < 1e-6,
        "_MAX = _MIN + N·_STEP"
    );
    let pts: Vec<f64> = vals.iter().map(|(n, _)| min + *n as f64 * step).collect();
    let up: Vec<f64> = vals.iter().map(|(_, v)| -v).collect();
    let down = up.iter().map(|u| u - backlash_mm * 1e3).collect();
    let t = Applied {
        points_mm: pts,
        up_um: up,
        down_um: down,
    };
    (t, axis.unwrap())
}

/// A FANUC parameter tape: `N<no>A<axis>P<value>` or `N<no>P<value>` between `%` lines.
fn fanuc_tape(t: &str) -> Vec<(i64, i64)> {
    assert!(t.starts_with("%\n") && t.trim_end().ends_with('%'));
    t.lines()
        .filter(|l| l.starts_with('N'))
        .map(|l| {
            let p = l.find('P').expect("P");
            let end = l.find(['A', 'P']).expect("A or P");
            (
                l[1..end].parse().expect("number"),
                l[p + 1..].parse().expect("value"),
            )
        })
        .collect()
}

/// FANUC stored pitch error compensation (Series 0i-PB Parameter Manual B-63980EN/01,
/// Nos. 3620–3624, p. 100): the value of point N is output over the section N − 1 → N, the
/// absolute compensation at a point is the sum of the values from the reference position
/// (No.3620) to it, in detection units (1 µm) × No.3623; point N lies at reference +
/// (N − No.3620) × No.3624; the first section starts one interval below No.3621. Values move
/// the axis. Backlash No.1851 is output on negative moves. Between points the shift is taken
/// as linear here (the manual gives the values per section, not how they are spread).
pub fn fanuc(params: &str, pitch: &str, reference_mm: f64) -> Applied {
    let prm = fanuc_tape(params);
    let get = |no: i64| prm.iter().find(|(n, _)| *n == no).map(|p| p.1);
    let (r, lo, hi) = (get(3620).unwrap(), get(3621).unwrap(), get(3622).unwrap());
    let mag = get(3623).unwrap() as f64;
    let step = get(3624).unwrap() as f64 * 1e-3;
    assert!(lo <= r + 1 && r <= hi, "{lo} ≤ {r} + 1, {r} ≤ {hi}");
    let data = fanuc_tape(pitch);
    let val = |no: i64| {
        data.iter()
            .find(|(n, _)| *n == 10000 + no)
            .unwrap_or_else(|| panic!("no value for point {no}"))
            .1 as f64
            * mag
    };
    let abs = |k: i64| -> f64 {
        if k >= r {
            (r + 1..=k).map(val).sum()
        } else {
            -(k + 1..=r).map(val).sum::<f64>()
        }
    };
    let ks: Vec<i64> = (lo - 1..=hi).collect();
    let up: Vec<f64> = ks.iter().map(|&k| abs(k)).collect();
    let b = get(1851).unwrap_or(0) as f64;
    Applied {
        points_mm: ks
            .iter()
            .map(|k| reference_mm + (k - r) as f64 * step)
            .collect(),
        down_um: up.iter().map(|u| u - b).collect(),
        up_um: up,
    }
}

/// HEIDENHAIN MANUALplus 620 `.COM` (Technical Manual pp. 716–718): AXISPOS, the axis column,
/// BACKLASH for the negative direction; values taken as the error (assumed, see the writer).
pub fn heidenhain(text: &str, axis: &str) -> Applied {
    let mut l = text.lines();
    assert_eq!(l.next(), Some(format!("BEGIN {axis}.COM MM").as_str()));
    let head: Vec<&str> = l.next().unwrap().split_whitespace().collect();
    assert_eq!(&head[..3], ["NR", "AXISPOS", axis]);
    let (mut p, mut e, mut b) = (vec![], vec![], vec![]);
    for (i, row) in l.take_while(|r| *r != "[END]").enumerate() {
        let f: Vec<f64> = row.split_whitespace().map(|x| x.parse().unwrap()).collect();
        assert_eq!(f[0] as usize, i);
        p.push(f[1]);
        e.push(-f[2] * 1e3);
        b.push(-f.get(3).copied().unwrap_or(f[2]) * 1e3);
    }
    Applied {
        points_mm: p,
        up_um: e,
        down_um: b,
    }
}
