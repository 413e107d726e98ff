//! Plots of analysis results with `plotters` (SVG or PNG, chosen by the file extension).
//!
//! Every chart follows the same rules (`docs/datasets.md`, "Charts"): the y range is the
//! data's (readings and bands) with a small margin, the legend and any results block sit in a
//! column of their own right of the plot area so that they never cover data, and tick labels
//! and numbers go through [`crate::export::num`], which never prints "-0.0".

use std::path::Path;

use crate::export::num;
use anyhow::{Context as _, anyhow};
use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf64;
use plotters::element::DashedPathElement;
use plotters::prelude::*;
use plotters::style::FontStyle;
use plotters::style::text_anchor::{HPos, Pos, VPos};

pub mod diagnosis;
pub mod positioning;
pub mod uncertainty;

pub(crate) const FONT: &str = "sans-serif";

/// Registers a TrueType font with plotters once (plotters draws text with `ab_glyph` and has
/// no font of its own). `METROLOG_FONT` names a .ttf; else common system fonts are tried.
pub fn ensure_font() -> anyhow::Result<()> {
    static DONE: std::sync::OnceLock<Result<(), String>> = std::sync::OnceLock::new();
    DONE.get_or_init(|| {
        let mut candidates: Vec<String> = Vec::new();
        if let Ok(p) = std::env::var("METROLOG_FONT") {
            candidates.push(p);
        }
        candidates.extend(
            [
                "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
                "/usr/share/fonts/TTF/DejaVuSans.ttf",
                "/usr/share/fonts/dejavu/DejaVuSans.ttf",
                "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
                "/usr/share/fonts/truetype/freefont/FreeSans.ttf",
            ]
            .map(String::from),
        );
        for c in candidates {
            if let Ok(bytes) = std::fs::read(&c) {
                // plotters keeps fonts for the life of the process.
                let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
                if plotters::style::register_font(FONT, FontStyle::Normal, bytes).is_ok() {
                    return Ok(());
                }
            }
        }
        Err("no TrueType font found for the plot text; set METROLOG_FONT to a .ttf file".into())
    })
    .clone()
    .map_err(|e| anyhow!(e))
}

/// Draws onto an SVG or PNG file by extension. Two closures because the backends are
/// different types and the drawing code is generic over them.
pub(crate) fn with_backend(
    path: &Path,
    size: (u32, u32),
    draw: &dyn Fn(&DrawingArea<SVGBackend, Shift>) -> anyhow::Result<()>,
    draw_png: &dyn Fn(&DrawingArea<BitMapBackend, Shift>) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    ensure_font()?;
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    match ext.as_str() {
        "svg" => {
            let root = SVGBackend::new(path, size).into_drawing_area();
            draw(&root)?;
            root.present().map_err(e)
        }
        "png" => {
            let root = BitMapBackend::new(path, size).into_drawing_area();
            draw_png(&root)?;
            root.present().map_err(e)
        }
        _ => anyhow::bail!(
            "cannot tell the plot format of {}: name it .svg or .png",
            path.display()
        ),
    }
    .with_context(|| format!("writing the plot {}", path.display()))
}

pub(crate) fn e<E: std::fmt::Debug>(e: E) -> anyhow::Error {
    anyhow!("{e:?}")
}

/// Labels per axis asked of plotters (`x_labels`, `y_labels`).
pub(crate) const LABELS: usize = 10;

/// The tick labels of an axis over `(lo, hi)`: the fewest decimals that write every label
/// plotters will put on it (its own key points for [`LABELS`]) exactly, one count for the
/// whole axis so that the labels align; [`num`] never writes "-0".
pub(crate) fn ticks(range: (f64, f64)) -> impl Fn(&f64) -> String {
    use plotters::coord::ranged1d::Ranged as _;
    let (lo, hi) = axis_range(range);
    let keys = RangedCoordf64::from(lo..hi).key_points(LABELS);
    let step = match keys.as_slice() {
        [a, b, ..] => b - a,
        _ => hi - lo,
    };
    // Exact: rounded to d decimals, every label is off by less than a millionth of the step.
    let exact = |d: usize| {
        let f = 10f64.powi(d as i32);
        keys.iter()
            .all(|v| ((v * f).round() / f - v).abs() <= 1e-6 * step.abs())
    };
    let d = (0..=12).find(|d| exact(*d)).unwrap_or(12);
    move |v: &f64| num(*v, d)
}

/// The largest magnitude an axis reaches: plotters' key points loop forever over a span that
/// overflows to infinity (±1e308 did) or that vanishes against its values' magnitude.
const AXIS_LIMIT: f64 = 1e300;

/// A range every chart axis can take: finite, within ±[`AXIS_LIMIT`], increasing, and with a
/// span of at least 10⁻⁹ of its magnitude (a NaN range becomes −1…1).
pub(crate) fn axis_range((lo, hi): (f64, f64)) -> (f64, f64) {
    if lo.is_nan() || hi.is_nan() {
        return (-1.0, 1.0);
    }
    let (lo, hi) = (
        lo.min(hi).clamp(-AXIS_LIMIT, AXIS_LIMIT),
        hi.max(lo).clamp(-AXIS_LIMIT, AXIS_LIMIT),
    );
    let magnitude = lo.abs().max(hi.abs());
    if hi - lo >= 1e-9 * magnitude && hi - lo > 1e-200 {
        return (lo, hi);
    }
    let half = (magnitude * 0.05).max(0.5);
    (lo - half, hi + half)
}

/// The range of some values (finite ones only) widened by `margin` of its span on each side;
/// a flat or empty set gets a span of its own so that the chart still has a scale.
pub(crate) fn padded_range(vals: impl Iterator<Item = f64>, margin: f64) -> (f64, f64) {
    let (lo, hi) = vals
        .filter(|v| v.is_finite())
        .map(|v| v.clamp(-AXIS_LIMIT, AXIS_LIMIT))
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(v), b.max(v))
        });
    if !lo.is_finite() {
        return (-1.0, 1.0);
    }
    let span = hi - lo;
    if span < 1e-9 * lo.abs().max(1.0) {
        let half = (lo.abs() * 0.05).max(0.5);
        return axis_range((lo - half, hi + half));
    }
    axis_range((lo - margin * span, hi + margin * span))
}

/// How a legend entry is drawn.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Mark {
    /// A solid line, 2 px.
    Line(RGBColor),
    /// A dashed line (band edges).
    Dashed(RGBColor),
    /// A thin line through small dots (one run of readings).
    Run(RGBColor),
    /// A light filled square (histogram bars).
    Bar(RGBColor),
}

/// The column right of a plot area: a results block (title and `symbol / value` rows) on top,
/// the legend below it, each in a frame of its own. Drawn in the area's pixel coordinates.
pub(crate) fn side_column<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    top: i32,
    block_title: &str,
    block: &[(String, String)],
    legend: &[(Mark, String)],
) -> anyhow::Result<()> {
    let (w, _) = area.dim_in_pixel();
    let (x0, x1) = (4, w as i32 - 10);
    let row = 21;
    let font = |size: i32| (FONT, size).into_font().color(&BLACK);
    let mut y = top;
    if !block.is_empty() {
        let h = 30 + row * block.len() as i32 + 6;
        area.draw(&Rectangle::new(
            [(x0, y), (x1, y + h)],
            RGBColor(246, 246, 246).filled(),
        ))
        .map_err(e)?;
        area.draw(&Rectangle::new(
            [(x0, y), (x1, y + h)],
            RGBColor(120, 120, 120).stroke_width(1),
        ))
        .map_err(e)?;
        area.draw(&Text::new(
            block_title.to_string(),
            (x0 + 8, y + 8),
            font(15),
        ))
        .map_err(e)?;
        for (i, (k, v)) in block.iter().enumerate() {
            let ry = y + 32 + row * i as i32;
            area.draw(&Text::new(k.clone(), (x0 + 8, ry), font(14)))
                .map_err(e)?;
            let right = font(14).pos(Pos::new(HPos::Right, VPos::Top));
            area.draw(&Text::new(v.clone(), (x1 - 8, ry), right))
                .map_err(e)?;
        }
        y += h + 14;
    }
    if legend.is_empty() {
        return Ok(());
    }
    let h = 8 + row * legend.len() as i32;
    area.draw(&Rectangle::new(
        [(x0, y), (x1, y + h)],
        RGBColor(120, 120, 120).stroke_width(1),
    ))
    .map_err(e)?;
    for (i, (mark, label)) in legend.iter().enumerate() {
        let ly = y + 6 + row * i as i32;
        let (mx, my) = (x0 + 8, ly + 8);
        draw_mark(area, *mark, (mx, my))?;
        area.draw(&Text::new(label.clone(), (mx + 34, ly), font(14)))
            .map_err(e)?;
    }
    Ok(())
}

/// One legend mark, 26 px wide, centred vertically on `y`.
fn draw_mark<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    mark: Mark,
    (x, y): (i32, i32),
) -> anyhow::Result<()> {
    let seg = vec![(x, y), (x + 26, y)];
    match mark {
        Mark::Line(c) => area.draw(&PathElement::new(seg, c.stroke_width(2))),
        Mark::Dashed(c) => area.draw(&DashedPathElement::new(seg, 5, 3, c.stroke_width(1))),
        Mark::Run(c) => {
            area.draw(&PathElement::new(seg, c.mix(0.45).stroke_width(1)))
                .map_err(e)?;
            area.draw(&Circle::new((x + 13, y), 2, c.mix(0.8).filled()))
        }
        Mark::Bar(c) => area.draw(&Rectangle::new(
            [(x + 5, y - 5), (x + 21, y + 5)],
            c.mix(0.45).filled(),
        )),
    }
    .map_err(e)
}

#[cfg(test)]
mod tests {
    use plotters::coord::ranged1d::Ranged as _;

    use super::*;

    #[test]
    fn tick_labels_are_exact_distinct_and_never_negative_zero() {
        for r in [
            (-0.155, 0.0371),
            (-0.17, -0.03),
            (-4.3, 4.3),
            (0.0, 860000.0),
            (1e-7, 3e-7),
        ] {
            let f = ticks(r);
            let keys = RangedCoordf64::from(r.0..r.1).key_points(LABELS);
            let labels: Vec<String> = keys.iter().map(&f).collect();
            for (k, l) in keys.iter().zip(&labels) {
                let back: f64 = l.parse().unwrap();
                assert!((back - k).abs() <= 1e-9 * (r.1 - r.0), "{k} written {l}");
            }
            let mut d = labels.clone();
            d.dedup();
            assert_eq!(d.len(), labels.len(), "{labels:?}");
            assert!(
                !labels
                    .iter()
                    .any(|l| l == "-0" || l == "-0.0" || l == "-0.00")
            );
        }
    }

    #[test]
    fn padded_range_of_flat_and_empty_data_has_a_span() {
        let (a, b) = padded_range([2.0, 2.0].into_iter(), 0.06);
        assert!(a < 2.0 && b > 2.0);
        assert_eq!(padded_range(std::iter::empty(), 0.06), (-1.0, 1.0));
        let (a, b) = padded_range([0.0, 10.0].into_iter(), 0.06);
        assert!((a + 0.6).abs() < 1e-12 && (b - 10.6).abs() < 1e-12);
    }

    /// ±1e308 made plotters' key points loop forever (the span overflowed to infinity); a
    /// span that vanishes against its magnitude, NaN and infinities must end too. Each range
    /// gets key points, few of them, and finite ones.
    #[test]
    fn extreme_ranges_give_finite_axes_and_end() {
        for r in [
            (-1e308, 1e308),
            (f64::MIN, f64::MAX),
            (f64::NEG_INFINITY, f64::INFINITY),
            (f64::NAN, 1.0),
            (1e20, 1e20 + 1.0),
            (1e300, 1e300),
            (5.0, -5.0),
            (0.0, 1e-300),
        ] {
            let (lo, hi) = axis_range(r);
            assert!(
                lo.is_finite() && hi.is_finite() && (hi - lo).is_finite() && hi > lo,
                "{r:?}"
            );
            let keys = RangedCoordf64::from(lo..hi).key_points(LABELS);
            assert!(
                keys.len() <= LABELS + 1 && keys.iter().all(|k| k.is_finite()),
                "{r:?}"
            );
            let _ = ticks(r)(&lo);
        }
        let (a, b) = padded_range([-1e308, 1e308, f64::NAN, f64::INFINITY].into_iter(), 0.08);
        assert!(a.is_finite() && b.is_finite() && (b - a).is_finite());
    }
}
