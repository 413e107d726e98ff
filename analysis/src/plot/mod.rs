//! Plots of analysis results with `plotters` (SVG or PNG, chosen by the file extension).

pub mod positioning;
pub mod uncertainty;
