//! PNG figures of one run, from its intervals:
//! - [`balance_figure`] (`balance.png`): the load imbalance eq. (18) per interval, measured and as the
//!   block weights predicted it, above each process's workload (eq. 16) per interval;
//! - [`parts_figure`] (`parts.png`): the task CPU time of each part of the step per interval.
//!
//! Same conventions as [`super`]: embedded font, non-finite values skipped, an error naming the file when
//! there is nothing to draw.

use super::{canvas, colour, legend_strip, legend_width, line_panel, range, render};
use crate::error::{Error, Result};
use crate::metrics::interval::IntervalStats;
use crate::physics::parts::Part;
use plotters::prelude::*;
use std::path::Path;

/// Size of [`balance_figure`] in pixels.
pub const BALANCE_FIGURE_SIZE: (u32, u32) = (1400, 1100);
/// Size of [`parts_figure`] in pixels.
pub const PARTS_FIGURE_SIZE: (u32, u32) = (1400, 800);

/// Processes drawn one line each; with more, the figure shows the lightest, mean and heaviest process.
const PROCESS_LINES: usize = 10;

/// Least width of the legend strip on the right.
const LEGEND_WIDTH: u32 = 260;

/// `balance.png`: load imbalance per interval (measured; predicted where the assignment came from
/// weights) and each process's workload per interval, against the interval's last step.
pub fn balance_figure(path: &Path, intervals: &[IntervalStats]) -> Result<()> {
    let end = |iv: &IntervalStats| iv.end as f64;
    let measured: Vec<(f64, f64)> = intervals.iter().map(|iv| (end(iv), 100.0 * iv.imbalance)).collect();
    let predicted: Vec<(f64, f64)> = intervals
        .iter()
        .map(|iv| (end(iv), 100.0 * iv.predicted_imbalance))
        .filter(|p| p.1.is_finite())
        .collect();
    let procs = intervals.first().map_or(0, |iv| iv.process_load.len());
    let (load_lines, load_names): (Vec<Vec<(f64, f64)>>, Vec<String>) = if procs <= PROCESS_LINES {
        (0..procs)
            .map(|p| {
                let pts = intervals.iter().map(|iv| (end(iv), iv.process_load[p])).collect();
                (pts, format!("process {p}"))
            })
            .unzip()
    } else {
        let stat = |f: fn(&[f64]) -> f64| intervals.iter().map(|iv| (end(iv), f(&iv.process_load))).collect();
        (
            vec![stat(min_of), stat(mean_of), stat(max_of)],
            vec!["lightest".into(), "mean".into(), "heaviest".into()],
        )
    };
    let xs = || intervals.iter().map(end);
    let (Some((x0, x1)), Some((_, li_max)), Some((_, load_max))) = (
        range(xs()),
        range(measured.iter().chain(&predicted).map(|p| p.1)),
        range(load_lines.iter().flatten().map(|p| p.1)),
    ) else {
        return Err(Error::Config(format!(
            "{}: load balance: no data to plot",
            path.display()
        )));
    };
    let (x0, x1) = widen(x0, x1);
    render(path, || {
        let title = "Load balance per interval";
        let (base, root) = canvas(path, BALANCE_FIGURE_SIZE, title)?;
        let (top, bottom) = root.split_vertically(BALANCE_FIGURE_SIZE.1 / 2 - 20);
        let li_names = ["measured".to_string(), "predicted by the weights".to_string()];
        let legend_px = legend_width(&li_names, 16.0, LEGEND_WIDTH, BALANCE_FIGURE_SIZE.0);
        let (li_plot, li_legend) = top.split_horizontally(BALANCE_FIGURE_SIZE.0 - legend_px);
        let li_lines = vec![(colour(0), measured.clone()), (colour(1), predicted.clone())];
        line_panel(
            &li_plot,
            "load imbalance eq. (18): heaviest process / mean - 1",
            "time step (end of interval)",
            "LI (%)",
            (x0, x1),
            (0.0, headroom(li_max)),
            &li_lines,
        )?;
        legend_strip(&li_legend, "load imbalance", &li_names, 16.0)?;
        let (load_plot, load_legend) = bottom.split_horizontally(BALANCE_FIGURE_SIZE.0 - legend_px);
        let coloured: Vec<(RGBColor, Vec<(f64, f64)>)> = load_lines
            .iter()
            .enumerate()
            .map(|(i, pts)| (colour(i), pts.clone()))
            .collect();
        line_panel(
            &load_plot,
            "workload eq. (16) per process: task CPU time without the exchange",
            "time step (end of interval)",
            "seconds per interval",
            (x0, x1),
            (0.0, headroom(load_max)),
            &coloured,
        )?;
        legend_strip(&load_legend, "workload", &load_names, 16.0)?;
        base.present()?;
        Ok(())
    })
}

/// `parts.png`: task CPU seconds of every part of the step (LBM, boundary, exchange, map, reconstruct,
/// rigid body) per interval; parts that took no time are left out.
pub fn parts_figure(path: &Path, intervals: &[IntervalStats]) -> Result<()> {
    let parts: Vec<(Part, Vec<(f64, f64)>)> = Part::ALL
        .iter()
        .filter(|&&p| intervals.iter().any(|iv| iv.part_seconds[p] > 0.0))
        .map(|&p| {
            (
                p,
                intervals.iter().map(|iv| (iv.end as f64, iv.part_seconds[p])).collect(),
            )
        })
        .collect();
    let (Some((x0, x1)), Some((_, ymax))) = (
        range(intervals.iter().map(|iv| iv.end as f64)),
        range(parts.iter().flat_map(|(_, pts)| pts.iter().map(|p| p.1))),
    ) else {
        return Err(Error::Config(format!(
            "{}: time per part: no data to plot",
            path.display()
        )));
    };
    let (x0, x1) = widen(x0, x1);
    render(path, || {
        let (base, root) = canvas(path, PARTS_FIGURE_SIZE, "Time per part of the step, per interval")?;
        let (plot, legend) = root.split_horizontally(PARTS_FIGURE_SIZE.0 - LEGEND_WIDTH);
        let coloured: Vec<(RGBColor, Vec<(f64, f64)>)> = parts
            .iter()
            .enumerate()
            .map(|(i, (_, pts))| (colour(i), pts.clone()))
            .collect();
        line_panel(
            &plot,
            "",
            "time step (end of interval)",
            "task CPU seconds per interval",
            (x0, x1),
            (0.0, headroom(ymax)),
            &coloured,
        )?;
        let names: Vec<String> = parts.iter().map(|(p, _)| p.label().to_string()).collect();
        legend_strip(&legend, "part", &names, 18.0)?;
        base.present()?;
        Ok(())
    })
}

/// An x range of at least one unit (a run of one interval).
fn widen(x0: f64, x1: f64) -> (f64, f64) {
    if x1 > x0 {
        (x0, x1)
    } else {
        (x0 - 1.0, x1 + 1.0)
    }
}

/// The top of a y axis from 0: 8 % above the largest value.
fn headroom(max: f64) -> f64 {
    if max > 0.0 {
        max * 1.08
    } else {
        1.0
    }
}

fn min_of(v: &[f64]) -> f64 {
    v.iter().copied().fold(f64::INFINITY, f64::min)
}

fn max_of(v: &[f64]) -> f64 {
    v.iter().copied().fold(f64::NEG_INFINITY, f64::max)
}

fn mean_of(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::parts::ByPart;

    fn interval(end: u64, load: [f64; 2], predicted: f64) -> IntervalStats {
        let mean = 0.5 * (load[0] + load[1]);
        IntervalStats {
            start: end - 100,
            end,
            process_load: load.to_vec(),
            imbalance: load[0].max(load[1]) / mean - 1.0,
            predicted_imbalance: predicted,
            part_seconds: ByPart([0.5, 0.2, 0.1, 0.05, 0.03, 0.0]),
            ..Default::default()
        }
    }

    #[test]
    fn run_figures_are_pngs_of_their_size_and_empty_input_is_an_error() {
        let dir = std::env::temp_dir().join(format!("blockflow-run-fig-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let ivs = vec![
            interval(100, [1.0, 0.2], f64::NAN),
            interval(200, [0.6, 0.55], 0.05),
            interval(300, [0.58, 0.6], 0.02),
        ];
        for (f, name, size) in [
            (
                balance_figure as fn(&Path, &[IntervalStats]) -> Result<()>,
                "balance.png",
                BALANCE_FIGURE_SIZE,
            ),
            (parts_figure, "parts.png", PARTS_FIGURE_SIZE),
        ] {
            let p = dir.join(name);
            f(&p, &ivs).unwrap();
            let img = image_size(&std::fs::read(&p).unwrap());
            assert_eq!(img, size, "{name}");
            assert!(f(&dir.join("empty.png"), &[]).is_err());
        }
        assert!(!dir.join("empty.png").exists());
        std::fs::remove_dir_all(&dir).ok();
    }

    /// Width and height from a PNG's IHDR chunk (bytes 16..24, big-endian), after checking the signature.
    fn image_size(png: &[u8]) -> (u32, u32) {
        assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
        let be = |i: usize| u32::from_be_bytes(png[i..i + 4].try_into().unwrap());
        (be(16), be(20))
    }
}
