//! PNG figures of `blockflow sweep` and `stress`: error against run time on log–log axes, one line per
//! variant, the fitted order of convergence in the legend ([`error_vs_time`]); MLUPS, wall time and
//! load imbalance per configuration for a sweep without an error observable ([`configurations`]); the
//! stability map ([`stability_map`]). Same conventions as [`super`].

use super::{bold, canvas, colour, font, legend_strip, legend_width, render, GRID};
use crate::error::{Error, Result};
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::path::Path;

/// Size of the figure in pixels.
pub const SWEEP_FIGURE_SIZE: (u32, u32) = (1400, 850);

/// One line: its legend label and (run seconds, error) points.
pub type SweepLine = (String, Vec<(f64, f64)>);

/// Error against run time, log–log. Points that are not positive and finite are skipped; an error when
/// none is left.
pub fn error_vs_time(path: &Path, title: &str, y_desc: &str, lines: &[SweepLine]) -> Result<()> {
    let ok = |p: &&(f64, f64)| p.0.is_finite() && p.1.is_finite() && p.0 > 0.0 && p.1 > 0.0;
    let lines: Vec<SweepLine> = lines
        .iter()
        .map(|(n, pts)| (n.clone(), pts.iter().filter(ok).copied().collect()))
        .collect();
    let xs: Vec<f64> = lines.iter().flat_map(|l| l.1.iter().map(|p| p.0)).collect();
    let ys: Vec<f64> = lines.iter().flat_map(|l| l.1.iter().map(|p| p.1)).collect();
    if xs.is_empty() {
        return Err(Error::Config(format!("{}: {title}: no data to plot", path.display())));
    }
    // Widened to whole decades, so that a log axis over a narrow range still shows labelled ticks.
    let span = |v: &[f64]| {
        let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = v.iter().copied().fold(0.0, f64::max);
        // (a little past the decades, so that their ticks and labels are inside the plot)
        (
            (lo / 1.5).min(10f64.powf(lo.log10().floor())) / 1.05,
            (hi * 1.5).max(10f64.powf(hi.log10().ceil())) * 1.05,
        )
    };
    let (x0, x1) = span(&xs);
    let (y0, y1) = span(&ys);
    let names: Vec<String> = lines.iter().map(|l| l.0.clone()).collect();
    render(path, || {
        let (base, root) = canvas(path, SWEEP_FIGURE_SIZE, title)?;
        let (plot, legend) =
            root.split_horizontally(SWEEP_FIGURE_SIZE.0 - legend_width(&names, 16.0, 330, SWEEP_FIGURE_SIZE.0));
        let mut c = ChartBuilder::on(&plot)
            .margin(12)
            .margin_right(30)
            .x_label_area_size(60)
            .y_label_area_size(110)
            .build_cartesian_2d((x0..x1).log_scale(), (y0..y1).log_scale())?;
        c.configure_mesh()
            .x_desc("run time (s)")
            .y_desc(y_desc)
            .label_style(font(17.0))
            .axis_desc_style(font(19.0))
            .x_labels(8)
            .y_labels(8)
            .x_label_formatter(&|v: &f64| short(*v))
            .y_label_formatter(&|v: &f64| short(*v))
            .light_line_style(WHITE)
            .bold_line_style(GRID)
            .draw()?;
        for (i, (_, pts)) in lines.iter().enumerate() {
            let col = colour(i);
            c.draw_series(LineSeries::new(pts.iter().copied(), col.stroke_width(2)))?;
            c.draw_series(pts.iter().map(|&p| Circle::new(p, 4, col.filled())))?;
        }
        legend_strip(&legend, "variant", &names, 16.0)?;
        base.present()?;
        Ok(())
    })
}

/// One configuration of a sweep without an error observable: its label and what it measured.
#[derive(Clone, Debug)]
pub struct ConfigurationBar {
    /// The varied values, e.g. `pin=compact count=2`.
    pub label: String,
    /// Million fluid-cell updates per second.
    pub mlups: f64,
    /// Wall seconds of the time loop.
    pub wall_seconds: f64,
    /// Median load imbalance eq. (18) (a fraction).
    pub imbalance: f64,
}

/// Size of [`configurations`] in pixels.
pub const CONFIGURATIONS_SIZE: (u32, u32) = (1400, 1000);

/// The figure of a sweep without an error observable (a pinning or placement experiment): three panels
/// of bars, MLUPS, wall seconds and median load imbalance, one bar per configuration numbered as in the
/// key on the right. Non-finite values (failed runs) get no bar; an error when no bar is left.
pub fn configurations(path: &Path, title: &str, bars: &[ConfigurationBar]) -> Result<()> {
    let panels: [(&str, Vec<f64>); 3] = [
        ("MLUPS", bars.iter().map(|b| b.mlups).collect()),
        ("wall seconds", bars.iter().map(|b| b.wall_seconds).collect()),
        ("median LI (%)", bars.iter().map(|b| 100.0 * b.imbalance).collect()),
    ];
    if !panels[0].1.iter().chain(&panels[1].1).any(|v| v.is_finite()) {
        return Err(Error::Config(format!("{}: {title}: no data to plot", path.display())));
    }
    let names: Vec<String> = bars
        .iter()
        .enumerate()
        .map(|(i, b)| format!("{}: {}", i + 1, b.label))
        .collect();
    let legend_px = legend_width(&names, 16.0, 330, CONFIGURATIONS_SIZE.0);
    let n = bars.len() as f64;
    render(path, || {
        let (base, root) = canvas(path, CONFIGURATIONS_SIZE, title)?;
        let (plot, legend) = root.split_horizontally(CONFIGURATIONS_SIZE.0 - legend_px);
        let rows = plot.split_evenly((3, 1));
        for (area, (desc, values)) in rows.iter().zip(&panels) {
            let top = values.iter().copied().filter(|v| v.is_finite()).fold(0.0, f64::max);
            let top = if top > 0.0 { top * 1.1 } else { 1.0 };
            let mut c = ChartBuilder::on(area)
                .margin(10)
                .margin_right(30)
                .x_label_area_size(40)
                .y_label_area_size(110)
                .build_cartesian_2d(0.5..n + 0.5, 0.0..top)?;
            let dy = super::decimals(top);
            let fy = move |v: &f64| super::tick(*v, dy);
            let fx = |v: &f64| {
                let k = v.round();
                if (v - k).abs() < 1e-6 && k >= 1.0 && k <= n {
                    format!("{k:.0}")
                } else {
                    String::new()
                }
            };
            c.configure_mesh()
                .y_desc(*desc)
                .label_style(font(17.0))
                .axis_desc_style(font(19.0))
                .x_labels(bars.len().max(1) * 2 + 1)
                .y_labels(5)
                .x_label_formatter(&fx)
                .y_label_formatter(&fy)
                .disable_x_mesh()
                .light_line_style(WHITE)
                .bold_line_style(GRID)
                .draw()?;
            c.draw_series(values.iter().enumerate().filter(|(_, v)| v.is_finite()).map(|(i, &v)| {
                let x = i as f64 + 1.0;
                Rectangle::new([(x - 0.35, 0.0), (x + 0.35, v)], colour(i).filled())
            }))?;
        }
        legend_strip(&legend, "configuration", &names, 16.0)?;
        base.present()?;
        Ok(())
    })
}

/// A short tick label: plain digits between 0.01 and 10⁴, else `1e-5` style.
fn short(v: f64) -> String {
    if (0.01..1e4).contains(&v.abs()) {
        let s = format!("{v:.3}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        format!("{v:.0e}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn short_labels() {
        assert_eq!(short(20.0), "20");
        assert_eq!(short(0.05), "0.05");
        assert_eq!(short(1e-5), "1e-5");
        assert_eq!(short(2e5), "2e5");
    }

    #[test]
    fn configurations_draw_bars_and_refuse_runs_that_all_failed() {
        let dir = std::env::temp_dir().join(format!("blockflow-conf-fig-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let bar = |label: &str, mlups: f64| ConfigurationBar {
            label: label.to_string(),
            mlups,
            wall_seconds: 10.0 / mlups,
            imbalance: 0.05,
        };
        let p = dir.join("c.png");
        configurations(
            &p,
            "t",
            &[bar("pin=compact count=1", 20.0), bar("pin=none count=2", 14.0)],
        )
        .unwrap();
        let png = std::fs::read(&p).unwrap();
        let be = |i: usize| u32::from_be_bytes(png[i..i + 4].try_into().unwrap());
        assert_eq!((be(16), be(20)), CONFIGURATIONS_SIZE);
        assert!(configurations(&dir.join("e.png"), "t", &[bar("x", f64::NAN)]).is_err());
        assert!(!dir.join("e.png").exists());
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn writes_a_png_and_refuses_empty_input() {
        let dir = std::env::temp_dir().join(format!("blockflow-sweep-fig-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("s.png");
        let lines = vec![("f64 (order 2.0)".to_string(), vec![(0.1, 1e-3), (0.8, 2.5e-4)])];
        error_vs_time(&p, "t", "l2 error", &lines).unwrap();
        assert_eq!(&std::fs::read(&p).unwrap()[1..4], b"PNG");
        let none = vec![("x".to_string(), vec![(0.1, 0.0)])];
        assert!(error_vs_time(&dir.join("e.png"), "t", "e", &none).is_err());
        std::fs::remove_dir_all(&dir).ok();
    }
}

/// Outcome of one run of a stability map.
#[derive(Clone, Debug, PartialEq)]
pub enum Outcome {
    /// Ran to the end within the error bound.
    Stable,
    /// Ran to the end with an error beyond the bound.
    Inaccurate,
    /// Stopped by the detector at this step (None: step unknown).
    Unstable(Option<u64>),
    /// Not run: the scene refused the values (e.g. τ below ½ or a Mach number past its limit).
    Refused,
}

/// Size of the stability map in pixels.
pub const MAP_SIZE: (u32, u32) = (1400, 900);

/// Stability map: one cell per (x value, y value), green stable, amber inaccurate, red unstable with the
/// step written in it. `cells[j][i]` is the outcome at `xs[i]`, `ys[j]`.
pub fn stability_map(
    path: &Path,
    title: &str,
    (x_key, xs): (&str, &[String]),
    (y_key, ys): (&str, &[String]),
    cells: &[Vec<Outcome>],
) -> Result<()> {
    if xs.is_empty() || ys.is_empty() {
        return Err(Error::Config(format!("{}: {title}: no data to plot", path.display())));
    }
    let (nx, ny) = (xs.len() as i32, ys.len() as i32);
    render(path, || {
        let (base, root) = canvas(path, MAP_SIZE, title)?;
        let (plot, legend) = root.split_horizontally(MAP_SIZE.0 - 260);
        let mut c = ChartBuilder::on(&plot)
            .margin(12)
            .x_label_area_size(70)
            .y_label_area_size(140)
            .build_cartesian_2d(0.0..nx as f64, 0.0..ny as f64)?;
        c.configure_mesh()
            .disable_mesh()
            .x_desc(x_key)
            .y_desc(y_key)
            .axis_desc_style(font(19.0))
            .x_labels(0)
            .y_labels(0)
            .draw()?;
        // Value labels at the cell centres (drawn on the whole canvas, in its pixel coordinates).
        for (i, x) in xs.iter().enumerate() {
            let (px, py) = c.backend_coord(&(i as f64 + 0.5, 0.0));
            let style = font(15.0).pos(Pos::new(HPos::Center, VPos::Top));
            base.draw(&Text::new(x.clone(), (px, py + 8), style))?;
        }
        for (j, y) in ys.iter().enumerate() {
            let (px, py) = c.backend_coord(&(0.0, j as f64 + 0.5));
            let style = font(15.0).pos(Pos::new(HPos::Right, VPos::Center));
            base.draw(&Text::new(y.clone(), (px - 8, py), style))?;
        }
        let green = RGBColor(0, 158, 115);
        let amber = RGBColor(230, 159, 0);
        let red = RGBColor(213, 94, 0);
        let grey = RGBColor(170, 170, 170);
        for (j, row) in cells.iter().enumerate() {
            for (i, o) in row.iter().enumerate() {
                let col = match o {
                    Outcome::Stable => green,
                    Outcome::Inaccurate => amber,
                    Outcome::Unstable(_) => red,
                    Outcome::Refused => grey,
                };
                let (a, b) = ((i as f64, j as f64), (i as f64 + 1.0, j as f64 + 1.0));
                c.draw_series(std::iter::once(Rectangle::new([a, b], col.filled())))?;
                c.draw_series(std::iter::once(Rectangle::new([a, b], WHITE.stroke_width(2))))?;
                if let Outcome::Unstable(Some(st)) = o {
                    let (px, py) = c.backend_coord(&(i as f64 + 0.5, j as f64 + 0.5));
                    let style = font(15.0).color(&WHITE).pos(Pos::new(HPos::Center, VPos::Center));
                    base.draw(&Text::new(format!("step {st}"), (px, py), style))?;
                }
            }
        }
        legend.draw(&Text::new("outcome", (12, 60), bold(18.0)))?;
        for (k, (name, col)) in [
            ("stable", green),
            ("inaccurate", amber),
            ("unstable (step)", red),
            ("refused", grey),
        ]
        .into_iter()
        .enumerate()
        {
            let y = 100 + 34 * k as i32;
            legend.draw(&Rectangle::new([(12, y - 10), (40, y + 10)], col.filled()))?;
            let label = font(17.0).pos(Pos::new(HPos::Left, VPos::Center));
            legend.draw(&Text::new(name, (50, y), label))?;
        }
        base.present()?;
        Ok(())
    })
}
