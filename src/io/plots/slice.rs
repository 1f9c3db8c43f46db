//! A snapshot of a run as a picture, like LAMMPS' `dump image`: one plane of cells coloured by the
//! velocity magnitude, walls and cells outside the fluid in greys, the spheres the plane cuts drawn as
//! circles of their cut radius, and the blocks the plane cuts outlined in the colour of the process that
//! owns them. [`render`] draws a [`Slice`] into an RGB buffer (for a PNG and a GIF frame at once),
//! [`write_png`] saves one.

use super::{bold, colour, font, tick, Area, DrawResult, GRID};
use crate::error::{Error, Result};
use plotters::prelude::*;
use plotters::style::colors::colormaps::ViridisRGB;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::path::Path;

/// What one cell of the plane shows.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SliceCell {
    /// A fluid cell with its velocity magnitude (lattice units).
    Fluid(f64),
    /// A cell covered by a sphere.
    Particle,
    /// A wall cell next to fluid (resting or moving).
    Wall,
    /// A solid cell with no fluid neighbour.
    Outside,
}

/// One plane of cells with the spheres and blocks it cuts, in cell coordinates of the plane: `u` along
/// the horizontal axis, `v` along the vertical one, the first cell spanning [0, 1] × [0, 1].
#[derive(Clone, Debug)]
pub struct Slice {
    /// The heading above the picture (scene, step, time, plane).
    pub title: String,
    /// Names of the horizontal and vertical axes (e.g. "x", "z").
    pub axes: [&'static str; 2],
    /// Cells along the horizontal and vertical axes.
    pub size: [usize; 2],
    /// One per cell, rows from the bottom: index `v * size[0] + u`.
    pub cells: Vec<SliceCell>,
    /// Spheres cut by the plane: centre (u, v) and radius of the cut circle, cells.
    pub circles: Vec<[f64; 3]>,
    /// Blocks cut by the plane: [u0, v0, u1, v1] in cells and the owning process.
    pub blocks: Vec<([f64; 4], u32)>,
    /// Number of processes (for the legend).
    pub processes: usize,
    /// Whether the scene has bodies: the legend names sphere cells and cut circles only then (the same
    /// in every picture of a run, so an animation's legend stays still).
    pub bodies: bool,
}

/// Width of the strip right of the plane: the colour bar and the legend.
const STRIP: u32 = 300;
/// The plane's longer side is drawn about this many pixels long (whole pixels per cell, 1 to 16).
const TARGET: usize = 760;
/// Processes named one by one in the legend; more are summed up in one line.
const LEGEND_PROCESSES: usize = 8;
/// The grey of wall cells and of cells outside the fluid.
const WALL: RGBColor = RGBColor(150, 150, 150);
const OUTSIDE: RGBColor = RGBColor(70, 70, 70);
/// The fill of cells under a sphere.
const PARTICLE: RGBColor = RGBColor(235, 235, 235);

/// Pixels per cell for a plane of `size` cells.
fn scale(size: [usize; 2]) -> u32 {
    (TARGET / size[0].max(size[1]).max(1)).clamp(1, 16) as u32
}

/// The picture's size in pixels for a plane of `size` cells: the plane at whole pixels per cell, axis
/// labels and a heading around it, the strip on the right; at least 520 px high for the legend.
pub fn image_size(size: [usize; 2]) -> (u32, u32) {
    let s = scale(size);
    let (w, h) = (size[0] as u32 * s, size[1] as u32 * s);
    (w + 100 + STRIP, (h + 130).max(520))
}

/// The colour of a velocity magnitude `m` on a scale from 0 to `max` (viridis).
fn speed_colour(m: f64, max: f64) -> RGBColor {
    let h = if max > 0.0 { (m / max).clamp(0.0, 1.0) } else { 0.0 };
    ViridisRGB::get_color(h)
}

/// Draws `slice` into a new RGB buffer of [`image_size`]; returns the buffer and its size. The colour
/// scale runs from 0 to the largest velocity magnitude in the plane.
pub fn render(slice: &Slice) -> Result<(Vec<u8>, (u32, u32))> {
    let (w, h) = image_size(slice.size);
    if slice.cells.len() != slice.size[0] * slice.size[1] {
        return Err(Error::Io(format!(
            "slice picture: {} cells for a plane of {} x {}",
            slice.cells.len(),
            slice.size[0],
            slice.size[1]
        )));
    }
    let mut buf = vec![0u8; w as usize * h as usize * 3];
    super::ensure_font().map_err(|e| Error::Io(format!("slice picture: {e}")))?;
    draw(&mut buf, (w, h), slice).map_err(|e| Error::Io(format!("slice picture: {e}")))?;
    Ok((buf, (w, h)))
}

fn draw(buf: &mut [u8], (w, h): (u32, u32), slice: &Slice) -> DrawResult {
    let root = BitMapBackend::with_buffer(buf, (w, h)).into_drawing_area();
    root.fill(&WHITE)?;
    let inner = root.margin(10, 6, 6, 6).titled(&slice.title, bold(22.0))?;
    let (plane, strip) = inner.split_horizontally(inner.dim_in_pixel().0 - STRIP);
    let max = slice
        .cells
        .iter()
        .filter_map(|c| match c {
            SliceCell::Fluid(m) if m.is_finite() => Some(*m),
            _ => None,
        })
        .fold(0.0, f64::max);
    draw_plane(&plane, slice, max)?;
    draw_strip(&strip, slice, max)?;
    root.present()?;
    Ok(())
}

fn draw_plane(area: &Area, slice: &Slice, max: f64) -> DrawResult {
    let [nu, nv] = slice.size;
    let (nuf, nvf) = (nu as f64, nv as f64);
    let s = scale(slice.size);
    // The plotting area is the area less the margins (10 + 10 + 6) and the label areas (70, 50); the
    // area is shrunk until that is the plane at whole pixels per cell, square cells.
    let (aw, ah) = area.dim_in_pixel();
    let (pw, ph) = (aw.saturating_sub(90), ah.saturating_sub(56));
    let (dw, dh) = (pw.saturating_sub(nu as u32 * s), ph.saturating_sub(nv as u32 * s));
    let fitted = area.margin(0, dh, 0, dw);
    let mut chart = ChartBuilder::on(&fitted)
        .margin_left(10)
        .margin_right(10)
        .margin_top(6)
        .x_label_area_size(50)
        .y_label_area_size(70)
        .build_cartesian_2d(0.0..nuf, 0.0..nvf)?;
    let fmt = |v: &f64| tick(*v, 0);
    chart
        .configure_mesh()
        .disable_mesh()
        .x_desc(format!("{} (cells)", slice.axes[0]))
        .y_desc(format!("{} (cells)", slice.axes[1]))
        .label_style(font(16.0))
        .axis_desc_style(font(18.0))
        .x_label_formatter(&fmt)
        .y_label_formatter(&fmt)
        .x_labels(8)
        .y_labels(8)
        .draw()?;
    let cell_colour = |c: &SliceCell| match c {
        SliceCell::Fluid(m) => speed_colour(*m, max),
        SliceCell::Particle => PARTICLE,
        SliceCell::Wall => WALL,
        SliceCell::Outside => OUTSIDE,
    };
    chart.draw_series((0..nv).flat_map(|v| (0..nu).map(move |u| (u, v))).map(|(u, v)| {
        let c = cell_colour(&slice.cells[v * nu + u]);
        let (x, y) = (u as f64, v as f64);
        Rectangle::new([(x, y), (x + 1.0, y + 1.0)], c.filled())
    }))?;
    let inside = |(u, v): (f64, f64)| (0.0..=nuf).contains(&u) && (0.0..=nvf).contains(&v);
    for &[cu, cv, r] in &slice.circles {
        // Outlines are cut where they leave the plane, so that no line is drawn outside the axes.
        let n = ((r * s as f64 * 0.8) as usize).clamp(24, 256);
        let mut run: Vec<(f64, f64)> = Vec::new();
        for k in 0..=n {
            let phi = std::f64::consts::TAU * k as f64 / n as f64;
            let p = (cu + r * phi.cos(), cv + r * phi.sin());
            if inside(p) {
                run.push(p);
            } else if run.len() > 1 {
                chart.draw_series(std::iter::once(PathElement::new(
                    std::mem::take(&mut run),
                    BLACK.stroke_width(2),
                )))?;
            } else {
                run.clear();
            }
        }
        if run.len() > 1 {
            chart.draw_series(std::iter::once(PathElement::new(run, BLACK.stroke_width(2))))?;
        }
    }
    let root = chart.plotting_area().strip_coord_spec();
    let (ox, oy) = chart.plotting_area().get_base_pixel();
    for &([u0, v0, u1, v1], owner) in &slice.blocks {
        let to_px = |u: f64, v: f64| {
            let (x, y) = chart.backend_coord(&(u, v));
            (x - ox, y - oy)
        };
        let (a, b) = (to_px(u0, v1), to_px(u1, v0));
        // Inset by one pixel so that neighbouring blocks of different processes both show.
        let style = colour(owner as usize).stroke_width(2);
        root.draw(&Rectangle::new([(a.0 + 1, a.1 + 1), (b.0 - 1, b.1 - 1)], style))?;
    }
    Ok(())
}

fn draw_strip(area: &Area, slice: &Slice, max: f64) -> DrawResult {
    area.draw(&Text::new("|u| (lattice units)", (10, 20), bold(17.0)))?;
    let (top, bottom, left) = (50, 250, 14);
    for k in 0..(bottom - top) {
        let h = 1.0 - k as f64 / (bottom - top - 1) as f64;
        let c = ViridisRGB::get_color(h);
        area.draw(&Rectangle::new([(left, top + k), (left + 28, top + k + 1)], c.filled()))?;
    }
    area.draw(&Rectangle::new(
        [(left, top), (left + 28, bottom)],
        GRID.stroke_width(1),
    ))?;
    let digits = super::decimals(max);
    for k in 0..=4 {
        let y = bottom - (bottom - top) * k / 4;
        let label = font(15.0).pos(Pos::new(HPos::Left, VPos::Center));
        area.draw(&Text::new(tick(max * k as f64 / 4.0, digits), (left + 36, y), label))?;
    }
    let mut y = bottom + 40;
    let label = font(15.0).pos(Pos::new(HPos::Left, VPos::Center));
    area.draw(&Text::new("blocks, by owner", (10, y), bold(17.0)))?;
    y += 28;
    for p in 0..slice.processes.min(LEGEND_PROCESSES) {
        area.draw(&Rectangle::new(
            [(left, y - 8), (left + 28, y + 8)],
            colour(p).stroke_width(2),
        ))?;
        area.draw(&Text::new(format!("process {p}"), (left + 40, y), label.clone()))?;
        y += 24;
    }
    if slice.processes > LEGEND_PROCESSES {
        area.draw(&Text::new(
            format!("… {} processes in all (colours repeat)", slice.processes),
            (left, y),
            label.clone(),
        ))?;
        y += 24;
    }
    y += 12;
    // Only what can appear: walls and outside cells where the plane has them, sphere cells where the
    // scene has bodies.
    let has = |kind: SliceCell| slice.cells.contains(&kind);
    let fills = [
        (PARTICLE, "under a sphere", slice.bodies),
        (WALL, "wall", has(SliceCell::Wall)),
        (OUTSIDE, "outside the fluid", has(SliceCell::Outside)),
    ];
    for (c, name, _) in fills.into_iter().filter(|f| f.2) {
        area.draw(&Rectangle::new([(left, y - 8), (left + 28, y + 8)], c.filled()))?;
        area.draw(&Text::new(name, (left + 40, y), label.clone()))?;
        y += 24;
    }
    if slice.bodies {
        area.draw(&Circle::new((left + 14, y), 8, BLACK.stroke_width(2)))?;
        area.draw(&Text::new("sphere cut by the plane", (left + 40, y), label))?;
    }
    Ok(())
}

/// Writes an RGB buffer of `size` as a PNG file.
pub fn write_png(path: &Path, rgb: &[u8], size: (u32, u32)) -> Result<()> {
    image::save_buffer_with_format(
        path,
        rgb,
        size.0,
        size.1,
        image::ColorType::Rgb8,
        image::ImageFormat::Png,
    )
    .map_err(|e| Error::Io(format!("{}: cannot write the picture: {e}", path.display())))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn slice() -> Slice {
        let size = [20, 30];
        let cells = (0..size[0] * size[1])
            .map(|i| match i % 7 {
                0 => SliceCell::Wall,
                1 => SliceCell::Outside,
                2 => SliceCell::Particle,
                k => SliceCell::Fluid(0.01 * k as f64),
            })
            .collect();
        Slice {
            title: "test".into(),
            axes: ["x", "z"],
            size,
            cells,
            circles: vec![[10.0, 15.0, 4.0], [0.0, 0.0, 3.0]],
            blocks: vec![([0.0, 0.0, 10.0, 30.0], 0), ([10.0, 0.0, 20.0, 30.0], 1)],
            processes: 2,
            bodies: true,
        }
    }

    #[test]
    fn cells_are_whole_pixels_and_coloured_by_speed() {
        let s = slice();
        let (buf, (w, h)) = render(&s).unwrap();
        assert_eq!((w, h), image_size(s.size));
        assert_eq!(buf.len(), (w * h * 3) as usize);
        // 760 / 30 = 25, clamped to 16 pixels per cell.
        assert_eq!(scale(s.size), 16);
        // The fastest cell value (0.06) takes the top of the scale, the brightest viridis yellow.
        let top = ViridisRGB::get_color(1.0);
        let has = |c: RGBColor| buf.chunks(3).any(|p| p == [c.0, c.1, c.2]);
        assert!(has(top) && has(WALL) && has(OUTSIDE) && has(PARTICLE));
        assert!(has(colour(0)) && has(colour(1)), "both owners' outlines are drawn");
    }

    #[test]
    fn a_wrong_cell_count_is_refused() {
        let mut s = slice();
        s.cells.pop();
        assert!(render(&s).is_err());
    }
}
