//! The outputs of `blockflow run` as observers of the time loop: the time series (`series.csv`,
//! `particles.csv`), body 0's trajectory, VTK files, checkpoints, the progress bar and the stop on a
//! signal.

use crate::app::signals;
use crate::checkpoint::{self, BalanceState, CheckpointInput};
use crate::config::Config;
use crate::error::{io_err, Result};
use crate::io::series::{ParticleRow, ParticleSeries, Series};
use crate::io::vtk::{ParticleVtkSeries, VtkEncoding, VtkParticle, VtkPiece, VtkSeries};
use crate::physics::simulation::Simulation;
use crate::ranks::views::{self, BlockCells};
use crate::ranks::World;
use crate::scenes::Units;
use crate::timeloop::{Flow, Observer, RunContext, RunEnd};
use crate::util::fs::write_atomic;
use blockflow_kernels::rigid::Body;
use blockflow_kernels::Real;
use indicatif::{ProgressBar, ProgressStyle};
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The next multiple of `every` after `step`.
fn next_multiple(step: u64, every: u64) -> u64 {
    (step / every + 1) * every
}

/// `path` with `.partial` appended: time series are written there and renamed when the run ends, so a
/// run that fails leaves no file that looks like a finished result.
fn partial(p: &Path) -> PathBuf {
    let mut s = p.as_os_str().to_owned();
    s.push(".partial");
    PathBuf::from(s)
}

/// One row of `particles.csv` for the state of `sim` (none without particles).
fn particle_row<T: Real>(world: &World, sim: &Simulation<T>) -> Result<Option<ParticleRow>> {
    let Some(p) = sim.particles.as_ref() else {
        return Ok(None);
    };
    let b = views::bodies(world, sim)?;
    let (contacts, pen) = views::last_contacts(world, sim)?;
    Ok(Some(ParticleRow {
        step: sim.step,
        time: sim.step as f64 * p.dt,
        bodies: b.len(),
        kinetic_energy: b.iter().map(|x| x.kinetic_energy()).sum(),
        max_speed: b.iter().map(|x| x.velocity.length()).fold(0.0, f64::max),
        contacts,
        max_penetration: pen,
    }))
}

/// The files of `series.csv` and `particles.csv` (rank 0 only).
struct SeriesFiles {
    fluid: Series,
    particles: Option<ParticleSeries>,
}

/// `series.csv` (and `particles.csv` for scenes with bodies): a row at the start, every `every` steps and
/// at the last step. Under ranks every rank computes the rows (the diagnostics are collectives) and rank
/// 0 writes them.
pub struct SeriesWriter {
    every: u64,
    threads: usize,
    end: u64,
    paths: (PathBuf, PathBuf),
    files: Option<SeriesFiles>,
}

impl SeriesWriter {
    /// Creates the files in `dir` with the row of the current state; the fluid's sums are taken on
    /// `threads` threads (the run's, idle while the observers run).
    pub fn new<T: Real>(
        dir: &Path,
        sim: &Simulation<T>,
        world: &World,
        every: u64,
        end: u64,
        threads: usize,
    ) -> Result<Self> {
        let paths = (dir.join("series.csv"), dir.join("particles.csv"));
        let d = views::diagnostics(world, sim, threads)?;
        let row = particle_row(world, sim)?;
        let files = if world.is_root() {
            let mut fluid = Series::create(&partial(&paths.0))?;
            fluid.push(sim.step, &d)?;
            let particles = match row {
                Some(row) => {
                    let mut ps = ParticleSeries::create(&partial(&paths.1))?;
                    ps.push(&row)?;
                    Some(ps)
                }
                None => None,
            };
            Some(SeriesFiles { fluid, particles })
        } else {
            None
        };
        Ok(SeriesWriter {
            every,
            threads,
            end,
            paths,
            files,
        })
    }
}

impl<T: Real> Observer<T> for SeriesWriter {
    fn next_stop(&self, step: u64) -> Option<u64> {
        Some(next_multiple(step, self.every))
    }

    fn at_stop(&mut self, cx: &RunContext<'_, T>) -> Result<Flow> {
        let s = cx.sim.step;
        if s.is_multiple_of(self.every) || s == self.end {
            let d = views::diagnostics(cx.world, cx.sim, self.threads)?;
            let row = particle_row(cx.world, cx.sim)?;
            if let Some(f) = self.files.as_mut() {
                f.fluid.push(s, &d)?;
                if let (Some(ps), Some(row)) = (f.particles.as_mut(), row) {
                    ps.push(&row)?;
                }
            }
        }
        Ok(Flow::Continue)
    }

    fn finish(&mut self, _cx: &RunContext<'_, T>, _end: &RunEnd<'_>) -> Result<()> {
        let Some(f) = self.files.as_mut() else {
            return Ok(());
        };
        f.fluid.flush()?;
        std::fs::rename(partial(&self.paths.0), &self.paths.0).map_err(|e| io_err(&self.paths.0, e))?;
        if let Some(ps) = f.particles.as_mut() {
            ps.flush()?;
            std::fs::rename(partial(&self.paths.1), &self.paths.1).map_err(|e| io_err(&self.paths.1, e))?;
        }
        Ok(())
    }
}

/// Body 0 over time (position, velocity, hydrodynamic force) for scenes with few bodies, recorded at
/// every stop of the time loop (at most `processes.steps_per_graph` steps apart, so that peaks are not
/// missed between series rows): `trajectory.csv` in lattice units
/// and, for scenes set up in SI units, `trajectory_si.csv`.
pub struct TrajectoryRecorder {
    dir: PathBuf,
    units: Option<Units>,
    /// (time, body 0) at every record.
    pub points: Vec<(f64, Body)>,
    text: String,
    si: String,
}

impl TrajectoryRecorder {
    /// The most bodies a scene may have to get a trajectory.
    pub const MAX_BODIES: usize = 16;

    /// A recorder for the run of `sim` (absent when the scene has no bodies or more than
    /// [`Self::MAX_BODIES`]), with the record of the current state.
    pub fn new<T: Real>(dir: &Path, sim: &Simulation<T>, world: &World, units: Option<Units>) -> Result<Option<Self>> {
        let bodies = views::bodies(world, sim)?;
        if sim.particles.is_none() || bodies.len() > Self::MAX_BODIES {
            return Ok(None);
        }
        let mut r = TrajectoryRecorder {
            dir: dir.to_path_buf(),
            units,
            points: Vec::new(),
            text: String::from("step,time,x,y,z,vx,vy,vz,wx,wy,wz,fx,fy,fz\n"),
            si: String::from("step,time_s,x_m,y_m,z_m,vx_m_s,vy_m_s,vz_m_s,fx_n,fy_n,fz_n\n"),
        };
        r.record(sim, &bodies);
        Ok(Some(r))
    }

    fn record<T: Real>(&mut self, sim: &Simulation<T>, bodies: &[Body]) {
        let Some(p) = sim.particles.as_ref() else { return };
        let Some(b) = bodies.first().copied() else {
            return;
        };
        let t = sim.step as f64 * p.dt;
        self.points.push((t, b));
        let (x, v, w, f) = (b.position, b.velocity, b.angular_velocity, b.force);
        self.text += &format!(
            "{},{t:.9e},{:.12e},{:.12e},{:.12e},{:.12e},{:.12e},{:.12e},{:.12e},{:.12e},{:.12e},{:.12e},{:.12e},{:.12e}\n",
            sim.step, x.x, x.y, x.z, v.x, v.y, v.z, w.x, w.y, w.z, f.x, f.y, f.z
        );
        if let Some(u) = self.units {
            let (lv, lf) = (u.dx / u.dt, u.density * u.dx.powi(4) / (u.dt * u.dt));
            self.si += &format!(
                "{},{:.9e},{:.9e},{:.9e},{:.9e},{:.9e},{:.9e},{:.9e},{:.9e},{:.9e},{:.9e}\n",
                sim.step,
                t * u.dt,
                x.x * u.dx,
                x.y * u.dx,
                x.z * u.dx,
                v.x * lv,
                v.y * lv,
                v.z * lv,
                f.x * lf,
                f.y * lf,
                f.z * lf
            );
        }
    }
}

impl<T: Real> Observer<T> for TrajectoryRecorder {
    fn at_stop(&mut self, cx: &RunContext<'_, T>) -> Result<Flow> {
        let bodies = views::bodies(cx.world, cx.sim)?;
        self.record(cx.sim, &bodies);
        Ok(Flow::Continue)
    }

    fn finish(&mut self, cx: &RunContext<'_, T>, _end: &RunEnd<'_>) -> Result<()> {
        if !cx.world.is_root() {
            return Ok(());
        }
        write_atomic(&self.dir.join("trajectory.csv"), self.text.as_bytes())?;
        if self.units.is_some() {
            write_atomic(&self.dir.join("trajectory_si.csv"), self.si.as_bytes())?;
        }
        Ok(())
    }
}

/// VTK output every `every` steps: `fluid.pvd` with one `.vti` per block (density, velocity, flags; cells
/// covered by a particle flagged as such) and, with bodies, `particles.pvd`. Under ranks each rank writes
/// its own blocks' files and rank 0 the files that list them and the bodies.
pub struct VtkWriter {
    every: u64,
    fluid: VtkSeries,
    particles: Option<ParticleVtkSeries>,
}

impl VtkWriter {
    /// Creates the series in `dir`, block arrays stored as `encoding`, and writes the current state.
    pub fn new<T: Real>(
        dir: &Path,
        sim: &Simulation<T>,
        world: &World,
        every: u64,
        encoding: VtkEncoding,
    ) -> Result<Self> {
        let particles = match &sim.particles {
            Some(_) if world.is_root() => Some(ParticleVtkSeries::new(dir).map_err(|e| io_err(dir, e))?),
            _ => None,
        };
        let mut w = VtkWriter {
            every,
            fluid: VtkSeries::new(dir, encoding).map_err(|e| io_err(dir, e))?,
            particles,
        };
        w.write(world, sim)?;
        Ok(w)
    }

    fn write<T: Real>(&mut self, world: &World, sim: &Simulation<T>) -> Result<()> {
        let cells: Vec<BlockCells> = sim
            .blocks
            .iter()
            .filter(|b| b.is_held())
            .map(|b| BlockCells::of(sim, b))
            .collect();
        let data: Vec<(Vec<f64>, &BlockCells)> = cells
            .iter()
            .map(|c| {
                (
                    c.delta_rho
                        .iter()
                        .zip(&c.flags)
                        .map(|(r, &f)| if f & 1 != 0 { 1.0 + r } else { 1.0 })
                        .collect(),
                    c,
                )
            })
            .collect();
        let pieces: Vec<VtkPiece> = data
            .iter()
            .map(|(rho, c)| VtkPiece {
                block_id: c.id,
                origin: c.origin,
                size: c.size,
                density: rho,
                velocity: &c.velocity,
                flags: &c.flags,
            })
            .collect();
        let vtk_err = |e: std::io::Error| crate::error::Error::Io(format!("VTK output at step {}: {e}", sim.step));
        self.fluid.write_blocks(sim.step, &pieces).map_err(vtk_err)?;
        let bodies = views::bodies(world, sim)?;
        if !world.is_single() {
            // Every rank's block files are in place before rank 0 lists them.
            world.sum(&mut [0])?;
        }
        if !world.is_root() {
            return Ok(());
        }
        let ids: Vec<usize> = (0..sim.blocks.len()).collect();
        self.fluid
            .write_index(sim.step, sim.step as f64, &ids)
            .map_err(vtk_err)?;
        if let (Some(pv), Some(parts)) = (self.particles.as_mut(), sim.particles.as_ref()) {
            let list: Vec<VtkParticle> = bodies
                .iter()
                .map(|b| VtkParticle {
                    id: b.id,
                    position: b.position.to_array(),
                    radius: b.radius,
                    velocity: b.velocity.to_array(),
                    angular_velocity: b.angular_velocity.to_array(),
                    orientation: [b.orientation.x, b.orientation.y, b.orientation.z, b.orientation.w],
                    force: b.force.to_array(),
                })
                .collect();
            pv.write_step(sim.step, sim.step as f64 * parts.dt, &list)
                .map_err(|e| crate::error::Error::Io(format!("particle VTK output at step {}: {e}", sim.step)))?;
        }
        Ok(())
    }
}

impl<T: Real> Observer<T> for VtkWriter {
    fn next_stop(&self, step: u64) -> Option<u64> {
        Some(next_multiple(step, self.every))
    }

    fn at_stop(&mut self, cx: &RunContext<'_, T>) -> Result<Flow> {
        if cx.sim.step.is_multiple_of(self.every) {
            self.write(cx.world, cx.sim)?;
        }
        Ok(Flow::Continue)
    }
}

/// Checkpoints (`OUT/checkpoints/step-<step>`): whenever the step is a multiple of `run.checkpoint_every`
/// or `run.checkpoint_wall` seconds have passed since the last one, and at the step reached when an
/// observer stopped the run (a signal). Only the newest `run.checkpoints_kept` are kept.
pub struct CheckpointWriter {
    dir: PathBuf,
    every: Option<u64>,
    wall: Option<f64>,
    kept: usize,
    /// The effective configuration (TOML) every checkpoint carries.
    config_text: String,
    scene: &'static str,
    cfg: Config,
    last_time: Instant,
    /// The last checkpoint written: (step, file).
    pub last: Option<(u64, PathBuf)>,
    /// Checkpoints written.
    pub count: u64,
    /// Seconds spent writing them.
    pub seconds: f64,
    /// Bytes of the last one.
    pub bytes: u64,
}

impl CheckpointWriter {
    /// A writer into `dir` (which must exist when a checkpoint is due) for the run of `cfg`.
    pub fn new(dir: PathBuf, cfg: &Config, config_text: String, scene: &'static str) -> Self {
        CheckpointWriter {
            dir,
            every: cfg.run.checkpoint_every,
            wall: cfg.run.checkpoint_wall,
            kept: cfg.run.checkpoints_kept,
            config_text,
            scene,
            cfg: cfg.clone(),
            last_time: Instant::now(),
            last: None,
            count: 0,
            seconds: 0.0,
            bytes: 0,
        }
    }

    fn save<T: Real>(&mut self, cx: &RunContext<'_, T>) -> Result<()> {
        let input = CheckpointInput {
            config: &self.config_text,
            scene: self.scene,
            balance: cx.balancer.map(|b| BalanceState::of(&self.cfg, b)),
        };
        let w = checkpoint::write_on(&self.dir, cx.sim, &input, self.kept, cx.world, cx.owners)?;
        self.count += 1;
        self.seconds += w.seconds;
        self.bytes = w.bytes;
        self.last = Some((cx.sim.step, w.path));
        self.last_time = Instant::now();
        Ok(())
    }
}

impl<T: Real> Observer<T> for CheckpointWriter {
    fn next_stop(&self, step: u64) -> Option<u64> {
        self.every.map(|e| next_multiple(step, e))
    }

    fn at_stop(&mut self, cx: &RunContext<'_, T>) -> Result<Flow> {
        let s = cx.sim.step;
        let due = self.every.is_some_and(|n| s.is_multiple_of(n))
            || self.wall.is_some_and(|w| self.last_time.elapsed().as_secs_f64() >= w);
        if due {
            self.save(cx)?;
        }
        Ok(Flow::Continue)
    }

    fn finish(&mut self, cx: &RunContext<'_, T>, end: &RunEnd<'_>) -> Result<()> {
        // Stopped early: a checkpoint of the step reached (unless one was just written).
        if matches!(end, RunEnd::Stopped) && self.last.as_ref().is_none_or(|(s, _)| *s != cx.sim.step) {
            if cx.world.is_root() {
                std::fs::create_dir_all(&self.dir).map_err(|e| io_err(&self.dir, e))?;
            }
            self.save(cx)?;
        }
        Ok(())
    }
}

/// A progress bar of the steps (only when stdout is a terminal), updated at least every 256 steps.
pub struct Progress {
    bar: ProgressBar,
}

impl Progress {
    /// A bar from the current step to `end`.
    pub fn new(step: u64, end: u64, show: bool) -> Self {
        let bar = if show && std::io::stdout().is_terminal() {
            let b = ProgressBar::new(end);
            b.set_style(
                ProgressStyle::with_template("{spinner} [{elapsed_precise}] {wide_bar} {pos}/{len} steps, ETA {eta}")
                    .expect("valid template"),
            );
            b.set_position(step);
            b
        } else {
            ProgressBar::hidden()
        };
        Progress { bar }
    }
}

impl<T: Real> Observer<T> for Progress {
    fn next_stop(&self, step: u64) -> Option<u64> {
        Some(step + 256)
    }

    fn at_stop(&mut self, cx: &RunContext<'_, T>) -> Result<Flow> {
        self.bar.set_position(cx.sim.step);
        Ok(Flow::Continue)
    }

    fn finish(&mut self, _cx: &RunContext<'_, T>, _end: &RunEnd<'_>) -> Result<()> {
        self.bar.finish_and_clear();
        Ok(())
    }
}

/// Stops the run at the next stop of the time loop once SIGINT or SIGTERM arrived (under ranks, once it
/// arrived at any rank: all stop at the same step).
pub struct StopOnSignal;

impl<T: Real> Observer<T> for StopOnSignal {
    fn at_stop(&mut self, cx: &RunContext<'_, T>) -> Result<Flow> {
        let mut stop = [u64::from(signals::interrupted().is_some())];
        if !cx.world.is_single() {
            cx.world.or(&mut stop)?;
        }
        Ok(if stop[0] != 0 { Flow::Stop } else { Flow::Continue })
    }
}
