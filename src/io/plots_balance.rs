//! PNG figures of the load-balancing study (section 4.3 of the paper, issue #8 point 5):
//! - [`figure10`]: modeled run time per interval, one line per strategy;
//! - [`figure11`]: load imbalance eq. (18) per interval, one line per strategy.
//!
//! Same conventions as [`super::plots`]: embedded font, non-finite values skipped, an error naming the
//! file when there is nothing to draw.

use super::plots::{bold, canvas, colour, decimals, font, range, render, tick, GRID};
use crate::error::{Error, Result};
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
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
    render(path, || {
        let (base, root) = canvas(path, STUDY_FIGURE_SIZE, title)?;
        let (plot, legend) = root.split_horizontally(STUDY_FIGURE_SIZE.0 - 220);
        let mut c = ChartBuilder::on(&plot)
            .margin(12)
            .margin_right(30)
            .x_label_area_size(60)
            .y_label_area_size(110)
            .build_cartesian_2d(x0..x1, 0.0..y1)?;
        let (dx, dy) = (decimals(x1 - x0), decimals(y1));
        let fx = move |v: &f64| tick(*v, dx);
        let fy = move |v: &f64| tick(*v, dy);
        c.configure_mesh()
            .x_desc("time step (end of interval)")
            .y_desc(y_desc)
            .label_style(font(17.0))
            .axis_desc_style(font(19.0))
            .x_label_formatter(&fx)
            .y_label_formatter(&fy)
            .x_labels(8)
            .y_labels(8)
            .light_line_style(WHITE)
            .bold_line_style(GRID)
            .draw()?;
        for (i, (_, pts)) in lines.iter().enumerate() {
            let col = colour(i);
            c.draw_series(LineSeries::new(pts.iter().copied(), col.stroke_width(2)))?;
            c.draw_series(pts.iter().map(|&p| Circle::new(p, 3, col.filled())))?;
        }
        legend.draw(&Text::new("strategy", (12, 60), bold(18.0)))?;
        for (i, (name, _)) in lines.iter().enumerate() {
            let y = 100 + 32 * i as i32;
            legend.draw(&PathElement::new(vec![(12, y), (52, y)], colour(i).stroke_width(4)))?;
            let label = font(18.0).pos(Pos::new(HPos::Left, VPos::Center));
            legend.draw(&Text::new(name.clone(), (62, y), label))?;
        }
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
