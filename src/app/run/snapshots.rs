//! Pictures of a run as it goes (`--png EVERY`, `run.png_every`): one plane of the flow every so many
//! steps as `OUT/slices/step-<step>.png` and all of them as `OUT/slices.gif`, like LAMMPS' `dump image`.

use crate::config::Config;
use crate::error::{io_err, Error, Result};
use crate::io::animation::Animation;
use crate::io::plots::slice::{self, Slice, SliceCell};
use crate::physics::geometry::flags;
use crate::physics::simulation::Simulation;
use crate::ranks::views;
use crate::ranks::World;
use crate::scenes::Units;
use crate::timeloop::{Flow, Observer, RunContext, RunEnd};
use blockflow_kernels::rigid::Body;
use blockflow_kernels::Real;
use std::path::{Path, PathBuf};

/// Each picture stays this many hundredths of a second in the GIF.
const FRAME_DELAY: u16 = 25;

/// The pictured plane: the axis normal to it and its cell index along that axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Plane {
    /// 0, 1, 2 for x, y, z.
    pub normal: usize,
    /// Cell index along the normal.
    pub at: usize,
}

const AXES: [&str; 3] = ["x", "y", "z"];

/// The default normal of the pictured plane: the thinnest axis where it has less than half the cells
/// of the longest (a channel, a 2D scene; ties go to z, then y), else y (a vertical plane, gravity
/// along z).
fn default_normal(cells: [usize; 3]) -> usize {
    let longest = *cells.iter().max().expect("three axes");
    let thinnest = [2, 1, 0].into_iter().min_by_key(|&k| cells[k]).expect("three axes");
    if 2 * cells[thinnest] < longest {
        thinnest
    } else {
        1
    }
}

impl Plane {
    /// The plane `run.png_normal` / `run.png_at` name in a domain of `cells`, with their defaults; the
    /// message names the key when the index lies outside the domain.
    pub fn of(cfg: &Config, cells: [usize; 3]) -> Result<Plane> {
        let normal = match cfg.run.png_normal.as_deref() {
            Some("x") => 0,
            Some("y") => 1,
            Some("z") => 2,
            Some(other) => {
                return Err(Error::Config(format!(
                    "run.png_normal = {other:?}: must be \"x\", \"y\" or \"z\""
                )))
            }
            None => default_normal(cells),
        };
        let at = cfg.run.png_at.unwrap_or(cells[normal] / 2);
        if at >= cells[normal] {
            return Err(Error::Config(format!(
                "run.png_at = {at}: the domain has {} cells along {}; give an index from 0 to {}",
                cells[normal],
                AXES[normal],
                cells[normal] - 1
            )));
        }
        Ok(Plane { normal, at })
    }

    /// The in-plane axes (horizontal, vertical), in x, y, z order.
    fn axes(&self) -> [usize; 2] {
        match self.normal {
            0 => [1, 2],
            1 => [0, 2],
            _ => [0, 1],
        }
    }
}

/// The cells of block `blk` (held by this process) in `plane`, row by row (v, then u), or `None` when
/// the plane misses the block.
fn block_plane<T: Real>(
    sim: &Simulation<T>,
    plane: Plane,
    blk: &crate::physics::block::Block<T>,
) -> Option<Vec<SliceCell>> {
    let [a, b] = plane.axes();
    let n = plane.normal;
    let (o, s) = (blk.origin, blk.layout.size);
    if plane.at < o[n] || plane.at >= o[n] + s[n] {
        return None;
    }
    let parity = sim.parity();
    let force = sim.params.force;
    let covered = blk.particle_cells();
    let mut out = Vec::with_capacity(s[a] * s[b]);
    for j in 0..s[b] {
        for i in 0..s[a] {
            let mut local = [0usize; 3];
            local[n] = plane.at - o[n] + 1;
            local[a] = i + 1;
            local[b] = j + 1;
            let idx = blk.layout.idx(local[0], local[1], local[2]);
            let f = blk.flags[idx];
            out.push(
                if covered.is_some_and(|pc| pc.owner.get(idx).is_some_and(|&w| w != 0)) {
                    SliceCell::Particle
                } else if f & flags::FLUID != 0 {
                    let (_, u) = crate::physics::fluid::cell_moments(blk, parity, idx, force);
                    SliceCell::Fluid((u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt())
                } else if f & (flags::NOSLIP | flags::MOVING_WALL) != 0 {
                    SliceCell::Wall
                } else {
                    SliceCell::Outside
                },
            );
        }
    }
    Some(out)
}

/// A block's plane cells as bytes (a tag per cell, and the speed of fluid cells); none: empty.
fn encode_plane(cells: Option<Vec<SliceCell>>) -> Vec<u8> {
    let mut v = Vec::new();
    for c in cells.into_iter().flatten() {
        match c {
            SliceCell::Fluid(x) => {
                v.push(0);
                v.extend_from_slice(&x.to_bits().to_le_bytes());
            }
            SliceCell::Particle => v.push(1),
            SliceCell::Wall => v.push(2),
            SliceCell::Outside => v.push(3),
        }
    }
    v
}

/// The cells of [`encode_plane`] (`None` for a block the plane misses).
fn decode_plane(b: &[u8]) -> Option<Vec<SliceCell>> {
    if b.is_empty() {
        return None;
    }
    let mut out = Vec::new();
    let mut at = 0;
    while at < b.len() {
        let tag = b[at];
        at += 1;
        out.push(match tag {
            0 => {
                let x = f64::from_bits(u64::from_le_bytes(b[at..at + 8].try_into().expect("8 bytes")));
                at += 8;
                SliceCell::Fluid(x)
            }
            1 => SliceCell::Particle,
            2 => SliceCell::Wall,
            _ => SliceCell::Outside,
        });
    }
    Some(out)
}

/// The plane `plane` of the state of `sim`, blocks outlined by their owners `owners` (every block held
/// by this process).
pub fn slice_of<T: Real>(sim: &Simulation<T>, plane: Plane, owners: &[u32], processes: usize, title: String) -> Slice {
    let cells: Vec<Option<Vec<SliceCell>>> = sim.blocks.iter().map(|b| block_plane(sim, plane, b)).collect();
    let bodies = sim.particles.as_ref().map(|p| p.bodies(sim.step));
    assemble(sim, plane, &cells, owners, bodies.as_deref(), processes, title)
}

/// The plane from every block's plane cells (block-id order) and the bodies (`None`: no particles).
fn assemble<T: Real>(
    sim: &Simulation<T>,
    plane: Plane,
    per_block: &[Option<Vec<SliceCell>>],
    owners: &[u32],
    bodies: Option<&[Body]>,
    processes: usize,
    title: String,
) -> Slice {
    let cells = sim.domain.cells();
    let [a, b] = plane.axes();
    let n = plane.normal;
    let (nu, nv) = (cells[a], cells[b]);
    let mut out = vec![SliceCell::Outside; nu * nv];
    let mut blocks = Vec::new();
    for (id, blk) in sim.blocks.iter().enumerate() {
        let Some(plane_cells) = &per_block[id] else {
            continue;
        };
        let (o, s) = (blk.origin, blk.layout.size);
        let owner = owners.get(id).copied().unwrap_or(0);
        let r = |k: usize| [o[k] as f64, (o[k] + s[k]) as f64];
        blocks.push(([r(a)[0], r(b)[0], r(a)[1], r(b)[1]], owner));
        for j in 0..s[b] {
            for i in 0..s[a] {
                out[(o[b] + j) * nu + o[a] + i] = plane_cells[j * s[a] + i];
            }
        }
    }
    let mut circles = Vec::new();
    if let Some(bodies) = bodies {
        let centre = plane.at as f64 + 0.5;
        for body in bodies {
            let x = body.position.to_array();
            let mut d = x[n] - centre;
            if sim.domain.periodic[n] {
                let l = cells[n] as f64;
                d -= l * (d / l).round();
            }
            if d.abs() >= body.radius {
                continue;
            }
            let r = (body.radius * body.radius - d * d).sqrt();
            // Periodic images of a circle that crosses an edge of a periodic in-plane axis.
            let shifts = |k: usize, len: usize| {
                let l = len as f64;
                let mut v = vec![0.0];
                if sim.domain.periodic[k] {
                    if x[k] - r < 0.0 {
                        v.push(l);
                    }
                    if x[k] + r > l {
                        v.push(-l);
                    }
                }
                v
            };
            for su in shifts(a, nu) {
                for sv in shifts(b, nv) {
                    circles.push([x[a] + su, x[b] + sv, r]);
                }
            }
        }
    }
    Slice {
        title,
        axes: [AXES[a], AXES[b]],
        size: [nu, nv],
        cells: out,
        circles,
        blocks,
        processes,
        bodies: sim.particles.is_some(),
    }
}

/// Draws the plane every `every` steps into `OUT/slices/step-<step:08>.png` and appends it to
/// `OUT/slices.gif` (kept when the run drew at least two pictures).
pub struct SliceWriter {
    every: u64,
    plane: Plane,
    dir: PathBuf,
    scene: String,
    units: Option<Units>,
    dt: Option<f64>,
    processes: usize,
    animation: Option<Animation>,
    /// Pictures written.
    pub count: usize,
    /// The last picture written.
    pub last: Option<PathBuf>,
    /// The step of the last picture drawn (by rank 0; every rank keeps it, so all draw at the same
    /// stops).
    drawn: Option<u64>,
}

impl SliceWriter {
    /// A writer for the run of `sim` into `dir/slices/` (created now); draws the current state, the
    /// blocks outlined by their owners `owners`.
    #[allow(clippy::too_many_arguments)] // the run's folder, state, assignment, settings and scene
    pub fn new<T: Real>(
        dir: &Path,
        sim: &Simulation<T>,
        world: &World,
        owners: &[u32],
        cfg: &Config,
        every: u64,
        scene: &str,
        units: Option<Units>,
    ) -> Result<Self> {
        let slices = dir.join("slices");
        if world.is_root() {
            std::fs::create_dir_all(&slices).map_err(|e| io_err(&slices, e))?;
        }
        let mut w = SliceWriter {
            every,
            plane: Plane::of(cfg, sim.domain.cells())?,
            dir: dir.to_path_buf(),
            scene: scene.to_string(),
            units,
            dt: sim.particles.as_ref().map(|p| p.dt),
            processes: cfg.processes.count,
            animation: None,
            count: 0,
            last: None,
            drawn: None,
        };
        w.draw(world, sim, owners)?;
        Ok(w)
    }

    fn title(&self, step: u64) -> String {
        let time = match self.units {
            Some(u) => format!(" · t = {:.4} s", step as f64 * self.dt.unwrap_or(1.0) * u.dt),
            None => String::new(),
        };
        let n = self.plane.normal;
        format!(
            "{} · step {step}{time} · plane {} = {}",
            self.scene, AXES[n], self.plane.at
        )
    }

    /// Draws the current state (under ranks: the plane's cells of every rank's blocks and the bodies
    /// gathered, drawn by rank 0).
    fn draw<T: Real>(&mut self, world: &World, sim: &Simulation<T>, owners: &[u32]) -> Result<()> {
        let step = sim.step;
        self.drawn = Some(step);
        let s = if world.is_single() {
            slice_of(sim, self.plane, owners, self.processes, self.title(step))
        } else {
            let held = sim.blocks.iter().filter(|b| b.is_held());
            let mine = held
                .map(|b| (b.id, encode_plane(block_plane(sim, self.plane, b))))
                .collect();
            let planes = world.gather_blocks(sim.blocks.len(), mine)?;
            let bodies = views::bodies(world, sim)?;
            let Some(planes) = planes else {
                return Ok(());
            };
            let cells: Vec<Option<Vec<SliceCell>>> = planes.iter().map(|b| decode_plane(b)).collect();
            let bodies = sim.particles.as_ref().map(|_| bodies.as_slice());
            assemble(
                sim,
                self.plane,
                &cells,
                owners,
                bodies,
                self.processes,
                self.title(step),
            )
        };
        let (rgb, size) = slice::render(&s)?;
        let path = self.dir.join("slices").join(format!("step-{step:08}.png"));
        slice::write_png(&path, &rgb, size)?;
        if self.animation.is_none() {
            self.animation = Some(Animation::new(&self.dir.join("slices.gif"), size, FRAME_DELAY)?);
        }
        self.animation.as_mut().expect("created above").push(&rgb)?;
        self.count += 1;
        self.last = Some(path);
        Ok(())
    }
}

impl<T: Real> Observer<T> for SliceWriter {
    fn next_stop(&self, step: u64) -> Option<u64> {
        Some((step / self.every + 1) * self.every)
    }

    fn at_stop(&mut self, cx: &RunContext<'_, T>) -> Result<Flow> {
        if cx.sim.step.is_multiple_of(self.every) && self.drawn != Some(cx.sim.step) {
            self.draw(cx.world, cx.sim, cx.owners)?;
        }
        Ok(Flow::Continue)
    }

    fn finish(&mut self, _cx: &RunContext<'_, T>, _end: &RunEnd<'_>) -> Result<()> {
        if let Some(a) = self.animation.take() {
            a.finish(2)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_plane_cuts_across_a_channel_and_vertically_through_a_box() {
        // A channel of 4 x 16 x 4 cells: the thin axes tie and z wins, the plane shows the profile in y.
        assert_eq!(default_normal([4, 16, 4]), 2);
        // A 2D scene one cell thick in x.
        assert_eq!(default_normal([1, 64, 64]), 0);
        // The demo's hopper, 48 x 48 x 72: a vertical plane.
        assert_eq!(default_normal([48, 48, 72]), 1);
        let mut cfg = crate::config::parse(crate::app::run::DEMO, "demo", &[]).unwrap();
        assert_eq!(Plane::of(&cfg, [48, 48, 72]).unwrap(), Plane { normal: 1, at: 24 });
        cfg.run.png_normal = Some("x".into());
        cfg.run.png_at = Some(47);
        assert_eq!(Plane::of(&cfg, [48, 48, 72]).unwrap(), Plane { normal: 0, at: 47 });
        cfg.run.png_at = Some(48);
        let e = Plane::of(&cfg, [48, 48, 72]).unwrap_err().to_string();
        assert!(e.contains("run.png_at = 48") && e.contains("0 to 47"), "{e}");
    }
}
