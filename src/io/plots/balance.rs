//! PNG figures of the load-balancing study (section 4.3 of the paper):
//! - [`figure10`]: modeled run time per interval, one line per strategy;
//! - [`figure11`]: load imbalance eq. (18) per interval, one line per strategy.
//!
//! Same conventions as [`super`]: embedded font, non-finite values skipped, an error naming the
//! file when there is nothing to draw.

use super::{canvas, colour, legend_strip, legend_width, line_panel, range, render};
use crate::error::{Error, Result};
use plotters::prelude::*;
use std::path::Path;

/// Size of [`figure10`] and [`figure11`] in pixels.
pub const STUDY_FIGURE_SIZE: (u32, u32) = (1400, 800);

/// One line: a strategy's name and its (interval end step, value) points.
pub type StrategyLine = (String, Vec<(f64, f64)>);

/// Figure 10: modeled seconds per interval (`lines`: per strategy, interval end step and seconds).
pub fn figure10(path: &Path, lines: &[StrategyLine]) -> Result<()> {
    chart(
        path,
        "Run time per interval (modeled)",
        "seconds per interval",
        1.0,
        lines,
    )
}

/// Figure 11: load imbalance eq. (18) per interval, in percent.
pub fn figure11(path: &Path, lines: &[StrategyLine]) -> Result<()> {
    chart(path, "Load imbalance per interval", "LI (%)", 100.0, lines)
}

fn chart(path: &Path, title: &str, y_desc: &str, scale: f64, lines: &[StrategyLine]) -> Result<()> {
    let lines: Vec<(String, Vec<(f64, f64)>)> = lines
        .iter()
        .map(|(n, pts)| {
            let p = pts
                .iter()
                .map(|&(x, y)| (x, y * scale))
                .filter(|(x, y)| x.is_finite() && y.is_finite())
                .collect();
            (n.clone(), p)
        })
        .collect();
    let all = || lines.iter().flat_map(|l| l.1.iter());
    let (Some((x0, x1)), Some((_, ymax))) = (range(all().map(|p| p.0)), range(all().map(|p| p.1))) else {
        return Err(Error::Config(format!("{}: {title}: no data to plot", path.display())));
    };
    let y1 = if ymax > 0.0 { ymax * 1.08 } else { 1.0 };
    let (x0, x1) = if x1 > x0 { (x0, x1) } else { (x0 - 1.0, x1 + 1.0) };
    let names: Vec<String> = lines.iter().map(|l| l.0.clone()).collect();
    let legend_px = legend_width(&names, 18.0, 220, STUDY_FIGURE_SIZE.0);
    render(path, || {
        let (base, root) = canvas(path, STUDY_FIGURE_SIZE, title)?;
        let (plot, legend) = root.split_horizontally(STUDY_FIGURE_SIZE.0 - legend_px);
        let coloured: Vec<(RGBColor, Vec<(f64, f64)>)> = lines
            .iter()
            .enumerate()
            .map(|(i, (_, p))| (colour(i), p.clone()))
            .collect();
        line_panel(
            &plot,
            "",
            "time step (end of interval)",
            y_desc,
            (x0, x1),
            (0.0, y1),
            &coloured,
        )?;
        legend_strip(&legend, "strategy", &names, 18.0)?;
        base.present()?;
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn figures_are_pngs_and_empty_input_is_an_error() {
        let dir = std::env::temp_dir().join(format!("blockflow-study-fig-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let lines = vec![
            ("none".to_string(), vec![(100.0, 0.6), (200.0, 0.62)]),
            ("hilbert".to_string(), vec![(100.0, 0.6), (200.0, 0.1)]),
        ];
        for (f, name) in [
            (figure10 as fn(&Path, &[StrategyLine]) -> Result<()>, "f10.png"),
            (figure11, "f11.png"),
        ] {
            let p = dir.join(name);
            f(&p, &lines).unwrap();
            let bytes = std::fs::read(&p).unwrap();
            assert_eq!(&bytes[1..4], b"PNG");
            assert!(f(&dir.join("empty.png"), &[("x".to_string(), vec![])]).is_err());
        }
        assert!(!dir.join("empty.png").exists());
        std::fs::remove_dir_all(&dir).ok();
    }
}
