//! `blockflow run`: builds a scene, steps it, writes summary.json, series.csv and optional VTK.

use crate::balance::{self, curves::Curve};
use crate::config::{Config, PinConfig, Precision, StealConfig, Strategy};
use crate::domain::DomainSpec;
use crate::error::{io_err, Error, Result};
use crate::io::series::{ParticleRow, ParticleSeries, Series};
use crate::io::summary::{BalanceSummary, Checksums, ParticleSummary, PartsSeconds, Summary, WorkSummary};
use crate::io::vtk::{ParticleVtkSeries, VtkParticle, VtkPiece, VtkSeries};
use crate::particles::Particles;
use crate::pipeline::Pipeline;
use crate::scenes::{self, FluidView, Scene};
use crate::sim::Simulation;
use blockflow_kernels::rigid::RigidParams;
use blockflow_kernels::Real;
use blockflow_scheduler::executor::{Executor, PoolConfig, Steal};
use blockflow_scheduler::topology::{placement, PinPolicy, Topology};
use glam::DVec3;
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
    /// `--trace FILE`: write a Chrome trace of every task.
    pub trace: Option<PathBuf>,
}

impl<T: Real> FluidView for Simulation<T> {
    fn visit(&self, f: &mut dyn FnMut([usize; 3], f64, [f64; 3])) {
        self.for_each_fluid(f)
    }
    fn steps_taken(&self) -> u64 {
        self.step
    }
    fn bodies(&self) -> Vec<blockflow_kernels::rigid::Body> {
        self.particles.as_ref().map_or_else(Vec::new, |p| p.bodies(self.step))
    }
    fn hydro_forces(&self) -> Vec<crate::coupling::BodyForce> {
        crate::coupling::tasks::total_forces(&self.blocks)
    }
}

/// The simulation plus what the run recorded over time, as the scenes' observables see it.
struct RunView<'a, T: Real> {
    sim: &'a Simulation<T>,
    trajectory: &'a [(f64, blockflow_kernels::rigid::Body)],
}

impl<T: Real> FluidView for RunView<'_, T> {
    fn visit(&self, f: &mut dyn FnMut([usize; 3], f64, [f64; 3])) {
        self.sim.visit(f)
    }
    fn steps_taken(&self) -> u64 {
        self.sim.step
    }
    fn bodies(&self) -> Vec<blockflow_kernels::rigid::Body> {
        self.sim.bodies()
    }
    fn hydro_forces(&self) -> Vec<crate::coupling::BodyForce> {
        self.sim.hydro_forces()
    }
    fn trajectory(&self) -> Vec<(f64, blockflow_kernels::rigid::Body)> {
        self.trajectory.to_vec()
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
    let mut geometry = scene.geometry.clone();
    geometry.no_fluid |= !cfg.fluid.enabled;
    let mut sim = Simulation::<T>::new(
        domain,
        &geometry,
        scene.params,
        cfg.fluid.velocity_limit,
        cfg.fluid.kernel,
    );
    if let Some(ps) = &scene.particles {
        let parts = build_particles(cfg, ps, domain)?;
        if !geometry.no_fluid {
            crate::coupling::tasks::map_all(&parts, &sim.blocks, 0, cfg.particles.boundary);
        }
        sim.particles = Some(parts);
    }
    if sim.fluid_cells() == 0 && !geometry.no_fluid {
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

/// The rigid bodies of a scene on the block grid, with `[particles]` applied over the scene's defaults.
pub fn build_particles(cfg: &Config, ps: &scenes::ParticleScene, domain: DomainSpec) -> Result<Particles> {
    let c = &cfg.particles;
    if cfg.fluid.enabled && c.dt.is_some_and(|dt| dt != 1.0) {
        return Err(Error::Config(
            "particles.dt: with the fluid on the step is the lattice time unit; remove the key".into(),
        ));
    }
    let params = RigidParams {
        gravity: DVec3::from(c.gravity.unwrap_or(ps.gravity)),
        fluid_density: if cfg.fluid.enabled { 1.0 } else { 0.0 },
        restitution: c.restitution,
        friction: c.friction,
        iterations: c.iterations,
        relaxation: c.relaxation,
        grid_threshold: c.grid_threshold,
        contact_margin: c.contact_margin,
        restitution_threshold: c.restitution_threshold.unwrap_or(ps.restitution_threshold),
        position_correction: c.position_correction,
    };
    Particles::new(
        domain,
        ps.bodies.clone(),
        ps.planes.clone(),
        params,
        c.subcycles,
        c.dt.unwrap_or(ps.dt),
    )
}

fn particle_row<T: Real>(sim: &Simulation<T>) -> Option<ParticleRow> {
    let p = sim.particles.as_ref()?;
    let b = p.bodies(sim.step);
    let (contacts, pen) = p.last_contacts();
    Some(ParticleRow {
        step: sim.step,
        time: sim.step as f64 * p.dt,
        bodies: b.len(),
        kinetic_energy: b.iter().map(|x| x.kinetic_energy()).sum(),
        max_speed: b.iter().map(|x| x.velocity.length()).fold(0.0, f64::max),
        contacts,
        max_penetration: pen,
    })
}

fn write_summary(dir: &Path, s: &Summary) -> Result<()> {
    let path = dir.join("summary.json");
    let tmp = dir.join("summary.json.tmp");
    let text = serde_json::to_string_pretty(s).expect("summary serialises");
    std::fs::write(&tmp, text + "\n").map_err(|e| io_err(&tmp, e))?;
    std::fs::rename(&tmp, &path).map_err(|e| io_err(&path, e))
}

fn vtk_step<T: Real>(vtk: &mut VtkSeries, pvtk: Option<&mut ParticleVtkSeries>, sim: &Simulation<T>) -> Result<()> {
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
                    let mut f = b.flags[i];
                    if b.particle_cells()
                        .is_some_and(|pc| pc.owner.get(i).is_some_and(|&o| o != 0))
                    {
                        f = crate::geometry::flags::PARTICLE;
                    }
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
        .map_err(|e| Error::Io(format!("VTK output at step {}: {e}", sim.step)))?;
    if let (Some(pv), Some(parts)) = (pvtk, sim.particles.as_ref()) {
        let list: Vec<VtkParticle> = parts
            .bodies(sim.step)
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
            .map_err(|e| Error::Io(format!("particle VTK output at step {}: {e}", sim.step)))?;
    }
    Ok(())
}

/// The pinning policy of a configuration.
pub fn pin_policy(cfg: &Config) -> Result<PinPolicy> {
    match &cfg.processes.pin {
        PinConfig::Name(s) => s
            .parse::<PinPolicy>()
            .map_err(|e| Error::Config(format!("processes.pin = {s:?}: {e}"))),
        PinConfig::Cores(v) => Ok(PinPolicy::List(v.clone())),
    }
}

/// Starts the worker threads of `[processes]`: P × T threads, pinned by `processes.pin`.
pub fn make_executor(cfg: &Config) -> Result<Executor> {
    let pr = &cfg.processes;
    let topo = Topology::detect();
    let cores = placement(&topo, pr.count, pr.threads_per_process, &pin_policy(cfg)?)
        .map_err(|e| Error::Config(format!("processes.pin: {e}")))?;
    Executor::new(PoolConfig {
        processes: pr.count,
        threads_per_process: pr.threads_per_process,
        cores,
        steal: match pr.steal {
            StealConfig::Process => Steal::Process,
            StealConfig::Global => Steal::Global,
        },
    })
    .map_err(|e| Error::Config(format!("[processes]: {e}")))
}

/// Block weights of `balance.weights`: fluid cells, or the estimate of eq. (15) with the coefficients
/// of `balance.coefficients` (the file is read and checked here; errors name the file and key).
pub fn block_weights<T: Real>(cfg: &Config, sim: &Simulation<T>) -> Result<Vec<f64>> {
    use crate::config::Weights;
    match cfg.balance.weights {
        // Nothing is measured before the first interval: `measured` starts from cells.
        Weights::Cells | Weights::Measured => {
            let dry = sim.fluid_cells() == 0;
            Ok(sim
                .blocks
                .iter()
                .map(|b| if dry { b.layout.interior_cells() } else { b.current_fluid_cells() } as f64)
                .collect())
        }
        Weights::Estimator | Weights::Corrected => {
            let c = load_coefficients(cfg)?;
            Ok((0..sim.blocks.len())
                .map(|b| c.total(&crate::calibrate::quantities(sim, b)))
                .collect())
        }
    }
}

/// The estimator coefficients of `balance.coefficients`; the error names the file and key.
pub fn load_coefficients(cfg: &Config) -> Result<crate::estimator::Coefficients> {
    crate::estimator::Coefficients::load(Path::new(&cfg.balance.coefficients)).map_err(|e| {
        Error::Config(format!(
            "balance.coefficients: {e}; run `blockflow calibrate` to write one"
        ))
    })
}

/// Owner process of every block by `balance.weights` (see [`block_weights`]): curve order
/// (`balance.strategy`; `none` is the static Hilbert split), greedy prefix split.
pub fn assignment_weighted<T: Real>(cfg: &Config, sim: &Simulation<T>) -> Result<Vec<u32>> {
    let curve = match cfg.balance.strategy {
        Strategy::None | Strategy::Hilbert | Strategy::Diffusive | Strategy::Metis => Curve::Hilbert,
        Strategy::Morton => Curve::Morton,
    };
    let weights = block_weights(cfg, sim)?;
    Ok(balance::assign_with(
        sim.domain.blocks,
        &weights,
        cfg.processes.count,
        curve,
        cfg.balance.split,
    ))
}

/// Owner process of every block: curve order (`balance.strategy`; `none` is the static Hilbert split),
/// greedy prefix split by fluid-cell count (cell count in scenes without fluid).
pub fn assignment<T: Real>(cfg: &Config, sim: &Simulation<T>) -> Vec<u32> {
    let curve = match cfg.balance.strategy {
        Strategy::None | Strategy::Hilbert | Strategy::Diffusive | Strategy::Metis => Curve::Hilbert,
        Strategy::Morton => Curve::Morton,
    };
    // Without fluid (dry rigid-body scenes) every block weighs its cell count.
    let dry = sim.fluid_cells() == 0;
    let weights: Vec<f64> = sim
        .blocks
        .iter()
        .map(|b| if dry { b.layout.interior_cells() } else { b.fluid_cells } as f64)
        .collect();
    balance::assign(sim.domain.blocks, &weights, cfg.processes.count, curve)
}

/// The balancer of `balance.strategy` on `processes.count` processes (none for `"none"`: the
/// assignment never changes).
pub fn make_balancer<T: Real>(cfg: &Config, sim: &Simulation<T>) -> Result<Option<crate::balance::dynamic::Balancer>> {
    use crate::config::Weights;
    if cfg.balance.strategy == Strategy::None {
        return Ok(None);
    }
    let coeffs = match cfg.balance.weights {
        Weights::Estimator | Weights::Corrected => Some(load_coefficients(cfg)?),
        _ => None,
    };
    Ok(Some(crate::balance::dynamic::Balancer::new(
        cfg.balance.weights,
        crate::balance::strategy::strategy(&cfg.balance),
        cfg.processes.count,
        coeffs,
        &sim.domain,
    )))
}

/// The pipeline of a run: the executor of `[processes]`, the initial assignment by `balance.weights`
/// (with the load imbalance those weights predict for the first interval), the balancer, the message
/// price of the modeled times, and the first touch of every block by its owner.
pub fn make_pipeline<T: Real>(cfg: &Config, sim: &Simulation<T>) -> Result<Pipeline<T>> {
    let exec = make_executor(cfg)?;
    let owners = assignment_weighted(cfg, sim)?;
    let weights = block_weights(cfg, sim)?;
    let mut pipe = Pipeline::new(sim, exec, owners, cfg.processes.steps_per_graph, cfg.balance.interval);
    pipe.surface = cfg.particles.boundary;
    pipe.force_averaging = cfg.particles.force_averaging;
    pipe.comm = crate::study::model::CommModel {
        latency: cfg.balance.latency,
        bandwidth: cfg.balance.bandwidth,
    };
    pipe.set_predicted_imbalance(&weights);
    pipe.balancer = make_balancer(cfg, sim)?;
    pipe.first_touch(sim);
    Ok(pipe)
}

pub use crate::balance::edge_cut_mean;

fn median(v: &[f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let mut s = v.to_vec();
    s.sort_by(|a, b| a.total_cmp(b));
    let n = s.len();
    if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    }
}

fn write_intervals(path: &Path, intervals: &[crate::pipeline::IntervalStats]) -> Result<()> {
    let procs = intervals.first().map_or(0, |i| i.process_load.len());
    let mut text = String::from(
        "interval,start,end,wall_seconds,modeled_seconds,bsp_seconds,imbalance,predicted_imbalance,message_bytes,\
         edge_cut_mean,migrated_blocks,migrated_bytes,balance_seconds",
    );
    for p in 0..procs {
        text += &format!(",load_p{p}");
    }
    text.push('\n');
    for (i, iv) in intervals.iter().enumerate() {
        text += &format!(
            "{i},{},{},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{},{:.6e},{},{},{:.6e}",
            iv.start,
            iv.end,
            iv.wall_seconds,
            iv.modeled_seconds,
            iv.bsp_seconds,
            iv.imbalance,
            iv.predicted_imbalance,
            iv.message_bytes,
            iv.edge_cut_mean,
            iv.migrated_blocks,
            iv.migrated_bytes,
            iv.balance_seconds
        );
        for l in &iv.process_load {
            text += &format!(",{l:.6e}");
        }
        text.push('\n');
    }
    std::fs::write(path, text).map_err(|e| io_err(path, e))
}

fn run_t<T: Real>(cfg: &Config, scene: Scene, opts: &RunOptions) -> Result<Summary> {
    let steps = opts.steps.or(cfg.run.steps).unwrap_or(scene.steps);
    let dir = output_dir(cfg, opts);
    std::fs::create_dir_all(&dir).map_err(|e| io_err(&dir, e))?;
    let _ = std::fs::remove_file(dir.join("summary.json"));
    let eff = dir.join("effective.toml");
    std::fs::write(&eff, cfg.to_toml()).map_err(|e| io_err(&eff, e))?;
    let mut sim = build_sim::<T>(cfg, &scene)?;
    let mut pipe = make_pipeline(cfg, &sim)?;
    if opts.trace.is_some() {
        pipe.enable_trace();
    }
    let series_every = cfg.run.series_every.unwrap_or((steps / 100).max(10));
    let mut series = Series::create(&dir.join("series.csv"))?;
    series.push(0, &sim.diagnostics())?;
    let mut pseries = match particle_row(&sim) {
        Some(row) => {
            let mut ps = ParticleSeries::create(&dir.join("particles.csv"))?;
            ps.push(&row)?;
            Some(ps)
        }
        None => None,
    };
    // Body 0 over time (position, velocity, hydrodynamic force) for scenes with few bodies.
    let mut trajectory: Vec<(f64, blockflow_kernels::rigid::Body)> = Vec::new();
    let mut traj_text = String::from("step,time,x,y,z,vx,vy,vz,wx,wy,wz,fx,fy,fz\n");
    let mut record = |sim: &Simulation<T>, text: &mut String| {
        if let Some(p) = sim.particles.as_ref() {
            if let Some(b) = p.bodies(sim.step).first() {
                let t = sim.step as f64 * p.dt;
                trajectory.push((t, *b));
                let (x, v, w, f) = (b.position, b.velocity, b.angular_velocity, b.force);
                *text += &format!(
                    "{},{t:.9e},{:.12e},{:.12e},{:.12e},{:.12e},{:.12e},{:.12e},{:.12e},{:.12e},{:.12e},{:.12e},{:.12e},{:.12e}\n",
                    sim.step, x.x, x.y, x.z, v.x, v.y, v.z, w.x, w.y, w.z, f.x, f.y, f.z
                );
            }
        }
    };
    record(&sim, &mut traj_text);
    let vtk_every = opts.vtk_every.or(cfg.run.vtk_every);
    let mut pvtk = match (vtk_every, &sim.particles) {
        (Some(_), Some(_)) => Some(ParticleVtkSeries::new(&dir).map_err(|e| io_err(&dir, e))?),
        _ => None,
    };
    let mut vtk = match vtk_every {
        Some(_) => {
            let mut v = VtkSeries::new(&dir).map_err(|e| io_err(&dir, e))?;
            vtk_step(&mut v, pvtk.as_mut(), &sim)?;
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
        processes: cfg.processes.count,
        threads_per_process: cfg.processes.threads_per_process,
        precision: T::NAME.to_string(),
        tau: sim.params.tau,
        magic: sim.params.magic,
        cores: pipe.executor().cores().to_vec(),
        ..Default::default()
    };
    if let Some(p) = sim.particles.as_mut() {
        let bodies = p.bodies(0);
        p.update_active(1, &bodies);
    }
    let tasks_per_step = pipe.tasks_per_step(&sim);
    let mut loop_time = 0.0;
    let mut failure = None;
    let next_event = |s: u64| {
        let mut n = steps;
        n = n.min((s / series_every + 1) * series_every);
        if let Some(e) = vtk_every {
            n = n.min((s / e + 1) * e);
        }
        n.min(s + 256)
    };
    while sim.step < steps {
        let target = next_event(sim.step);
        let ts = Instant::now();
        let todo = target - sim.step;
        let r = pipe.advance(&mut sim, todo);
        loop_time += ts.elapsed().as_secs_f64();
        if let Err(e) = r {
            failure = Some(e);
            break;
        }
        let s = sim.step;
        if s % series_every == 0 || s == steps {
            series.push(s, &sim.diagnostics())?;
            if let (Some(ps), Some(row)) = (pseries.as_mut(), particle_row(&sim)) {
                ps.push(&row)?;
            }
            record(&sim, &mut traj_text);
        }
        if let (Some(v), Some(every)) = (vtk.as_mut(), vtk_every) {
            if s % every == 0 {
                vtk_step(v, pvtk.as_mut(), &sim)?;
            }
        }
        bar.set_position(s);
    }
    bar.finish_and_clear();
    pipe.close_interval(&sim);
    series.finish()?;
    if let Some(ps) = pseries {
        ps.finish()?;
    }
    if sim.particles.as_ref().is_some_and(|p| p.bodies(sim.step).len() <= 16) {
        let path = dir.join("trajectory.csv");
        std::fs::write(&path, &traj_text).map_err(|e| io_err(&path, e))?;
    }
    if let Some(path) = &opts.trace {
        pipe.write_trace(path).map_err(|e| io_err(path, e))?;
    }
    write_intervals(&dir.join("intervals.csv"), &pipe.intervals)?;
    summary.steps = sim.step;
    summary.wall_seconds = loop_time;
    summary.mlups = if loop_time > 0.0 {
        (sim.fluid_cells() as f64 * sim.step as f64) / loop_time / 1e6
    } else {
        0.0
    };
    let t = &pipe.totals;
    let coupled = sim.blocks.iter().any(|b| b.particle_cells().is_some());
    summary.parts_seconds = PartsSeconds {
        lbm: t.part_cpu[0],
        boundary: t.part_cpu[1],
        exchange: t.part_cpu[2],
        rigid_body: sim.particles.as_ref().map(|_| t.part_cpu[3]),
        map: coupled.then_some(t.part_cpu[4]),
        reconstruct: coupled.then_some(t.part_cpu[5]),
    };
    summary.particles = sim.particles.as_ref().map(|p| ParticleSummary {
        bodies: p.bodies(sim.step).len(),
        subcycles: p.subcycles,
        substeps: p.counters.substeps,
        contacts_per_substep: p.counters.contacts as f64 / p.counters.substeps.max(1) as f64,
        max_penetration: p.counters.max_penetration,
        active_blocks: p.active.iter().filter(|&&a| a).count(),
    });
    let owners = pipe.owners();
    let procs = cfg.processes.count;
    let imbalance: Vec<f64> = pipe.intervals.iter().map(|i| i.imbalance).collect();
    summary.balance = Some(BalanceSummary {
        strategy: format!("{:?}", cfg.balance.strategy).to_lowercase(),
        interval: cfg.balance.interval,
        imbalance_median: median(&imbalance),
        imbalance,
        predicted_imbalance: pipe
            .intervals
            .iter()
            .map(|i| i.predicted_imbalance.is_finite().then_some(i.predicted_imbalance))
            .collect(),
        modeled_seconds: pipe.intervals.iter().map(|i| i.modeled_seconds).sum(),
        bsp_seconds: pipe.intervals.iter().map(|i| i.bsp_seconds).sum(),
        balance_seconds: pipe.intervals.iter().map(|i| i.balance_seconds).sum(),
        migrated_bytes: pipe.intervals.iter().map(|i| i.migrated_bytes).sum(),
        latency: cfg.balance.latency,
        bandwidth: cfg.balance.bandwidth,
        edge_cut_mean: edge_cut_mean(&sim.domain, owners, procs),
        migrated_blocks: pipe.balancer.as_ref().map_or(0, |b| b.migrated),
        blocks_per_process: (0..procs as u32)
            .map(|p| owners.iter().filter(|&&o| o == p).count())
            .collect(),
        message_bytes: t.message_bytes,
        remote_messages: t.remote_messages,
        local_copies: t.local_copies,
        tasks_per_step,
    });
    let (sweeps, bnd, msgs) = sim.blocks.iter().fold((0, 0, 0), |(s, b, m), blk| {
        if blk.fluid_cells == 0 {
            (s, b, m)
        } else {
            (s + 1, b + usize::from(!blk.links.is_empty()), m + blk.recv.len())
        }
    });
    summary.work = WorkSummary {
        fluid_sweeps_per_step: sweeps,
        boundary_passes_per_step: bnd,
        messages_per_step: msgs,
        blocks_without_fluid: sim.blocks.iter().filter(|b| b.fluid_cells == 0).count(),
        blocks_without_boundary: sim
            .blocks
            .iter()
            .filter(|b| b.fluid_cells > 0 && b.links.is_empty())
            .count(),
    };
    summary.checksum = Checksums {
        fluid: format!("{:016x}", sim.checksum()),
        particles: sim.particles.as_ref().map(|p| format!("{:016x}", p.checksum(sim.step))),
    };
    if let Some(inst) = failure {
        let e = inst;
        summary.status = "unstable".to_string();
        summary.error = Some(e.to_string());
        write_summary(&dir, &summary)?;
        return Err(e);
    }
    summary.observables = (scene.observe)(&RunView {
        sim: &sim,
        trajectory: &trajectory,
    });
    summary.status = "ok".to_string();
    write_summary(&dir, &summary)?;
    Ok(summary)
}
