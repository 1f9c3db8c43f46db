//! Pictures of a run as it goes (`--png EVERY`, `run.png_every`): one plane of the flow every so many
//! steps as `OUT/slices/step-<step>.png` and all of them as `OUT/slices.gif`, like LAMMPS' `dump image`.

use crate::config::Config;
use crate::error::{io_err, Error, Result};
use crate::io::animation::Animation;
use crate::io::plots::slice::{self, Slice, SliceCell};
use crate::physics::geometry::flags;
use crate::physics::simulation::Simulation;
use crate::scenes::Units;
use crate::timeloop::{Flow, Observer, RunContext, RunEnd};
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

/// The plane `plane` of the state of `sim`, blocks outlined by their owners `owners`.
pub fn slice_of<T: Real>(sim: &Simulation<T>, plane: Plane, owners: &[u32], processes: usize, title: String) -> Slice {
    let cells = sim.domain.cells();
    let [a, b] = plane.axes();
    let n = plane.normal;
    let (nu, nv) = (cells[a], cells[b]);
    let mut out = vec![SliceCell::Outside; nu * nv];
    let mut blocks = Vec::new();
    let parity = sim.parity();
    let force = sim.params.force;
    for (id, blk) in sim.blocks.iter().enumerate() {
        let (o, s) = (blk.origin, blk.layout.size);
        if plane.at < o[n] || plane.at >= o[n] + s[n] {
            continue;
        }
        let owner = owners.get(id).copied().unwrap_or(0);
        let r = |k: usize| [o[k] as f64, (o[k] + s[k]) as f64];
        blocks.push(([r(a)[0], r(b)[0], r(a)[1], r(b)[1]], owner));
        let covered = blk.particle_cells();
        for j in 0..s[b] {
            for i in 0..s[a] {
                let mut local = [0usize; 3];
                local[n] = plane.at - o[n] + 1;
                local[a] = i + 1;
                local[b] = j + 1;
                let idx = blk.layout.idx(local[0], local[1], local[2]);
                let f = blk.flags[idx];
                let c = if covered.is_some_and(|pc| pc.owner.get(idx).is_some_and(|&w| w != 0)) {
                    SliceCell::Particle
                } else if f & flags::FLUID != 0 {
                    let (_, u) = crate::physics::fluid::cell_moments(blk, parity, idx, force);
                    SliceCell::Fluid((u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt())
                } else if f & (flags::NOSLIP | flags::MOVING_WALL) != 0 {
                    SliceCell::Wall
                } else {
                    SliceCell::Outside
                };
                out[(o[b] + j) * nu + o[a] + i] = c;
            }
        }
    }
    let mut circles = Vec::new();
    if let Some(p) = &sim.particles {
        let centre = plane.at as f64 + 0.5;
        for body in p.bodies(sim.step) {
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
}

impl SliceWriter {
    /// A writer for the run of `sim` into `dir/slices/` (created now); draws the current state, the
    /// blocks outlined by their owners `owners`.
    pub fn new<T: Real>(
        dir: &Path,
        sim: &Simulation<T>,
        owners: &[u32],
        cfg: &Config,
        every: u64,
        scene: &str,
        units: Option<Units>,
    ) -> Result<Self> {
        let slices = dir.join("slices");
        std::fs::create_dir_all(&slices).map_err(|e| io_err(&slices, e))?;
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
        };
        w.draw(sim, owners)?;
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

    fn draw<T: Real>(&mut self, sim: &Simulation<T>, owners: &[u32]) -> Result<()> {
        let step = sim.step;
        let s = slice_of(sim, self.plane, owners, self.processes, self.title(step));
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
        if cx.sim.step.is_multiple_of(self.every) && self.last_step() != Some(cx.sim.step) {
            self.draw(cx.sim, cx.owners)?;
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

impl SliceWriter {
    /// The step of the last picture, from its file name.
    fn last_step(&self) -> Option<u64> {
        let name = self.last.as_ref()?.file_stem()?.to_str()?;
        name.strip_prefix("step-")?.parse().ok()
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
