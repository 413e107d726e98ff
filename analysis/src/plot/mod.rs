//! Plots of analysis results with `plotters` (SVG or PNG, chosen by the file extension).

use anyhow::anyhow;
use plotters::style::FontStyle;

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
