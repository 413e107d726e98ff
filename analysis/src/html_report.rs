//! The positioning report a customer signs (`metrolog report`): one self-contained HTML file
//! (inline CSS and SVG, no scripts, no external resources) with the header (machine, axis,
//! instruments, operator, date, standard and edition, environment, material temperature and
//! α, compensation), the results by each standard asked for, the deviation chart with the
//! ±2 s bands and the results block, the drift-free chart (Stejskal et al. 2017), the
//! measurement uncertainty and the readings as data runs. `docs/datasets.md` lists the
//! metadata keys the header reads.

use std::fmt::Write as _;

use positioning::axis_model::Direction;
use positioning::positioning_data::PositioningData;
use positioning::standards::StandardResult;
use positioning::units::Units;

use crate::export::num;
use crate::positioning_report::{
    DECISION_RULE, PositioningAnalysis, lower_bound_note, origin_text, sensor_text,
};

/// What the header says; `None` prints "not stated".
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ReportHeader {
    pub machine: Option<String>,
    pub operator: Option<String>,
    pub date: Option<String>,
    /// Instruments and their serial numbers, e.g. "LI-80 interferometer s/n 1234".
    pub instruments: Vec<String>,
    /// "applied: …" or "none" — whether a compensation was active during the run.
    pub compensation: Option<String>,
    /// Air pressure and humidity, "min / mean / max" with units (a log's environment records).
    pub air_pressure: Option<String>,
    pub humidity: Option<String>,
    /// Identifies the report with its input: a hash of the input's bytes ([`report_id`]).
    pub report_id: Option<String>,
}

/// An `*IDN?` answer "maker,model,serial,firmware" in words; anything else as it is.
pub fn idn_text(idn: &str) -> String {
    let p: Vec<&str> = idn.split(',').map(str::trim).collect();
    match p.as_slice() {
        [maker, model, serial, fw, ..] if !serial.is_empty() => {
            format!("{maker} {model}, s/n {serial}, firmware {fw}")
        }
        _ => idn.to_string(),
    }
}

/// The report ID of an input: FNV-1a (64 bit, offset 0xcbf29ce484222325, prime 0x100000001b3)
/// of its bytes, 16 hex digits; fed in blocks (a log can be gigabytes). Not a cryptographic
/// hash: it names the input a report was made from (the same file gives the same ID, a changed
/// one another); it does not protect the file against a deliberate change.
#[derive(Debug, Clone, Copy)]
pub struct ReportId(u64);

impl Default for ReportId {
    fn default() -> Self {
        ReportId(0xcbf2_9ce4_8422_2325)
    }
}

impl ReportId {
    pub fn update(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 ^= u64::from(b);
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
    pub fn hex(&self) -> String {
        format!("{:016x}", self.0)
    }
}

impl ReportHeader {
    /// The header from the dataset's metadata: `machine`, `operator`, `date` (else a log's
    /// `start_time`, the run's start), the instruments (a log's `instrument.<name>` `*IDN?`
    /// identities; a CSV's keys starting with `instrument` or `serial`), `compensation`,
    /// `air_pressure_kpa` and `humidity_pct`.
    pub fn from_metadata(d: &PositioningData) -> ReportHeader {
        let m = &d.metadata;
        let mut instruments: Vec<String> = m
            .iter()
            .filter(|(k, _)| k.starts_with("instrument.") && !k.ends_with('.'))
            .map(|(k, v)| format!("{}: {}", &k["instrument.".len()..], idn_text(v)))
            .collect();
        instruments.extend(
            m.iter()
                .filter(|(k, _)| {
                    (k.starts_with("instrument") || k.starts_with("serial"))
                        && !k.starts_with("instrument.")
                        && k.as_str() != "instruments_configured"
                })
                .map(|(k, v)| format!("{}: {v}", k.replace('_', " "))),
        );
        if instruments.is_empty()
            && let Some(c) = m.get("instruments_configured")
        {
            instruments.push(format!(
                "{} (configured; no identity or serial recorded)",
                c.replace(',', ", ")
            ));
        }
        ReportHeader {
            machine: m.get("machine").cloned().filter(|v| !v.is_empty()),
            operator: m.get("operator").cloned(),
            date: m.get("date").cloned().or_else(|| {
                m.get("start_time")
                    .map(|t| format!("{t} (run start, from the log)"))
            }),
            instruments,
            compensation: m.get("compensation").cloned(),
            air_pressure: m.get("air_pressure_kpa").cloned(),
            humidity: m.get("humidity_pct").cloned(),
            report_id: None,
        }
    }
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

fn stated(v: &Option<String>) -> String {
    v.as_deref()
        .map(esc)
        .unwrap_or_else(|| "<i>not stated</i>".into())
}

fn recorded(v: &Option<String>) -> String {
    v.as_deref()
        .map(esc)
        .unwrap_or_else(|| "<i>not recorded</i>".into())
}

/// min / mean / max of some readings' values, °C.
fn temps(v: impl Iterator<Item = Option<f64>>) -> String {
    let v: Vec<f64> = v.flatten().collect();
    if v.is_empty() {
        return "<i>not recorded</i>".into();
    }
    let (lo, hi) = v
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
            (a.min(*x), b.max(*x))
        });
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    format!(
        "{} / {} / {} °C (min / mean / max)",
        num(lo, 2),
        num(mean, 2),
        num(hi, 2)
    )
}

/// One series of a chart.
pub(crate) enum Series<'a> {
    Points {
        xy: Vec<(f64, f64)>,
        color: &'a str,
        label: &'a str,
    },
    Line {
        xy: Vec<(f64, f64)>,
        color: &'a str,
        label: &'a str,
    },
    /// A band between lower and upper curves.
    Band {
        x: Vec<f64>,
        lo: Vec<f64>,
        hi: Vec<f64>,
        color: &'a str,
        label: &'a str,
    },
}

/// "Nice" tick step for a range.
fn tick_step(span: f64) -> f64 {
    let raw = span / 6.0;
    let p = 10f64.powf(raw.log10().floor());
    [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * p)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * p)
}

/// An SVG chart: plot area on the left, the results block (if any) to its right and the
/// legend below, so neither covers data; the y range is the data's with a 6 % margin.
pub(crate) fn svg_chart(
    title: &str,
    x_label: &str,
    series: &[Series],
    block: &[(String, String)],
) -> String {
    let (w, h, l, t, pw, ph) = (900.0, 440.0, 70.0, 30.0, 620.0, 320.0);
    let (x0, x1, y0, y1) = data_range(series);
    let px = |x: f64| l + (x - x0) / (x1 - x0) * pw;
    let py = |y: f64| t + ph - (y - y0) / (y1 - y0) * ph;
    let mut s = format!(
        r#"<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {w} {h}" width="{w}" height="{h}" font-family="sans-serif" font-size="12"><title>{}</title>"#,
        esc(title)
    );
    let _ = write!(
        s,
        r##"<rect x="{l}" y="{t}" width="{pw}" height="{ph}" fill="#fff" stroke="#444"/>"##
    );
    for (step, vertical) in [(tick_step(x1 - x0), true), (tick_step(y1 - y0), false)] {
        let (a, b) = if vertical { (x0, x1) } else { (y0, y1) };
        let mut v = (a / step).ceil() * step;
        while v <= b {
            let label = num(
                v,
                if step < 1.0 {
                    (-step.log10() - 1e-9).ceil() as usize
                } else {
                    0
                },
            );
            if vertical {
                let _ = write!(
                    s,
                    r##"<line x1="{0:.1}" y1="{t}" x2="{0:.1}" y2="{1}" stroke="#ddd"/><text x="{0:.1}" y="{2}" text-anchor="middle">{label}</text>"##,
                    px(v),
                    t + ph,
                    t + ph + 16.0
                );
            } else {
                let _ = write!(
                    s,
                    r##"<line x1="{l}" y1="{0:.1}" x2="{1}" y2="{0:.1}" stroke="#ddd"/><text x="{2}" y="{3:.1}" text-anchor="end">{label}</text>"##,
                    py(v),
                    l + pw,
                    l - 6.0,
                    py(v) + 4.0
                );
            }
            v += step;
        }
    }
    let _ = write!(
        s,
        r#"<text x="{}" y="{}" text-anchor="middle">{}</text><text transform="translate(16,{}) rotate(-90)" text-anchor="middle">deviation (µm)</text><text x="{l}" y="18" font-weight="bold">{}</text>"#,
        l + pw / 2.0,
        t + ph + 34.0,
        esc(x_label),
        t + ph / 2.0,
        esc(title)
    );
    let mut legend = Vec::new();
    for se in series {
        match se {
            Series::Band {
                x,
                lo,
                hi,
                color,
                label,
            } => {
                let pts: Vec<String> = x
                    .iter()
                    .zip(hi)
                    .chain(x.iter().zip(lo).rev())
                    .map(|(a, b)| format!("{:.1},{:.1}", px(*a), py(*b)))
                    .collect();
                let _ = write!(
                    s,
                    r#"<polygon points="{}" fill="{color}" fill-opacity="0.18" stroke="{color}" stroke-opacity="0.5" stroke-dasharray="4 3"/>"#,
                    pts.join(" ")
                );
                legend.push((*color, *label, "band"));
            }
            Series::Line { xy, color, label } => {
                let pts: Vec<String> = xy
                    .iter()
                    .map(|(a, b)| format!("{:.1},{:.1}", px(*a), py(*b)))
                    .collect();
                let _ = write!(
                    s,
                    r#"<polyline points="{}" fill="none" stroke="{color}" stroke-width="2"/>"#,
                    pts.join(" ")
                );
                legend.push((*color, *label, "line"));
            }
            Series::Points { xy, color, label } => {
                for (a, b) in xy {
                    let _ = write!(
                        s,
                        r#"<circle cx="{:.1}" cy="{:.1}" r="2.6" fill="{color}" fill-opacity="0.75"/>"#,
                        px(*a),
                        py(*b)
                    );
                }
                legend.push((*color, *label, "dot"));
            }
        }
    }
    write_legend(&mut s, &legend, (l, t + ph));
    write_results_block(&mut s, block, (l + pw + 20.0, t));
    s.push_str("</svg>");
    s
}

/// The x and y range of all series (finite values only), with margins of 3 % and 6 %.
fn data_range(series: &[Series]) -> (f64, f64, f64, f64) {
    let mut xs = Vec::new();
    let mut ys = Vec::new();
    for s in series {
        match s {
            Series::Points { xy, .. } | Series::Line { xy, .. } => {
                xs.extend(xy.iter().map(|p| p.0));
                ys.extend(xy.iter().map(|p| p.1));
            }
            Series::Band { x, lo, hi, .. } => {
                xs.extend(x);
                ys.extend(lo.iter().chain(hi));
            }
        }
    }
    let fin = |v: &[f64]| {
        v.iter()
            .copied()
            .filter(|x| x.is_finite())
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
                (a.min(x), b.max(x))
            })
    };
    let (mut x0, mut x1) = fin(&xs);
    let (mut y0, mut y1) = fin(&ys);
    if !(x0.is_finite() && y0.is_finite()) {
        (x0, x1, y0, y1) = (0.0, 1.0, -1.0, 1.0);
    }
    if x1 - x0 < 1e-9 {
        x1 = x0 + 1.0;
    }
    if y1 - y0 < 1e-9 {
        y0 -= 0.5;
        y1 += 0.5;
    }
    let (mx, my) = (0.03 * (x1 - x0), 0.06 * (y1 - y0));
    (x0 - mx, x1 + mx, y0 - my, y1 + my)
}

/// The legend below the plot area (`(l, bottom)`: its left edge and the plot's bottom).
fn write_legend(s: &mut String, legend: &[(&str, &str, &str)], (l, bottom): (f64, f64)) {
    for (i, (color, label, kind)) in legend.iter().enumerate() {
        let (lx, ly) = (
            l + (i % 3) as f64 * 210.0,
            bottom + 52.0 + (i / 3) as f64 * 16.0,
        );
        let mark = match *kind {
            "dot" => format!(
                r#"<circle cx="{}" cy="{}" r="3" fill="{color}"/>"#,
                lx + 8.0,
                ly - 4.0
            ),
            "band" => format!(
                r#"<rect x="{lx}" y="{}" width="16" height="8" fill="{color}" fill-opacity="0.3"/>"#,
                ly - 8.0
            ),
            _ => format!(
                r#"<line x1="{lx}" y1="{0}" x2="{1}" y2="{0}" stroke="{color}" stroke-width="2"/>"#,
                ly - 4.0,
                lx + 16.0
            ),
        };
        let _ = write!(
            s,
            r#"{mark}<text x="{}" y="{ly}">{}</text>"#,
            lx + 22.0,
            esc(label)
        );
    }
}

/// The results block right of the plot area, at `(bx, t)`.
fn write_results_block(s: &mut String, block: &[(String, String)], (bx, t): (f64, f64)) {
    if !block.is_empty() {
        let _ = write!(
            s,
            r##"<rect x="{bx}" y="{t}" width="180" height="{}" fill="#f7f7f7" stroke="#888"/><text x="{}" y="{}" font-weight="bold">Results</text>"##,
            26.0 + 18.0 * block.len() as f64,
            bx + 10.0,
            t + 18.0
        );
        for (i, (k, v)) in block.iter().enumerate() {
            let y = t + 38.0 + 18.0 * i as f64;
            let _ = write!(
                s,
                r#"<text x="{}" y="{y}" class="res">{}</text><text x="{}" y="{y}" text-anchor="end" class="res">{} µm</text>"#,
                bx + 10.0,
                esc(k),
                bx + 170.0,
                esc(v)
            );
        }
    }
}

const UP: &str = "#1f5fbf";
const DOWN: &str = "#c0392b";

/// The deviation chart: readings, mean deviations x̄↑ x̄↓ and their x̄ ± 2s bands, with the
/// ISO 230-2 results block (A, E, R, B, M).
fn deviation_chart(data: &PositioningData, an: &PositioningAnalysis) -> String {
    let mut series = Vec::new();
    for (dir, color, name) in [(Direction::Up, UP, "+"), (Direction::Down, DOWN, "−")] {
        let xy: Vec<(f64, f64)> = data
            .readings
            .iter()
            .filter(|r| r.direction == dir)
            .map(|r| (r.target_mm, r.deviation_um))
            .collect();
        let stats: Vec<(f64, f64, f64)> = an
            .targets
            .iter()
            .filter_map(|t| {
                let (m, s) = if dir == Direction::Up {
                    (t.mean_up_um, t.s_up_um)
                } else {
                    (t.mean_down_um, t.s_down_um)
                };
                Some((t.target_mm, m?, s.unwrap_or(0.0)))
            })
            .collect();
        let (band_label, mean_label, pts_label) = match name {
            "+" => ("x̄↑ ± 2s↑", "mean x̄↑", "readings +"),
            _ => ("x̄↓ ± 2s↓", "mean x̄↓", "readings −"),
        };
        series.push(Series::Band {
            x: stats.iter().map(|s| s.0).collect(),
            lo: stats.iter().map(|s| s.1 - 2.0 * s.2).collect(),
            hi: stats.iter().map(|s| s.1 + 2.0 * s.2).collect(),
            color,
            label: band_label,
        });
        series.push(Series::Line {
            xy: stats.iter().map(|s| (s.0, s.1)).collect(),
            color,
            label: mean_label,
        });
        series.push(Series::Points {
            xy,
            color,
            label: pts_label,
        });
    }
    let block: Vec<(String, String)> = an
        .results_block()
        .into_iter()
        .map(|r| (r.symbol.to_string(), r.value))
        .collect();
    svg_chart(
        "Positional deviation (ISO 230-2)",
        "target (mm)",
        &series,
        &block,
    )
}

/// The drift-free chart: deviations rebuilt from adjacent-target differences with their
/// ±k·s_diff borders, per direction.
fn drift_chart(an: &PositioningAnalysis) -> String {
    let mut series = Vec::new();
    for d in &an.drift_elimination.directions {
        let (color, band, line) = if d.direction == Direction::Up {
            (UP, "border + (±k·s_diff)", "drift-free +")
        } else {
            (DOWN, "border − (±k·s_diff)", "drift-free −")
        };
        let pts: Vec<(f64, f64, f64)> = d
            .chart
            .iter()
            .filter_map(|c| Some((c.target_mm, c.deviation_um?, c.border_um.unwrap_or(0.0))))
            .collect();
        series.push(Series::Band {
            x: pts.iter().map(|p| p.0).collect(),
            lo: pts.iter().map(|p| p.1 - p.2).collect(),
            hi: pts.iter().map(|p| p.1 + p.2).collect(),
            color,
            label: band,
        });
        series.push(Series::Line {
            xy: pts.iter().map(|p| (p.0, p.1)).collect(),
            color,
            label: line,
        });
    }
    svg_chart(
        "Drift-free deviation (Stejskal et al. 2017)",
        "target (mm)",
        &series,
        &[],
    )
}

fn standards_tables(standards: &[StandardResult]) -> String {
    let mut s = String::new();
    for r in standards {
        let _ = write!(
            s,
            "<h3>{} <small>(bands {})</small></h3><table class=\"res\"><tr><th>symbol</th><th>parameter</th><th>value (µm)</th></tr>",
            esc(&r.designation),
            esc(&r.coverage)
        );
        for p in &r.parameters {
            let v = p.value_um.map(|v| num(v, 2)).unwrap_or_else(|| "—".into());
            let _ = write!(
                s,
                "<tr><td>{}</td><td>{}</td><td class=\"n\" data-symbol=\"{}\">{v}</td></tr>",
                esc(&p.symbol),
                esc(&p.name),
                esc(&p.symbol)
            );
        }
        s.push_str("</table>");
        for n in &r.notes {
            let _ = write!(s, "<p class=\"note\">{}</p>", esc(n));
        }
    }
    s
}

/// The ISO 230-2 statistics per target: x̄↑, x̄↓, s↑, s↓, B_i, R_i, x̄_i.
fn target_table(an: &PositioningAnalysis) -> String {
    let mut s = String::from(
        "<table class=\"res targets\"><tr><th>i</th><th>target (mm)</th><th>n↑</th><th>n↓</th><th>x̄↑ (µm)</th><th>x̄↓ (µm)</th><th>s↑ (µm)</th><th>s↓ (µm)</th><th>B_i (µm)</th><th>R_i (µm)</th><th>x̄_i (µm)</th></tr>",
    );
    let o = |v: Option<f64>| v.map(|v| num(v, 2)).unwrap_or_else(|| "—".into());
    for t in &an.targets {
        let _ = write!(
            s,
            "<tr><td>{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td></tr>",
            t.index,
            num(t.target_mm, 3),
            t.n_up,
            t.n_down,
            o(t.mean_up_um),
            o(t.mean_down_um),
            o(t.s_up_um),
            o(t.s_down_um),
            o(t.b_um),
            o(t.r_um),
            o(t.mean_um)
        );
    }
    s.push_str("</table>");
    s
}

/// The readings as data runs: one row per target, one column per (cycle, direction).
fn readings_table(data: &PositioningData) -> String {
    let g = data.grid();
    let t = data.targets_mm();
    let mut s = String::from("<table class=\"runs\"><tr><th>target (mm)</th>");
    for c in 1..=data.n_cycles() {
        let _ = write!(s, "<th>{c}↑</th><th>{c}↓</th>");
    }
    s.push_str("</tr>");
    for (i, tm) in t.iter().enumerate() {
        let _ = write!(s, "<tr><td>{}</td>", num(*tm, 3));
        for c in 0..data.n_cycles() {
            for d in &g {
                let v = d[i][c].map(|v| num(v, 2)).unwrap_or_else(|| "—".into());
                let _ = write!(s, "<td class=\"n\">{v}</td>");
            }
        }
        s.push_str("</tr>");
    }
    s.push_str("</table><p class=\"note\">deviations in µm (actual − target)</p>");
    s
}

/// The budget of the results: one row per contributor (its u, status and source), then U of
/// each result, the lower-bound sentence when terms are missing, and the decisions.
fn uncertainty_section(an: &PositioningAnalysis) -> String {
    let u = &an.uncertainty;
    let mut s = format!(
        "<p>Uncertainty of the results by the contributors of ISO 230-2:2014 Annex A / ISO/TR \
         230-9 (GUM combination, docs/methods.md); sensor: <b>{}</b>; measured length L = {} \
         mm. Each term is <i>recorded</i> by the run, <i>assumed</i> (value and source given) or \
         <i>missing</i>.</p><table class=\"res budget\"><tr><th>term</th><th>what</th>\
         <th>u (µm)</th><th>status</th><th>source</th></tr>",
        esc(&sensor_text(&u.sensor)),
        num(u.length_mm, 3)
    );
    for c in &u.contributors {
        let (status, note) = origin_text(&c.origin);
        let _ = write!(
            s,
            "<tr class=\"{}\"><td>{}</td><td>{}</td><td class=\"n\">{}</td><td>{status}</td><td>{}</td></tr>",
            status.replace(' ', "-").to_lowercase(),
            esc(&c.symbol),
            esc(&c.description),
            c.u_um.map(|v| num(v, 3)).unwrap_or_else(|| "—".into()),
            esc(note)
        );
    }
    s.push_str("</table><table class=\"res\"><tr><th>result</th><th>value (µm)</th><th>u (µm)</th><th>U, k = 2 (µm)</th><th>terms in U</th><th>missing</th></tr>");
    for r in &u.results {
        let terms: Vec<String> = r
            .contributions
            .iter()
            .map(|(k, v)| format!("{k} {}", num(*v, 3)))
            .collect();
        let _ = write!(
            s,
            "<tr><td>{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"n\" data-u=\"{}\">{}{}</td><td class=\"small\">{}</td><td>{}</td></tr>",
            esc(&r.parameter),
            r.value_um.map(|v| num(v, 2)).unwrap_or_else(|| "—".into()),
            num(r.u_um, 3),
            esc(&r.parameter),
            if r.missing.is_empty() { "" } else { "≥ " },
            num(r.expanded_um, 3),
            esc(&terms.join(", ")),
            if r.missing.is_empty() {
                "none".into()
            } else {
                esc(&r.missing.join(", "))
            }
        );
    }
    s.push_str("</table>");
    if let Some(n) = lower_bound_note(u) {
        let _ = write!(s, "<p class=\"lower\"><b>{}</b></p>", esc(&n));
    }
    s
}

/// The ISO 14253-1 decisions under the tolerances given, with the rule.
fn conformance_section(an: &PositioningAnalysis) -> String {
    if an.conformance.is_empty() {
        return "<p>No tolerance given (<code>--tolerance E=…</code>): no conformance decision.</p>"
            .into();
    }
    let mut s = format!(
        "<p>Decision rule: {}.</p><table class=\"res\"><tr><th>result</th><th>value (µm)</th><th>tolerance (µm)</th><th>U, k = 2 (µm)</th><th>decision</th><th>why</th></tr>",
        esc(DECISION_RULE)
    );
    for c in &an.conformance {
        let (v, u, label) = match &c.decision {
            Some(d) => (
                num(d.value, 2),
                num(d.expanded_uncertainty, 3),
                d.decision.label(),
            ),
            None => ("—".into(), "—".into(), "no decision"),
        };
        let _ = write!(
            s,
            "<tr><td>{}</td><td class=\"n\">{v}</td><td class=\"n\">{}</td><td class=\"n\">{u}</td><td class=\"decision {}\" data-decision=\"{}\"><b>{}</b></td><td>{}</td></tr>",
            esc(&c.parameter),
            num(c.tolerance_um, 3),
            label.replace(' ', "-"),
            esc(&c.parameter),
            label.to_uppercase(),
            esc(&c.reason)
        );
    }
    s.push_str("</table>");
    s
}

fn header_table(
    data: &PositioningData,
    an: &PositioningAnalysis,
    standards: &[StandardResult],
    h: &ReportHeader,
) -> String {
    let designations: Vec<String> = standards.iter().map(|r| r.designation.clone()).collect();
    let alpha = data
        .alpha_um_per_m_k
        .map(|a| format!("{} µm/(m·K)", num(a, 2)))
        .unwrap_or_else(|| "<i>not stated</i>".into());
    // Normalised to 20 °C only means something with a material temperature to normalise from.
    let has_material = data.readings.iter().any(|r| r.material_c.is_some());
    let norm = match (data.material_compensation, has_material) {
        (true, true) => "readings normalised to 20 °C from the material temperature",
        (true, false) => "no material temperature recorded: normalisation to 20 °C not shown",
        (false, _) => "readings NOT normalised to 20 °C",
    };
    let rows = [
        ("Report ID", stated(&h.report_id)),
        ("Machine", stated(&h.machine)),
        ("Axis", stated(&an.axis)),
        (
            "Instruments",
            if h.instruments.is_empty() {
                "<i>not stated</i>".into()
            } else {
                esc(&h.instruments.join("; "))
            },
        ),
        ("Sensor", esc(&sensor_text(&an.uncertainty.sensor))),
        ("Operator", stated(&h.operator)),
        ("Date", stated(&h.date)),
        ("Standard", esc(&designations.join(", "))),
        (
            "Test",
            format!(
                "{} targets × {} bidirectional cycles",
                an.n_targets, an.n_cycles
            ),
        ),
        (
            "Air temperature",
            temps(data.readings.iter().map(|r| r.air_c)),
        ),
        ("Air pressure", recorded(&h.air_pressure)),
        ("Air humidity", recorded(&h.humidity)),
        (
            "Material temperature",
            temps(data.readings.iter().map(|r| r.material_c)),
        ),
        ("Expansion coefficient α", format!("{alpha}; {norm}")),
        (
            "Compensation during the run",
            h.compensation
                .as_deref()
                .map(esc)
                .unwrap_or_else(|| "<i>not stated</i>".into()),
        ),
    ];
    let mut s = String::from("<table class=\"head\">");
    for (k, v) in rows {
        let _ = write!(s, "<tr><th>{k}</th><td>{v}</td></tr>");
    }
    s.push_str("</table>");
    s
}

const STYLE: &str = "body{font-family:sans-serif;margin:24px;color:#222;max-width:1000px}h1{font-size:22px}h2{font-size:18px;border-bottom:1px solid #aaa;margin-top:28px}h3{font-size:15px}table{border-collapse:collapse;margin:6px 0}td,th{border:1px solid #bbb;padding:3px 8px;font-size:13px}th{background:#eee;text-align:left}td.n{text-align:right;font-variant-numeric:tabular-nums}.note{font-size:12px;color:#555}table.runs td,table.runs th{font-size:11px;padding:2px 4px}.sign td{height:40px;width:200px}.sign td.sig{width:300px}tr.missing td{color:#a00}.lower{color:#a00}td.decision.pass{background:#d8f0d8}td.decision.fail{background:#f5d0d0}td.decision.not-decidable{background:#f7ecc8}td.small{font-size:11px}svg{max-width:100%;height:auto}@page{size:A4;margin:14mm 12mm}@page runs{size:A4 landscape}@media print{body{margin:0;max-width:none}h2,h3{break-after:avoid}svg,table.head,table.res,tr,section.keep{break-inside:avoid}section.runs{page:runs}table.runs td,table.runs th{font-size:9px;padding:1px 3px}}";

/// The whole report.
pub fn positioning_html(
    data: &PositioningData,
    an: &PositioningAnalysis,
    standards: &[StandardResult],
    h: &ReportHeader,
) -> String {
    // Page margin boxes: the report ID and "page n of N" on every printed page.
    let id = h
        .report_id
        .as_deref()
        .unwrap_or("")
        .replace(['"', '\\'], "");
    let mut s = format!(
        "<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>Positioning test, axis {}</title><style>{STYLE}@page{{@bottom-left{{content:\"report {id}\";font-size:9px;color:#555}}@bottom-right{{content:\"page \" counter(page) \" of \" counter(pages);font-size:9px;color:#555}}}}</style></head><body>",
        esc(an.axis.as_deref().unwrap_or("?"))
    );
    let _ = write!(
        s,
        "<h1>Positioning accuracy and repeatability, axis {}</h1>",
        esc(an.axis.as_deref().unwrap_or("?"))
    );
    // A report built on a damaged log says so before any result.
    if let Some(d) = &an.log_damage {
        let _ = write!(
            s,
            "<p class=\"lower\"><b>Built on part of the run:</b> the log is damaged: {}; the \
             results use the readings before the damage only.</p>",
            esc(d)
        );
    }
    s.push_str(&header_table(data, an, standards, h));
    s.push_str("<h2>Results</h2>");
    s.push_str(&standards_tables(standards));
    s.push_str("<h2>Statistics per target</h2>");
    s.push_str(&target_table(an));
    s.push_str("<h2>Deviation chart</h2>");
    s.push_str(&deviation_chart(data, an));
    s.push_str("<h2>Drift-free chart</h2><p class=\"note\">Thermal drift between cycles removed with adjacent-target differences (docs/methods.md, paper 000).</p>");
    s.push_str(&drift_chart(an));
    // One block: its heading is not left alone at the foot of a printed page.
    s.push_str("<section class=\"keep\"><h2>Measurement uncertainty</h2>");
    s.push_str(&uncertainty_section(an));
    s.push_str("</section><section class=\"keep\"><h2>Conformance (ISO 14253-1)</h2>");
    s.push_str(&conformance_section(an));
    s.push_str("</section>");
    for n in an.notes.iter().chain(&an.drift_elimination.notes) {
        let _ = write!(s, "<p class=\"note\">{}</p>", esc(n));
    }
    // Its own section: printed on landscape pages (the runs table is wide), see STYLE.
    s.push_str("<section class=\"runs\"><h2>Readings</h2>");
    s.push_str(&readings_table(data));
    s.push_str("<h2>Signatures</h2><table class=\"sign\"><tr><th></th><th>name</th><th>date</th><th>signature</th></tr>");
    for role in ["Measured by", "Accepted by"] {
        let name = if role == "Measured by" {
            h.operator.as_deref().map(esc).unwrap_or_default()
        } else {
            String::new()
        };
        let _ = write!(
            s,
            "<tr><th>{role}</th><td class=\"name\">{name}</td><td class=\"date\"></td><td class=\"sig\"></td></tr>"
        );
    }
    s.push_str("</table>");
    let _ = writeln!(
        s,
        "<p class=\"note\">Written by metrolog report{}.</p></section></body></html>",
        h.report_id
            .as_deref()
            .map(|id| format!(", report ID {}", esc(id)))
            .unwrap_or_default()
    );
    relabel_body(&s, &data.units())
}

/// The page with the body's mm and µm named in the dataset's units (a rotary axis: deg and
/// mdeg), and a note saying so; the style sheet (its page margins in mm) is left alone.
fn relabel_body(page: &str, u: &Units) -> String {
    let Some(note) = u.note() else {
        return page.to_string();
    };
    let (head, body) = page.split_at(page.find("</head>").unwrap_or(0));
    let body = u.relabel(body).replacen(
        "<h2>Results</h2>",
        &format!("<p class=\"note\">{}.</p><h2>Results</h2>", esc(&note)),
        1,
    );
    format!("{head}{body}")
}
