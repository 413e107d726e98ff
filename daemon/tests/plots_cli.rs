//! The `--plot` charts read back the way a viewer sees them, not through our chart code: the
//! SVG is taken apart with regular expressions (its `<text>`, `<rect>` and `<circle>`
//! elements), and what a metrologist checks on a CARTO-style chart is asserted on that: the
//! results block A, E, R, B, M carries the numbers of the analysis JSON, every reading is
//! plotted, the legend box covers no plotted point, the data fill at least half of each chart's
//! y range, and no text reads "-0", "-0.0" or "-0.00". The PNGs are kept in the target
//! directory for a look. Charts are a build feature: run with `--features plot` (CI does).

use std::path::PathBuf;

use regex::Regex;

const PSI: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../positioning/tests/data/psi_ecmc_iso230.csv"
);
const ESS_B02: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../positioning/tests/data/real/ess_target_b02_x.csv"
);

mod cli_common;
use cli_common::metrolog;

#[derive(Debug, Clone)]
struct Txt {
    x: f64,
    y: f64,
    s: String,
}

#[derive(Debug, Clone, Copy)]
struct Rect {
    x: f64,
    y: f64,
    w: f64,
    h: f64,
}

impl Rect {
    fn contains(&self, x: f64, y: f64) -> bool {
        x > self.x && x < self.x + self.w && y > self.y && y < self.y + self.h
    }
}

#[derive(Debug, Clone, Copy)]
struct Dot {
    x: f64,
    y: f64,
    r: f64,
}

/// A polyline: its vertices and whether its stroke has a colour (grid and axes are grey).
#[derive(Debug, Clone)]
struct Line {
    points: Vec<(f64, f64)>,
    coloured: bool,
}

/// The texts, rectangles, circles and polylines of an SVG file.
struct Svg {
    texts: Vec<Txt>,
    rects: Vec<Rect>,
    dots: Vec<Dot>,
    lines: Vec<Line>,
}

fn span(v: impl Iterator<Item = f64>) -> f64 {
    let (lo, hi) = v.fold((f64::INFINITY, f64::NEG_INFINITY), |a, y| {
        (a.0.min(y), a.1.max(y))
    });
    hi - lo
}

fn polyline(tag: &str) -> Line {
    let stroke =
        Regex::new(r##"stroke="#([0-9A-Fa-f]{2})([0-9A-Fa-f]{2})([0-9A-Fa-f]{2})""##).unwrap();
    let coloured = stroke.captures(tag).is_some_and(|c| {
        let v: Vec<u8> = (1..4)
            .map(|i| u8::from_str_radix(&c[i], 16).unwrap())
            .collect();
        v.iter().max().unwrap() - v.iter().min().unwrap() > 40
    });
    let pts = Regex::new(r#"points="([^"]*)""#).unwrap();
    let points = pts
        .captures(tag)
        .map(|c| {
            c[1].split_whitespace()
                .filter_map(|p| {
                    let (x, y) = p.split_once(',')?;
                    Some((x.parse().ok()?, y.parse().ok()?))
                })
                .collect()
        })
        .unwrap_or_default();
    Line { points, coloured }
}

fn attr(tag: &str, name: &str) -> Option<f64> {
    let re = Regex::new(&format!(r#"\s{name}="([^"]*)""#)).unwrap();
    re.captures(tag)?.get(1)?.as_str().parse().ok()
}

fn parse(svg: &str) -> Svg {
    let text = Regex::new(r"(?s)<text([^>]*)>([^<]*)</text>").unwrap();
    let rect = Regex::new(r"<rect([^>]*)/>").unwrap();
    let circle = Regex::new(r"<circle([^>]*)/>").unwrap();
    let line = Regex::new(r"<polyline([^>]*)/>").unwrap();
    let unescape = |s: &str| {
        s.replace("&lt;", "<")
            .replace("&gt;", ">")
            .replace("&quot;", "\"")
            .replace("&amp;", "&")
    };
    Svg {
        texts: text
            .captures_iter(svg)
            .map(|c| Txt {
                x: attr(&c[1], "x").unwrap(),
                y: attr(&c[1], "y").unwrap(),
                s: unescape(c[2].trim()),
            })
            .collect(),
        rects: rect
            .captures_iter(svg)
            .map(|c| Rect {
                x: attr(&c[1], "x").unwrap(),
                y: attr(&c[1], "y").unwrap(),
                w: attr(&c[1], "width").unwrap(),
                h: attr(&c[1], "height").unwrap(),
            })
            .collect(),
        dots: circle
            .captures_iter(svg)
            .map(|c| Dot {
                x: attr(&c[1], "cx").unwrap(),
                y: attr(&c[1], "cy").unwrap(),
                r: attr(&c[1], "r").unwrap(),
            })
            .collect(),
        lines: line.captures_iter(svg).map(|c| polyline(&c[1])).collect(),
    }
}

/// No "-0", "-0.0", "-0.00" … as a number of its own anywhere in the text.
fn assert_no_negative_zero(svg: &Svg, what: &str) {
    let nz = Regex::new(r"(^|[^0-9.])[-−]0(\.0*)?([^0-9.]|$)").unwrap();
    for t in &svg.texts {
        assert!(!nz.is_match(&t.s), "{what}: negative zero in {:?}", t.s);
    }
}

/// The plot areas: the large framed rectangles that hold plotted points and no text (the
/// background and the legend boxes hold text; tick labels are outside the plot area).
fn plot_frames(svg: &Svg) -> Vec<(Rect, Vec<Dot>)> {
    svg.rects
        .iter()
        .filter(|r| r.w > 250.0 && r.h > 150.0)
        .filter(|r| !svg.texts.iter().any(|t| r.contains(t.x, t.y)))
        .map(|r| {
            let inside = svg
                .dots
                .iter()
                .filter(|d| r.contains(d.x, d.y))
                .copied()
                .collect::<Vec<_>>();
            (*r, inside)
        })
        .filter(|(_, d)| d.len() >= 3)
        .collect()
}

/// The boxes that hold the given legend labels: the smallest rectangle round each label.
fn legend_boxes(svg: &Svg, labels: &[&str]) -> Vec<Rect> {
    let mut boxes: Vec<Rect> = Vec::new();
    for l in labels {
        let t = svg
            .texts
            .iter()
            .find(|t| t.s == *l)
            .unwrap_or_else(|| panic!("legend label {l:?} not in the chart"));
        let b = svg
            .rects
            .iter()
            .filter(|r| r.contains(t.x, t.y + 5.0))
            .min_by(|a, b| (a.w * a.h).total_cmp(&(b.w * b.h)))
            .unwrap_or_else(|| panic!("legend label {l:?} has no box"));
        boxes.push(*b);
    }
    boxes
}

/// The value printed right of a results-block row whose label starts with `symbol` and a
/// space, on the same line.
fn block_value(svg: &Svg, symbol: &str) -> f64 {
    let rows: Vec<&Txt> = svg
        .texts
        .iter()
        .filter(|t| t.s.starts_with(&format!("{symbol} ")))
        .collect();
    assert_eq!(rows.len(), 1, "one row {symbol} in the results block");
    let row = rows[0];
    let value = svg
        .texts
        .iter()
        .find(|t| (t.y - row.y).abs() < 1.0 && t.x > row.x && t.s.ends_with(" µm"))
        .unwrap_or_else(|| panic!("no value beside {:?}", row.s));
    value.s.trim_end_matches(" µm").parse().unwrap()
}

fn kept(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(name)
}

/// Draws a run's charts as SVG and PNG and checks what a metrologist checks.
fn check_positioning_chart(run: &str, name: &str) {
    let json: serde_json::Value =
        serde_json::from_str(&metrolog(&["analyze", "positioning", run, "--json"])).unwrap();
    let svg_path = kept(&format!("{name}.svg"));
    let png_path = kept(&format!("{name}.png"));
    for p in [&svg_path, &png_path] {
        metrolog(&["analyze", "positioning", run, "--plot", p.to_str().unwrap()]);
    }
    assert!(std::fs::read(&png_path).unwrap().starts_with(b"\x89PNG"));
    let svg = parse(&std::fs::read_to_string(&svg_path).unwrap());
    assert_no_negative_zero(&svg, name);

    // The results block carries the analysis's numbers (two decimals).
    for s in ["A", "E", "R", "B", "M"] {
        let want = json["iso230_2"][s].as_f64().unwrap();
        let got = block_value(&svg, s);
        assert!(
            (got - want).abs() <= 0.005 + 1e-9,
            "{name}: {s} on the chart {got}, analysis {want}"
        );
    }

    // Three charts, the ISO one on top; it shows every reading as a point.
    let mut frames = plot_frames(&svg);
    assert_eq!(frames.len(), 3, "{name}: three plot areas with points");
    frames.sort_by(|a, b| a.0.y.total_cmp(&b.0.y));
    let n_readings: u64 = json["targets"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t["n_up"].as_u64().unwrap() + t["n_down"].as_u64().unwrap())
        .sum();
    let small = frames[0].1.iter().filter(|d| d.r <= 2.0).count() as u64;
    assert_eq!(small, n_readings, "{name}: every reading plotted");

    // The legends cover no plotted point.
    let legends = legend_boxes(&svg, &["mean ↑", "drift-free ↓", "readings ↑"]);
    for (f, dots) in &frames {
        for b in &legends {
            for d in dots {
                assert!(
                    !b.contains(d.x, d.y),
                    "{name}: legend box {b:?} covers the point {d:?} of {f:?}"
                );
            }
        }
        // The data — points and coloured lines (means, band edges; the grid is grey) — fill
        // at least half of the y range (no empty 70 %).
        let ys = dots.iter().map(|d| d.y).chain(
            svg.lines
                .iter()
                .filter(|l| l.coloured)
                .flat_map(|l| &l.points)
                .filter(|p| f.contains(p.0, p.1))
                .map(|p| p.1),
        );
        let share = span(ys) / f.h;
        assert!(
            share >= 0.5,
            "{name}: data fill {:.0} % of the plot {f:?}",
            100.0 * share
        );
    }
    // On the ISO chart the readings alone fill half of it.
    let share = span(frames[0].1.iter().map(|d| d.y)) / frames[0].0.h;
    assert!(
        share >= 0.5,
        "{name}: the readings fill {:.0} % of the ISO chart",
        100.0 * share
    );
    eprintln!("charts kept: {} {}", svg_path.display(), png_path.display());
}

#[test]
#[cfg_attr(not(feature = "plot"), ignore = "draws charts: needs --features plot")]
fn positioning_chart_of_the_published_run() {
    // Deviations near −0.1 µm with sub-0.01 µm scatter: the tick labels cross zero.
    check_positioning_chart(PSI, "chart_psi");
}

#[test]
#[cfg_attr(not(feature = "plot"), ignore = "draws charts: needs --features plot")]
fn positioning_chart_of_a_real_run_with_times() {
    check_positioning_chart(ESS_B02, "chart_ess_b02_x");
}

#[test]
#[cfg_attr(not(feature = "plot"), ignore = "draws charts: needs --features plot")]
fn uncertainty_chart_keeps_its_legend_off_the_histogram() {
    let budget = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/budgets/jcgm101_9_2_2_additive_normal.toml"
    );
    let path = kept("uncertainty.svg");
    metrolog(&[
        "uncertainty",
        budget,
        "--trials",
        "20000",
        "--plot",
        path.to_str().unwrap(),
    ]);
    let svg = parse(&std::fs::read_to_string(&path).unwrap());
    assert_no_negative_zero(&svg, "uncertainty");
    let legend = legend_boxes(&svg, &["Monte Carlo"])[0];
    let inside = |r: &Rect| {
        r.x >= legend.x
            && r.x + r.w <= legend.x + legend.w
            && r.y >= legend.y
            && r.y + r.h <= legend.y + legend.h
    };
    let overlaps = |r: &Rect| {
        r.x < legend.x + legend.w
            && r.x + r.w > legend.x
            && r.y < legend.y + legend.h
            && r.y + r.h > legend.y
    };
    // The histogram bars: narrow rectangles outside the legend (its own marks are inside).
    let bars: Vec<&Rect> = svg
        .rects
        .iter()
        .filter(|r| r.w < 30.0 && r.h > 1.0 && !inside(r))
        .collect();
    assert!(bars.len() > 20, "histogram drawn: {} bars", bars.len());
    for b in bars {
        assert!(!overlaps(b), "legend {legend:?} over the bar {b:?}");
    }
}

#[test]
#[cfg_attr(not(feature = "plot"), ignore = "draws charts: needs --features plot")]
fn diagnosis_chart_prints_no_negative_zero() {
    let path = kept("diagnosis.svg");
    metrolog(&["diagnose", PSI, "--plot", path.to_str().unwrap()]);
    let svg = parse(&std::fs::read_to_string(&path).unwrap());
    assert_no_negative_zero(&svg, "diagnosis");
    assert!(svg.dots.len() > 50, "residuals plotted");
}
