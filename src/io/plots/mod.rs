//! PNG figures: the shared drawing pieces (DejaVu Sans embedded in the binary, the colour palette, canvas,
//! legend strip, line panel, tick labels) and one file per family of figures: [`calibration`] (figures
//! 6–8 of the workload evaluation), [`balance`] (figures 10 and 11 of the study), [`scan`] (run time
//! against error, stability maps), [`run`] (load balance and time per part of one run) and [`slice`] (a
//! snapshot of one plane of the flow with its spheres and blocks).
//!
//! Plain data in, PNG out (plotters' bitmap backend; `path` should end in `.png`, the encoder is chosen by
//! the extension). Text is set in DejaVu Sans embedded in the binary (the `dejavu` crate, registered with
//! plotters' ab_glyph font table), so no system font and no fontconfig are needed. Non-finite values are
//! skipped everywhere.

pub mod balance;
pub mod calibration;
pub mod run;
pub mod scan;
pub mod slice;

pub use calibration::{figure6, figure7, figure8, figure8_size, BlockSeries, FIGURE6_SIZE, FIGURE7_SIZE};

use crate::error::{Error, Result};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use plotters::style::{register_font, FontStyle};
use std::path::Path;
use std::sync::OnceLock;

use crate::util::stats::{mad, median, sorted_finite};

pub(super) type DrawResult = std::result::Result<(), Box<dyn std::error::Error>>;
pub(super) type Area<'a> = DrawingArea<BitMapBackend<'a>, Shift>;
/// A line of a chart panel: colour and points.
type Line = (RGBColor, Vec<(f64, f64)>);

/// Colour-blind-friendly qualitative palette (Okabe–Ito, then Tableau), cycled.
const PALETTE: [RGBColor; 10] = [
    RGBColor(0, 114, 178),
    RGBColor(230, 159, 0),
    RGBColor(0, 158, 115),
    RGBColor(204, 121, 167),
    RGBColor(213, 94, 0),
    RGBColor(86, 180, 233),
    RGBColor(140, 86, 75),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(0, 0, 0),
];

pub(super) const GRID: RGBColor = RGBColor(225, 225, 225);

pub(super) fn colour(i: usize) -> RGBColor {
    PALETTE[i % PALETTE.len()]
}

/// Registers DejaVu Sans (regular and bold) as plotters' "sans-serif", once per process.
fn ensure_font() -> std::result::Result<(), String> {
    static DONE: OnceLock<std::result::Result<(), String>> = OnceLock::new();
    DONE.get_or_init(|| {
        register_font("sans-serif", FontStyle::Normal, dejavu::sans::regular())
            .map_err(|_| "the embedded DejaVu Sans font is invalid".to_string())?;
        register_font("sans-serif", FontStyle::Bold, dejavu::sans::bold())
            .map_err(|_| "the embedded DejaVu Sans Bold font is invalid".to_string())
    })
    .clone()
}

pub(super) fn font(size: f64) -> TextStyle<'static> {
    TextStyle::from(FontDesc::new(FontFamily::SansSerif, size, FontStyle::Normal)).color(&BLACK)
}

pub(super) fn bold(size: f64) -> TextStyle<'static> {
    TextStyle::from(FontDesc::new(FontFamily::SansSerif, size, FontStyle::Bold)).color(&BLACK)
}

fn empty_err<T>(path: &Path, what: &str) -> Result<T> {
    Err(Error::Config(format!("{}: {what}: no data to plot", path.display())))
}

/// A white canvas of `size`: the whole area (to present) and the part below a bold title, with a margin.
pub(super) fn canvas<'a>(
    path: &'a Path,
    size: (u32, u32),
    title: &str,
) -> std::result::Result<(Area<'a>, Area<'a>), Box<dyn std::error::Error>> {
    let root = BitMapBackend::new(path, size).into_drawing_area();
    root.fill(&WHITE)?;
    let inner = root.margin(14, 6, 6, 6).titled(title, bold(28.0))?;
    Ok((root, inner))
}

/// Sets up the font, draws, and names the file in any error.
pub(super) fn render(path: &Path, draw: impl FnOnce() -> DrawResult) -> Result<()> {
    ensure_font().map_err(|e| Error::Io(format!("{}: {e}", path.display())))?;
    draw().map_err(|e| Error::Io(format!("{}: cannot write the figure: {e}", path.display())))
}

/// Median and median absolute deviation (unscaled: median of |x − median|) of the finite values;
/// `None` when there is none.
pub fn median_mad(values: &[f64]) -> Option<(f64, f64)> {
    let s = sorted_finite(values);
    (!s.is_empty()).then(|| (median(&s), mad(&s)))
}

/// Decimals for tick labels over an axis span: one more than the finest tick step plotters picks (at most
/// about ten ticks) needs, trailing zeros then dropped by [`tick`].
pub(super) fn decimals(span: f64) -> usize {
    if span.is_nan() || span <= 0.0 {
        return 2;
    }
    (1.0 - (span / 10.0).log10().floor()).clamp(0.0, 6.0) as usize
}

/// A tick label: `v` with at most `d` decimals, trailing zeros dropped ("0.5", "1", "30000").
pub(super) fn tick(v: f64, d: usize) -> String {
    let s = format!("{v:.d$}");
    let s = if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.')
    } else {
        &s
    };
    if s == "-0" {
        "0".to_string()
    } else {
        s.to_string()
    }
}

/// [min, max] of finite values, widened when empty or degenerate.
pub(super) fn range(values: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
    if lo > hi {
        return None;
    }
    if lo == hi {
        let d = if lo == 0.0 { 1.0 } else { lo.abs() * 0.05 };
        return Some((lo - d, hi + d));
    }
    Some((lo, hi))
}

/// Width of a legend strip ([`legend_strip`]) for `names` set at `size` px: the swatch and gap (62 px),
/// about 0.6 em per character of the longest name and a margin; at least `min`, at most half of
/// `figure_width`.
pub(super) fn legend_width(names: &[String], size: f64, min: u32, figure_width: u32) -> u32 {
    let longest = names.iter().map(|n| n.chars().count()).max().unwrap_or(0) as f64;
    ((80.0 + 0.6 * size * longest) as u32).clamp(min, figure_width / 2)
}

/// A legend in its own strip: a bold heading, then one coloured line and name per entry (colour i).
pub(super) fn legend_strip(area: &Area, heading: &str, names: &[String], size: f64) -> DrawResult {
    area.draw(&Text::new(heading.to_string(), (12, 60), bold(18.0)))?;
    for (i, name) in names.iter().enumerate() {
        let y = 100 + 32 * i as i32;
        area.draw(&PathElement::new(vec![(12, y), (52, y)], colour(i).stroke_width(4)))?;
        let label = font(size).pos(Pos::new(HPos::Left, VPos::Center));
        area.draw(&Text::new(name.clone(), (62, y), label))?;
    }
    Ok(())
}

/// One line chart panel of [`figure6`] and the study figures.
pub(super) fn line_panel(
    area: &Area,
    title: &str,
    x_desc: &str,
    y_desc: &str,
    (x0, x1): (f64, f64),
    (y0, y1): (f64, f64),
    lines: &[Line],
) -> DrawResult {
    let mut chart = ChartBuilder::on(area)
        .caption(title, font(22.0))
        .margin(12)
        .margin_right(30)
        .x_label_area_size(60)
        .y_label_area_size(110)
        .build_cartesian_2d(x0..x1, y0..y1)?;
    let (dx, dy) = (decimals(x1 - x0), decimals(y1 - y0));
    let fx = move |v: &f64| tick(*v, dx);
    let fy = move |v: &f64| tick(*v, dy);
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .label_style(font(17.0))
        .axis_desc_style(font(19.0))
        .x_label_formatter(&fx)
        .y_label_formatter(&fy)
        .x_labels(8)
        .y_labels(7)
        .light_line_style(WHITE)
        .bold_line_style(GRID)
        .draw()?;
    for (c, pts) in lines {
        if let [p] = pts[..] {
            chart.draw_series(std::iter::once(Circle::new(p, 4, c.filled())))?;
        } else {
            // Thick polylines join their segments with mitres, and a series with more points than
            // pixels zigzags at sharp angles: its mitres would draw spikes far past the data. Dense
            // series are drawn one pixel wide.
            let width = if pts.len() > 400 { 1 } else { 2 };
            chart.draw_series(LineSeries::new(pts.iter().copied(), c.stroke_width(width)))?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_legend_widens_for_long_names_within_half_the_figure() {
        assert_eq!(super::legend_width(&["f64".to_string()], 16.0, 330, 1400), 330);
        let long = "drag_array cli f32 solid_fraction=0.125 (order 1.9)".to_string();
        // 62 px of swatch and at least 9 px per character at 16 px.
        assert!(super::legend_width(std::slice::from_ref(&long), 16.0, 330, 1400) >= 62 + 9 * long.len() as u32);
        assert_eq!(super::legend_width(&["x".repeat(500)], 16.0, 330, 1400), 700);
    }
}
