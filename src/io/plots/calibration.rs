//! The figures of the workload evaluation (section 3.4 of the paper):
//! - [`figure6`]: fluid cells F and LBM time m_LBM per block over t* = t/T, coloured by block row;
//! - [`figure7`]: box plot of each part's share m_X/m_tot of the total runtime per sample;
//! - [`figure8`]: histograms of the relative errors E_X = (WL_X − m_X)/m_tot of the workload fits.
//!
//! Empty input: a figure with nothing to show at all (no series, no part, or not one finite value) is an
//! error ([`Error::Config`], naming the file) and no file is written. One series or part without data among
//! others is drawn empty: no line (Figure 6), no box (Figure 7), a panel saying "no data" (Figure 8).

use super::{
    bold, canvas, colour, decimals, empty_err, font, legend_strip, line_panel, median_mad, range, render, tick, Area,
    DrawResult, Line, GRID,
};
use crate::error::Result;
use crate::util::stats::{quantile, sorted_finite};
use plotters::coord::ranged1d::{DefaultFormatting, KeyPointHint, Ranged};
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::collections::BTreeMap;
use std::path::Path;

/// Size of [`figure6`] in pixels (width, height).
pub const FIGURE6_SIZE: (u32, u32) = (1400, 1100);
/// Size of [`figure7`] in pixels (width, height).
pub const FIGURE7_SIZE: (u32, u32) = (1200, 800);

/// Size of [`figure8`] in pixels for `panels` panels (parts plus total): 520 × 440 pixels per panel in a
/// grid of about 3:2, plus the title.
pub fn figure8_size(panels: usize) -> (u32, u32) {
    let (rows, cols) = figure8_grid(panels);
    (520 * cols as u32, 440 * rows as u32 + 60)
}

/// The measurements of one block for [`figure6`].
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BlockSeries {
    /// Block row (the colour and legend entry, "row N").
    pub row: usize,
    /// (t*, F, m_LBM): dimensionless time t/T, fluid cells of the block, LBM seconds per step.
    pub points: Vec<(f64, f64, f64)>,
}

/// Figure 6: number of fluid cells F (top) and LBM time m_LBM in ms per step (bottom) of every block over
/// t* = t/T, one line per block, coloured by block row, with a legend per row to the right of the panels.
/// `m_LBM` is given in seconds; its axis ends at 1.5× the 99.9th percentile. Written as a [`FIGURE6_SIZE`] PNG; an error when no series has a finite point.
pub fn figure6(path: &Path, series: &[BlockSeries]) -> Result<()> {
    let finite = |p: &&(f64, f64, f64)| p.0.is_finite() && p.1.is_finite() && p.2.is_finite();
    let lines: Vec<BlockSeries> = series
        .iter()
        .map(|s| BlockSeries {
            row: s.row,
            points: s.points.iter().filter(finite).copied().collect(),
        })
        .collect();
    let all = || lines.iter().flat_map(|s| s.points.iter());
    let Some(t) = range(all().map(|p| p.0)) else {
        return empty_err(path, "figure 6");
    };
    let f_max = all().map(|p| p.1).fold(0.0, f64::max);
    // The LBM axis ends at 1.5× the 99.9th percentile: single steps slowed many-fold by the machine
    // would otherwise squash every line to the bottom (how many lie above is named in the title).
    let m_sorted = sorted_finite(&all().map(|p| p.2 * 1e3).collect::<Vec<f64>>());
    let m_max = if m_sorted.is_empty() {
        0.0
    } else {
        (1.5 * quantile(&m_sorted, 0.999)).min(m_sorted[m_sorted.len() - 1])
    };
    let above = m_sorted.iter().filter(|&&m| m > m_max * 1.05).count();
    let m_title = if above == 0 {
        "LBM time per block".to_string()
    } else {
        format!(
            "LBM time per block ({above} of {} steps above the axis)",
            m_sorted.len()
        )
    };
    let rows: BTreeMap<usize, usize> = lines
        .iter()
        .map(|s| s.row)
        .collect::<std::collections::BTreeSet<_>>()
        .into_iter()
        .enumerate()
        .map(|(i, r)| (r, i))
        .collect();
    render(path, || {
        let (base, root) = canvas(path, FIGURE6_SIZE, "LBM workload per block over time")?;
        let (plots, legend) = root.split_horizontally(FIGURE6_SIZE.0 - 180);
        let panels = plots.split_evenly((2, 1));
        let project = |f: fn(&(f64, f64, f64)) -> (f64, f64)| -> Vec<Line> {
            lines
                .iter()
                .map(|s| (colour(rows[&s.row]), s.points.iter().map(f).collect()))
                .collect()
        };
        let top = project(|q| (q.0, q.1));
        let f_top = if f_max > 0.0 { f_max * 1.05 } else { 1.0 };
        let m_top = if m_max > 0.0 { m_max * 1.05 } else { 1.0 };
        // Steps above the axis are drawn at its top edge (lines are not clipped to the plot area).
        let bottom: Vec<Line> = project(|q| (q.0, q.2 * 1e3))
            .into_iter()
            .map(|(c, pts)| (c, pts.into_iter().map(|(t, m)| (t, m.min(m_top))).collect()))
            .collect();
        line_panel(
            &panels[0],
            "fluid cells per block",
            "t* = t / T",
            "F (fluid cells)",
            t,
            (0.0, f_top),
            &top,
        )?;
        line_panel(
            &panels[1],
            &m_title,
            "t* = t / T",
            "m_LBM (ms per step)",
            t,
            (0.0, m_top),
            &bottom,
        )?;
        // Legend in its own strip, level with the top panel's plot area: it never covers data.
        let names: Vec<String> = rows.keys().map(|r| format!("row {r}")).collect();
        legend_strip(&legend, "block row", &names, 18.0)?;
        base.present()?;
        Ok(())
    })
}

/// Figure 7: box-and-whiskers plot of m_X/m_tot per part (`parts`: name and one share per sample, in
/// [0, 1]): box from the lower to the upper quartile, a line at the median, whiskers at the 5th and 95th
/// percentiles. Written as a [`FIGURE7_SIZE`] PNG; an error when no part has a finite value.
pub fn figure7(path: &Path, parts: &[(String, Vec<f64>)]) -> Result<()> {
    let sorted: Vec<Vec<f64>> = parts.iter().map(|(_, v)| sorted_finite(v)).collect();
    if sorted.iter().all(Vec::is_empty) {
        return empty_err(path, "figure 7");
    }
    let names: Vec<&str> = parts.iter().map(|(n, _)| n.as_str()).collect();
    let n = parts.len();
    render(path, || {
        let (base, root) = canvas(path, FIGURE7_SIZE, "Share of each part in the total runtime")?;
        let x = PartAxis(n);
        let mut chart = ChartBuilder::on(&root)
            .caption(
                "box: quartiles, line: median, whiskers: 5th and 95th percentiles",
                font(18.0),
            )
            .margin(15)
            .margin_right(35)
            .x_label_area_size(60)
            .y_label_area_size(100)
            .build_cartesian_2d(x, 0.0..1.0)?;
        let fx = |v: &f64| {
            let i = v.round();
            if i >= 0.0 && (i as usize) < n && (v - i).abs() < 1e-6 {
                names[i as usize].to_string()
            } else {
                String::new()
            }
        };
        let fy = |v: &f64| format!("{v:.1}");
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_desc("part X")
            .y_desc("share of m_tot (m_X / m_tot)")
            .label_style(font(18.0))
            .axis_desc_style(font(20.0))
            .x_label_formatter(&fx)
            .y_label_formatter(&fy)
            .y_labels(11)
            .light_line_style(WHITE)
            .bold_line_style(GRID)
            .draw()?;
        for (i, s) in sorted.iter().enumerate() {
            if s.is_empty() {
                continue;
            }
            let (xc, c) = (i as f64, colour(i));
            let q = |p: f64| quantile(s, p).clamp(0.0, 1.0);
            let (p5, q1, med, q3, p95) = (q(0.05), q(0.25), q(0.5), q(0.75), q(0.95));
            let (w, cap) = (0.3, 0.12);
            let whiskers = [
                vec![(xc, p5), (xc, q1)],
                vec![(xc, q3), (xc, p95)],
                vec![(xc - cap, p5), (xc + cap, p5)],
                vec![(xc - cap, p95), (xc + cap, p95)],
            ];
            for wl in whiskers {
                chart.draw_series(std::iter::once(PathElement::new(wl, BLACK.stroke_width(2))))?;
            }
            chart.draw_series(std::iter::once(Rectangle::new(
                [(xc - w, q1), (xc + w, q3)],
                c.mix(0.35).filled(),
            )))?;
            chart.draw_series(std::iter::once(Rectangle::new(
                [(xc - w, q1), (xc + w, q3)],
                c.stroke_width(2),
            )))?;
            chart.draw_series(std::iter::once(PathElement::new(
                vec![(xc - w, med), (xc + w, med)],
                BLACK.stroke_width(3),
            )))?;
        }
        base.present()?;
        Ok(())
    })
}

/// The x axis of [`figure7`]: parts at 0, 1, …, n − 1 with a tick (the part's name) at each.
struct PartAxis(usize);

impl Ranged for PartAxis {
    type FormatOption = DefaultFormatting;
    type ValueType = f64;

    fn map(&self, v: &f64, (a, b): (i32, i32)) -> i32 {
        let r = self.range();
        a + ((v - r.start) / (r.end - r.start) * f64::from(b - a)).round() as i32
    }

    fn key_points<Hint: KeyPointHint>(&self, _hint: Hint) -> Vec<f64> {
        (0..self.0).map(|i| i as f64).collect()
    }

    fn range(&self) -> std::ops::Range<f64> {
        -0.6..self.0 as f64 - 0.4
    }
}

/// Rows and columns of the [`figure8`] grid: about 3:2, one row up to three panels.
fn figure8_grid(panels: usize) -> (usize, usize) {
    let panels = panels.max(1);
    let rows = ((panels as f64 / 1.5).sqrt().round() as usize).clamp(1, panels);
    (rows, panels.div_ceil(rows))
}

/// Figure 8: one histogram per part of the relative errors E_X = (WL_X − m_X)/m_tot, given as fractions
/// (0.05 = 5 %) and plotted in %; the caller passes the total last (e.g. named "total"). Each panel's title
/// gives the median and the median absolute deviation (unscaled) of its finite values, a red line marks the
/// median. The x axis spans the 1st to 99th percentile, cut to ±50 % and widened to include 0; values
/// outside are counted in the axis label. Written as a [`figure8_size`] PNG; an error when no part has a
/// finite value.
pub fn figure8(path: &Path, parts: &[(String, Vec<f64>)]) -> Result<()> {
    let pct: Vec<Vec<f64>> = parts
        .iter()
        .map(|(_, v)| sorted_finite(&v.iter().map(|e| e * 100.0).collect::<Vec<_>>()))
        .collect();
    if pct.iter().all(Vec::is_empty) {
        return empty_err(path, "figure 8");
    }
    let size = figure8_size(parts.len());
    let (rows, cols) = figure8_grid(parts.len());
    render(path, || {
        let (base, root) = canvas(
            path,
            size,
            "Relative error of the predicted workload, E_X = (WL_X − m_X) / m_tot",
        )?;
        let panels = root.split_evenly((rows, cols));
        for (i, ((name, _), v)) in parts.iter().zip(&pct).enumerate() {
            histogram_panel(&panels[i], name, v, colour(i))?;
        }
        base.present()?;
        Ok(())
    })
}

/// The x range of a [`figure8`] panel, in %.
fn histogram_range(sorted: &[f64]) -> (f64, f64) {
    let (p1, p99) = (quantile(sorted, 0.01), quantile(sorted, 0.99));
    let (mut lo, mut hi) = (p1.max(-50.0), p99.min(50.0));
    if lo < hi || (lo == hi && lo.abs() < 50.0) {
        lo = lo.clamp(-50.0, 0.0);
        hi = hi.clamp(0.0, 50.0);
    } else {
        // Everything beyond ±50 %: show it rather than an empty axis.
        (lo, hi) = (p1, p99);
    }
    if lo == hi {
        let d = if lo == 0.0 { 1.0 } else { lo.abs() * 0.1 };
        (lo, hi) = (lo - d, hi + d);
    }
    let pad = 0.03 * (hi - lo);
    (lo - pad, hi + pad)
}

/// One histogram panel of [`figure8`]; `v` sorted, finite, in %.
fn histogram_panel(area: &Area, name: &str, v: &[f64], c: RGBColor) -> DrawResult {
    let area = area.margin(8, 8, 8, 8);
    let Some((med, mad)) = median_mad(v) else {
        let (w, h) = area.dim_in_pixel();
        let style = bold(18.0).pos(Pos::new(HPos::Center, VPos::Center));
        area.draw(&Text::new(
            format!("{name}: no data"),
            (w as i32 / 2, h as i32 / 2),
            style,
        ))?;
        return Ok(());
    };
    let (lo, hi) = histogram_range(v);
    let bins = ((v.len() as f64).sqrt() * 2.0).clamp(10.0, 40.0) as usize;
    let width = (hi - lo) / bins as f64;
    let mut counts = vec![0usize; bins];
    let mut outside = 0;
    for &x in v {
        if x < lo || x > hi {
            outside += 1;
        } else {
            counts[(((x - lo) / width) as usize).min(bins - 1)] += 1;
        }
    }
    let top = (*counts.iter().max().unwrap_or(&1)).max(1) as f64 * 1.08;
    let title = format!("{name}: median = {}%, MAD = {}%", pct_str(med), pct_str(mad));
    let mut chart = ChartBuilder::on(&area)
        .caption(title, bold(18.0))
        .margin(6)
        .margin_right(22)
        .x_label_area_size(55)
        .y_label_area_size(75)
        .build_cartesian_2d(lo..hi, 0.0..top)?;
    let dx = decimals(hi - lo);
    let fx = move |x: &f64| tick(*x, dx);
    let fy = |y: &f64| {
        if y.fract() == 0.0 {
            format!("{y:.0}")
        } else {
            String::new()
        }
    };
    let x_desc = if outside > 0 {
        format!("E_{name} [%] ({outside} of {} outside)", v.len())
    } else {
        format!("E_{name} [%]")
    };
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc("samples")
        .label_style(font(16.0))
        .axis_desc_style(font(17.0))
        .x_label_formatter(&fx)
        .y_label_formatter(&fy)
        .x_labels(6)
        .y_labels(6)
        .light_line_style(WHITE)
        .bold_line_style(GRID)
        .draw()?;
    chart.draw_series(counts.iter().enumerate().filter(|(_, &k)| k > 0).map(|(b, &k)| {
        let x0 = lo + b as f64 * width;
        Rectangle::new([(x0, 0.0), (x0 + width, k as f64)], c.mix(0.75).filled())
    }))?;
    if lo < 0.0 && hi > 0.0 {
        chart.draw_series(std::iter::once(PathElement::new(
            vec![(0.0, 0.0), (0.0, top)],
            BLACK.stroke_width(1),
        )))?;
    }
    if med >= lo && med <= hi {
        chart.draw_series(std::iter::once(PathElement::new(
            vec![(med, 0.0), (med, top)],
            RED.stroke_width(2),
        )))?;
    }
    Ok(())
}

/// A percentage with three significant digits (at least one decimal below 100).
fn pct_str(p: f64) -> String {
    let a = p.abs();
    let d = if a >= 100.0 {
        0
    } else if a >= 10.0 {
        1
    } else if a >= 1.0 || a == 0.0 {
        2
    } else {
        (2.0 - a.log10().floor()).min(6.0) as usize
    };
    format!("{p:.d$}")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::Error;
    use crate::util::hash::SplitMix;
    use std::fs;
    use std::path::PathBuf;

    /// A fresh directory; kept when BLOCKFLOW_KEEP_PLOTS is set (to look at the figures), removed otherwise.
    struct Scratch(PathBuf);

    impl Scratch {
        fn new(name: &str) -> Self {
            let nanos = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .unwrap()
                .subsec_nanos();
            let dir = std::env::temp_dir().join(format!("blockflow_plots_{name}_{}_{nanos}", std::process::id()));
            fs::create_dir_all(&dir).unwrap();
            Scratch(dir)
        }
    }

    impl Drop for Scratch {
        fn drop(&mut self) {
            if std::env::var_os("BLOCKFLOW_KEEP_PLOTS").is_some() {
                eprintln!("plots kept in {}", self.0.display());
            } else {
                let _ = fs::remove_dir_all(&self.0);
            }
        }
    }

    /// Asserts a PNG signature and the IHDR width and height.
    fn assert_png(path: &Path, size: (u32, u32)) {
        let b = fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        assert!(b.len() > 24, "{} too short", path.display());
        assert_eq!(&b[..8], b"\x89PNG\r\n\x1a\n", "{} is not a PNG", path.display());
        assert_eq!(&b[12..16], b"IHDR");
        let w = u32::from_be_bytes(b[16..20].try_into().unwrap());
        let h = u32::from_be_bytes(b[20..24].try_into().unwrap());
        assert_eq!((w, h), size, "{}", path.display());
    }

    fn synthetic_blocks() -> Vec<BlockSeries> {
        let mut rng = SplitMix(7);
        let mut out = Vec::new();
        for row in 0..5 {
            for b in 0..4 {
                let base = 32768.0 * (1.0 - 0.22 * row as f64) - 300.0 * b as f64;
                let points = (0..=200)
                    .map(|k| {
                        let t = k as f64 / 100.0;
                        let dip = 4000.0 * (-(t - 0.4 * row as f64).powi(2) * 8.0).exp();
                        let f = (base - dip).max(0.0);
                        let m = 2e-3 + 4.5e-7 * f + 2e-4 * rng.unit();
                        (t, f, m)
                    })
                    .collect();
                out.push(BlockSeries { row, points });
            }
        }
        out
    }

    fn synthetic_shares() -> Vec<(String, Vec<f64>)> {
        let mut rng = SplitMix(11);
        let names = ["LBM", "BH", "Coup1", "Coup2", "RB"];
        let mut shares: Vec<Vec<f64>> = vec![Vec::new(); names.len()];
        for _ in 0..400 {
            let raw = [
                0.45 + 0.1 * rng.normal(),
                0.35 + 0.08 * rng.normal(),
                0.02 + 0.01 * rng.unit(),
                0.1 + 0.05 * rng.unit(),
                0.04 + 0.03 * rng.unit(),
            ];
            let raw: Vec<f64> = raw.iter().map(|x| x.max(0.001)).collect();
            let tot: f64 = raw.iter().sum();
            for (s, x) in shares.iter_mut().zip(&raw) {
                s.push(x / tot);
            }
        }
        names.iter().map(|n| n.to_string()).zip(shares).collect()
    }

    fn synthetic_errors() -> Vec<(String, Vec<f64>)> {
        let mut rng = SplitMix(13);
        let spec = [
            ("LBM", 0.01, 0.04),
            ("BH", -0.005, 0.03),
            ("Coup1", 0.0, 0.004),
            ("Coup2", 0.002, 0.01),
        ];
        let mut parts: Vec<(String, Vec<f64>)> = spec
            .iter()
            .map(|&(n, mu, s)| (n.to_string(), (0..500).map(|_| mu + s * rng.normal()).collect()))
            .collect();
        // RB: heavy tail, some far outside ±50 %.
        let mut rb: Vec<f64> = (0..500).map(|_| 0.01 * rng.normal()).collect();
        rb.extend([0.8, -0.9, 1.5]);
        parts.push(("RB".into(), rb));
        let total = (0..500).map(|i| parts.iter().map(|p| p.1[i]).sum()).collect();
        parts.push(("total".into(), total));
        parts
    }

    #[test]
    fn renders_all_three_figures() {
        let dir = Scratch::new("all");
        let p6 = dir.0.join("figure6.png");
        let p7 = dir.0.join("figure7.png");
        let p8 = dir.0.join("figure8.png");
        figure6(&p6, &synthetic_blocks()).unwrap();
        figure7(&p7, &synthetic_shares()).unwrap();
        let errors = synthetic_errors();
        figure8(&p8, &errors).unwrap();
        assert_png(&p6, FIGURE6_SIZE);
        assert_png(&p7, FIGURE7_SIZE);
        assert_png(&p8, figure8_size(errors.len()));
        assert_eq!(figure8_size(6), (1560, 940));
    }

    #[test]
    fn empty_input_is_an_error_and_writes_nothing() {
        let dir = Scratch::new("empty");
        let p = dir.0.join("f.png");
        for r in [
            figure6(&p, &[]),
            figure6(
                &p,
                &[BlockSeries {
                    row: 0,
                    points: vec![(f64::NAN, 1.0, 1.0)],
                }],
            ),
            figure7(&p, &[]),
            figure7(&p, &[("LBM".into(), vec![])]),
            figure8(&p, &[]),
            figure8(&p, &[("total".into(), vec![f64::INFINITY])]),
        ] {
            let e = r.unwrap_err();
            assert!(matches!(e, Error::Config(_)));
            assert!(
                e.to_string().contains("f.png") && e.to_string().contains("no data"),
                "{e}"
            );
        }
        assert!(!p.exists());
    }

    #[test]
    fn one_empty_part_among_others_is_drawn_empty() {
        let dir = Scratch::new("partial");
        let parts = vec![("LBM".to_string(), vec![0.5, 0.6, 0.4]), ("RB".to_string(), vec![])];
        let p7 = dir.0.join("f7.png");
        figure7(&p7, &parts).unwrap();
        assert_png(&p7, FIGURE7_SIZE);
        let p8 = dir.0.join("f8.png");
        figure8(
            &p8,
            &[
                ("LBM".to_string(), vec![0.01, -0.02, 0.0]),
                ("RB".to_string(), vec![]),
                ("total".to_string(), vec![0.0]),
            ],
        )
        .unwrap();
        assert_png(&p8, figure8_size(3));
        let p6 = dir.0.join("f6.png");
        let series = vec![
            BlockSeries {
                row: 0,
                points: vec![(0.0, 10.0, 1e-3)],
            },
            BlockSeries { row: 1, points: vec![] },
        ];
        figure6(&p6, &series).unwrap();
        assert_png(&p6, FIGURE6_SIZE);
    }

    #[test]
    fn unwritable_path_names_the_file() {
        let p = std::env::temp_dir().join("blockflow_plots_no_such_dir_x").join("f.png");
        let e = figure7(&p, &[("LBM".into(), vec![0.5])]).unwrap_err();
        assert!(matches!(e, Error::Io(_)));
        assert!(e.to_string().contains("blockflow_plots_no_such_dir_x"), "{e}");
    }

    #[test]
    fn statistics() {
        assert_eq!(median_mad(&[]), None);
        assert_eq!(median_mad(&[f64::NAN]), None);
        // median 3, deviations 2 1 0 1 97 -> MAD 1
        assert_eq!(median_mad(&[1.0, 2.0, 3.0, 4.0, 100.0, f64::NAN]), Some((3.0, 1.0)));
        assert_eq!(median_mad(&[1.0, 2.0, 3.0, 4.0]), Some((2.5, 1.0)));
        let s: Vec<f64> = (0..=100).map(f64::from).collect();
        assert_eq!(quantile(&s, 0.05), 5.0);
        assert_eq!(quantile(&s, 0.95), 95.0);
        assert_eq!(quantile(&[1.0, 2.0], 0.25), 1.25);
        assert_eq!(figure8_grid(6), (2, 3));
        assert_eq!(figure8_grid(1), (1, 1));
        assert_eq!(figure8_grid(3), (1, 3));
        let (lo, hi) = histogram_range(&s);
        assert!(lo < 0.0 && (50.0..52.0).contains(&hi), "{lo} {hi}");
        let far: Vec<f64> = (0..10).map(|i| 60.0 + i as f64).collect();
        let (lo, hi) = histogram_range(&far);
        assert!(lo > 55.0 && hi < 75.0, "{lo} {hi}");
        assert_eq!(pct_str(1.234), "1.23");
        assert_eq!(pct_str(0.01234), "0.0123");
        assert_eq!(pct_str(-12.34), "-12.3");
    }
}
