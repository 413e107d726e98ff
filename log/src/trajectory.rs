//! The trajectory (pose table) of a run: `pose,x_mm,y_mm,z_mm[,a_deg,c_deg]`, poses numbered
//! 1, 2, 3, … in order (`docs/instruments.md` §5, `docs/datasets.md`). The service reads it
//! from its config, stores it in the log as [`crate::TRAJECTORY_ATTACHMENT`], and the analyses
//! read it back from there: this module is the one parser and writer of the format.

/// One programmed pose of the trajectory.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct TrajectoryRow {
    pub pose: u32,
    pub x_mm: f64,
    pub y_mm: f64,
    pub z_mm: f64,
    pub a_deg: Option<f64>,
    pub c_deg: Option<f64>,
}

/// Parses the trajectory CSV; the error says which line and what is wrong.
pub fn parse_trajectory(text: &str) -> Result<Vec<TrajectoryRow>, String> {
    let mut rdr = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .comment(Some(b'#'))
        .from_reader(text.as_bytes());
    let headers = rdr
        .headers()
        .map_err(|e| format!("bad header: {e}"))?
        .clone();
    let h: Vec<&str> = headers.iter().collect();
    let rotary = match h.as_slice() {
        ["pose", "x_mm", "y_mm", "z_mm"] => false,
        ["pose", "x_mm", "y_mm", "z_mm", "a_deg", "c_deg"] => true,
        _ => {
            return Err(format!(
                "header is {h:?}; expected pose,x_mm,y_mm,z_mm or pose,x_mm,y_mm,z_mm,a_deg,c_deg"
            ));
        }
    };
    let mut rows: Vec<TrajectoryRow> = Vec::new();
    for rec in rdr.records() {
        let rec = rec.map_err(|e| format!("{e}"))?;
        let expected = rows.last().map_or(1, |r| r.pose + 1);
        rows.push(parse_row(&rec, &h, rotary, expected)?);
    }
    if rows.is_empty() {
        return Err("has no poses".into());
    }
    Ok(rows)
}

fn parse_row(
    rec: &csv::StringRecord,
    h: &[&str],
    rotary: bool,
    expected: u32,
) -> Result<TrajectoryRow, String> {
    let line = rec.position().map_or(0, |p| p.line());
    let num = |i: usize| -> Result<f64, String> {
        let s = rec.get(i).unwrap_or("");
        s.parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| format!("line {line}: {} = {s:?} is not a finite number", h[i]))
    };
    let pose: u32 = rec.get(0).unwrap_or("").parse().map_err(|_| {
        format!(
            "line {line}: pose {:?} is not a whole number",
            rec.get(0).unwrap_or("")
        )
    })?;
    if pose != expected {
        return Err(format!(
            "line {line}: pose {pose} should be {expected} (poses count up from 1)"
        ));
    }
    Ok(TrajectoryRow {
        pose,
        x_mm: num(1)?,
        y_mm: num(2)?,
        z_mm: num(3)?,
        a_deg: if rotary { Some(num(4)?) } else { None },
        c_deg: if rotary { Some(num(5)?) } else { None },
    })
}

/// Writes rows in the format [`parse_trajectory`] reads (six columns when any row has A and C).
pub fn write_trajectory(rows: &[TrajectoryRow]) -> String {
    let rotary = rows.iter().any(|r| r.a_deg.is_some() || r.c_deg.is_some());
    let mut s = String::from(if rotary {
        "pose,x_mm,y_mm,z_mm,a_deg,c_deg\n"
    } else {
        "pose,x_mm,y_mm,z_mm\n"
    });
    for r in rows {
        s.push_str(&format!(
            "{},{:.6},{:.6},{:.6}",
            r.pose, r.x_mm, r.y_mm, r.z_mm
        ));
        if rotary {
            let (a, c) = (r.a_deg.unwrap_or(0.0), r.c_deg.unwrap_or(0.0));
            s.push_str(&format!(",{a:.6},{c:.6}"));
        }
        s.push('\n');
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_with_rotary_axes() {
        let rows: Vec<TrajectoryRow> = (1..=5)
            .map(|k| TrajectoryRow {
                pose: k,
                x_mm: 1.5 * f64::from(k),
                y_mm: -2.0,
                z_mm: 0.25,
                a_deg: Some(-90.0 + f64::from(k)),
                c_deg: Some(72.0 * f64::from(k)),
            })
            .collect();
        assert_eq!(parse_trajectory(&write_trajectory(&rows)).unwrap(), rows);
    }

    #[test]
    fn refuses_poses_out_of_order() {
        let e = parse_trajectory("pose,x_mm,y_mm,z_mm\n2,0,0,0\n").unwrap_err();
        assert!(e.contains("should be 1"), "{e}");
    }

    #[test]
    fn refuses_unknown_header_and_bad_numbers() {
        assert!(parse_trajectory("pose,x,y,z\n1,0,0,0\n").is_err());
        let e = parse_trajectory("pose,x_mm,y_mm,z_mm\n1,0,nan,0\n").unwrap_err();
        assert!(e.contains("y_mm"), "{e}");
        assert!(parse_trajectory("pose,x_mm,y_mm,z_mm\n").is_err());
    }
}
