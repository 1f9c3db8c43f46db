//! `blockflow run`: builds a scene, steps it, writes summary.json, series.csv and optional VTK.

use crate::config::{Config, Precision};
use crate::error::{io_err, Error, Result};
use crate::io::series::Series;
use crate::io::summary::{Checksums, PartsSeconds, Summary, WorkSummary};
use crate::io::vtk::{VtkPiece, VtkSeries};
use crate::scenes::{self, FluidView, Scene};
use crate::sim::Simulation;
use blockflow_kernels::Real;
use indicatif::{ProgressBar, ProgressStyle};
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Command-line options of `blockflow run` that override the scene file.
#[derive(Clone, Debug, Default)]
pub struct RunOptions {
    /// `--steps`.
    pub steps: Option<u64>,
    /// `--out`.
    pub out: Option<PathBuf>,
    /// `--vtk EVERY`.
    pub vtk_every: Option<u64>,
    /// Show a progress bar (only when stdout is a terminal).
    pub progress: bool,
    /// The scene file, to name the default output folder.
    pub scene_path: Option<PathBuf>,
}

impl<T: Real> FluidView for Simulation<T> {
    fn visit(&self, f: &mut dyn FnMut([usize; 3], f64, [f64; 3])) {
        self.for_each_fluid(f)
    }
    fn steps_taken(&self) -> u64 {
        self.step
    }
}

/// The output folder a run writes to.
pub fn output_dir(cfg: &Config, opts: &RunOptions) -> PathBuf {
    if let Some(o) = &opts.out {
        return o.clone();
    }
    if let Some(o) = &cfg.run.out {
        return PathBuf::from(o);
    }
    let stem = opts
        .scene_path
        .as_ref()
        .and_then(|p| p.file_stem())
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_else(|| "run".to_string());
    Path::new("out").join(stem)
}

/// Runs a configuration to the end. On an unstable run, summary.json says `"status": "unstable"` and the
/// error is returned.
pub fn run(cfg: &Config, opts: &RunOptions) -> Result<Summary> {
    let scene = scenes::build(cfg)?;
    match cfg.fluid.precision {
        Precision::F64 => run_t::<f64>(cfg, scene, opts),
        Precision::F32 => run_t::<f32>(cfg, scene, opts),
    }
}

/// Builds the simulation of a scene (domain resolved, blocks built, initial state set).
pub fn build_sim<T: Real>(cfg: &Config, scene: &Scene) -> Result<Simulation<T>> {
    let domain = scenes::domain_for(&cfg.domain, scene)?;
    let mut sim = Simulation::<T>::new(
        domain,
        &scene.geometry,
        scene.params,
        cfg.fluid.velocity_limit,
        cfg.fluid.kernel,
    );
    if sim.fluid_cells() == 0 {
        return Err(Error::Config(format!(
            "scene {}: the geometry leaves no fluid cell in the {:?}-cell domain; check the walls and planes \
             (scene.planes) and the domain size",
            scene.name,
            domain.cells()
        )));
    }
    sim.init(&scene.init);
    Ok(sim)
}

fn write_summary(dir: &Path, s: &Summary) -> Result<()> {
    let path = dir.join("summary.json");
    let tmp = dir.join("summary.json.tmp");
    let text = serde_json::to_string_pretty(s).expect("summary serialises");
    std::fs::write(&tmp, text + "\n").map_err(|e| io_err(&tmp, e))?;
    std::fs::rename(&tmp, &path).map_err(|e| io_err(&path, e))
}

fn vtk_step<T: Real>(vtk: &mut VtkSeries, sim: &Simulation<T>) -> Result<()> {
    let force = sim.params.force;
    let p = sim.parity();
    let mut data = Vec::with_capacity(sim.blocks.len());
    for b in &sim.blocks {
        let [nx, ny, nz] = b.layout.size;
        let mut rho = Vec::with_capacity(nx * ny * nz);
        let mut vel = Vec::with_capacity(nx * ny * nz);
        let mut fl = Vec::with_capacity(nx * ny * nz);
        for z in 1..=nz {
            for y in 1..=ny {
                for x in 1..=nx {
                    let i = b.layout.idx(x, y, z);
                    let f = b.flags[i];
                    fl.push(f);
                    if f & crate::geometry::flags::FLUID != 0 {
                        let (r, u) = crate::fluid::cell_moments(b, p, i, force);
                        rho.push(1.0 + r);
                        vel.push(u);
                    } else {
                        rho.push(1.0);
                        vel.push([0.0; 3]);
                    }
                }
            }
        }
        data.push((b.id, b.origin, b.layout.size, rho, vel, fl));
    }
    let pieces: Vec<VtkPiece> = data
        .iter()
        .map(|(id, o, s, r, v, f)| VtkPiece {
            block_id: *id,
            origin: *o,
            size: *s,
            density: r,
            velocity: v,
            flags: f,
        })
        .collect();
    vtk.write_step(sim.step, sim.step as f64, &pieces)
        .map_err(|e| Error::Io(format!("VTK output at step {}: {e}", sim.step)))
}

fn run_t<T: Real>(cfg: &Config, scene: Scene, opts: &RunOptions) -> Result<Summary> {
    let steps = opts.steps.or(cfg.run.steps).unwrap_or(scene.steps);
    let dir = output_dir(cfg, opts);
    std::fs::create_dir_all(&dir).map_err(|e| io_err(&dir, e))?;
    let _ = std::fs::remove_file(dir.join("summary.json"));
    let eff = dir.join("effective.toml");
    std::fs::write(&eff, cfg.to_toml()).map_err(|e| io_err(&eff, e))?;
    let mut sim = build_sim::<T>(cfg, &scene)?;
    let series_every = cfg.run.series_every.unwrap_or((steps / 200).max(1));
    let mut series = Series::create(&dir.join("series.csv"))?;
    series.push(0, &sim.diagnostics())?;
    let vtk_every = opts.vtk_every.or(cfg.run.vtk_every);
    let mut vtk = match vtk_every {
        Some(_) => {
            let mut v = VtkSeries::new(&dir).map_err(|e| io_err(&dir, e))?;
            vtk_step(&mut v, &sim)?;
            Some(v)
        }
        None => None,
    };
    let bar = if opts.progress && std::io::stdout().is_terminal() {
        let b = ProgressBar::new(steps);
        b.set_style(
            ProgressStyle::with_template("{spinner} [{elapsed_precise}] {wide_bar} {pos}/{len} steps, ETA {eta}")
                .expect("valid template"),
        );
        b
    } else {
        ProgressBar::hidden()
    };
    let mut summary = Summary {
        scene: scene.name.to_string(),
        description: scene.description.clone(),
        steps_requested: steps,
        cells: sim.domain.total_cells(),
        fluid_cells: sim.fluid_cells(),
        blocks: sim.blocks.len(),
        block_grid: sim.domain.blocks,
        block_size: sim.domain.block_size,
        processes: 1,
        threads_per_process: 1,
        precision: T::NAME.to_string(),
        tau: sim.params.tau,
        magic: sim.params.magic,
        ..Default::default()
    };
    let t0 = Instant::now();
    let mut loop_time = 0.0;
    let mut failure = None;
    for s in 1..=steps {
        let ts = Instant::now();
        let r = sim.step();
        loop_time += ts.elapsed().as_secs_f64();
        if let Err(e) = r {
            failure = Some(e);
            break;
        }
        if s % series_every == 0 || s == steps {
            series.push(s, &sim.diagnostics())?;
        }
        if let (Some(v), Some(every)) = (vtk.as_mut(), vtk_every) {
            if s % every == 0 {
                vtk_step(v, &sim)?;
            }
        }
        if s % 16 == 0 || s == steps {
            bar.set_position(s);
        }
    }
    bar.finish_and_clear();
    let _ = t0;
    series.finish()?;
    summary.steps = sim.step;
    summary.wall_seconds = loop_time;
    summary.mlups = if loop_time > 0.0 {
        (sim.fluid_cells() as f64 * sim.step as f64) / loop_time / 1e6
    } else {
        0.0
    };
    summary.parts_seconds = PartsSeconds {
        lbm: sim.times.lbm,
        boundary: sim.times.boundary,
        exchange: sim.times.exchange,
        ..Default::default()
    };
    summary.work = WorkSummary {
        fluid_sweeps_per_step: sim.work.sweeps,
        boundary_passes_per_step: sim.work.boundary_passes,
        messages_per_step: sim.work.messages,
        blocks_without_fluid: sim.blocks.iter().filter(|b| b.fluid_cells == 0).count(),
        blocks_without_boundary: sim
            .blocks
            .iter()
            .filter(|b| b.fluid_cells > 0 && b.links.is_empty())
            .count(),
    };
    summary.checksum = Checksums {
        fluid: format!("{:016x}", sim.checksum()),
        particles: None,
    };
    if let Some(inst) = failure {
        let e = Error::Unstable(inst);
        summary.status = "unstable".to_string();
        summary.error = Some(e.to_string());
        write_summary(&dir, &summary)?;
        return Err(e);
    }
    summary.observables = (scene.observe)(&sim);
    summary.status = "ok".to_string();
    write_summary(&dir, &summary)?;
    Ok(summary)
}
