//! `blockflow run`: builds a scene, steps it, writes summary.json, series.csv and optional VTK.

use crate::checkpoint::{self, BalanceState, Checkpoint, CheckpointInput};
use crate::config::{Config, Precision};
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
    /// `--restart PATH`: continue from this checkpoint (read and checked; the configuration must be
    /// [`crate::checkpoint::restart_config`]'s).
    pub restart: Option<std::sync::Arc<Checkpoint>>,
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

/// Writes `bytes` to `path` through `path.tmp` and a rename: the file is either absent, the old one or
/// complete, never half-written.
fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    if let Err(e) = std::fs::write(&tmp, bytes) {
        let _ = std::fs::remove_file(&tmp);
        return Err(io_err(&tmp, e));
    }
    std::fs::rename(&tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        io_err(path, e)
    })
}

fn write_summary(dir: &Path, s: &Summary) -> Result<()> {
    let text = serde_json::to_string_pretty(s).expect("summary serialises");
    write_atomic(&dir.join("summary.json"), (text + "\n").as_bytes())
}

/// Creates the output folder and checks that a file can be written in it (before the first step).
fn check_writable(dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir)
        .map_err(|e| Error::Io(format!("output folder {}: cannot be created: {e}", dir.display())))?;
    let probe = dir.join(format!(".blockflow-write-check-{}", std::process::id()));
    std::fs::write(&probe, b"blockflow")
        .and_then(|_| std::fs::remove_file(&probe))
        .map_err(|e| Error::Io(format!("output folder {} is not writable: {e}", dir.display())))
}

/// Bytes available to a new allocation: the smallest of `MemAvailable` (/proc/meminfo), the cgroup v2
/// `memory.max` and four fifths of the soft `RLIMIT_AS` (None where /proc/meminfo cannot be read).
pub fn available_memory() -> Option<u128> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: u128 = line.split_whitespace().nth(1)?.parse().ok()?;
    let mut avail = kb * 1024;
    // A container's or batch job's cgroup limit (v2) and the process's own address-space limit bound it
    // too (with a fifth left for the binary, the threads' stacks and the allocator).
    if let Some(max) = std::fs::read_to_string("/sys/fs/cgroup/memory.max")
        .ok()
        .and_then(|t| t.trim().parse::<u128>().ok())
    {
        avail = avail.min(max);
    }
    let mut lim = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit writes the struct it is given.
    if unsafe { libc::getrlimit(libc::RLIMIT_AS, &mut lim) } == 0 && lim.rlim_cur != libc::RLIM_INFINITY {
        avail = avail.min(lim.rlim_cur as u128 / 5 * 4);
    }
    Some(avail)
}

/// The memory a scene's state needs, estimated before anything is allocated: (total, PDFs, flags,
/// particles) in bytes. PDFs: two fields of 19 values per cell with the ghost layer, in the precision;
/// flags: one byte per cell with the ghost layer; particles: each body's copies (two published lists, the
/// rigid-body result, shadows) and the per-block bookkeeping.
pub fn estimate_memory(cfg: &Config, scene: &Scene) -> Result<(u128, u128, u128, u128)> {
    let d = scenes::domain_for(&cfg.domain, scene)?;
    let blocks: u128 = d.blocks.iter().map(|&x| x as u128).product();
    let full: u128 = d.block_size.iter().map(|&x| x as u128 + 2).product();
    let bytes: u128 = match cfg.fluid.precision {
        Precision::F64 => 8,
        Precision::F32 => 4,
    };
    let fluid = cfg.fluid.enabled && !scene.geometry.no_fluid;
    let pdf = if fluid { 2 * 19 * blocks * full * bytes } else { 0 };
    let flags = blocks * full;
    let particles = match &scene.particles {
        Some(ps) => {
            let body = std::mem::size_of::<blockflow_kernels::rigid::Body>() as u128;
            ps.bodies.len() as u128 * body * 8 + blocks * 1024
        }
        None => 0,
    };
    Ok((pdf + flags + particles, pdf, flags, particles))
}

/// Refuses a scene whose estimated memory ([`estimate_memory`]) exceeds what the machine has available.
pub fn check_memory(cfg: &Config, scene: &Scene) -> Result<()> {
    let (total, pdf, flags, particles) = estimate_memory(cfg, scene)?;
    if let Some(avail) = available_memory() {
        if total > avail {
            return Err(Error::Config(format!(
                "scene {} needs an estimated {total} bytes ({:.1} GiB: PDFs {pdf}, flags {flags}, particles \
                 {particles}) but the machine has {avail} bytes available (MemAvailable, cgroup and address-space limits); use fewer or smaller \
                 blocks (domain.blocks, domain.block_size, scene.resolution)",
                scene.name,
                total as f64 / (1u64 << 30) as f64
            )));
        }
    }
    Ok(())
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

pub use crate::run_setup::*;

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
    write_atomic(path, text.as_bytes())
}

/// The configuration a run's output records (effective.toml and every checkpoint): `cfg` with the
/// resolved step count, output folder and VTK interval filled in, so that the file alone reproduces the run.
fn effective_text(cfg: &Config, steps: u64, dir: &Path, vtk_every: Option<u64>) -> String {
    let mut c = cfg.clone();
    c.run.steps = Some(steps);
    let abs = std::fs::canonicalize(dir).unwrap_or_else(|_| dir.to_path_buf());
    c.run.out = Some(abs.display().to_string());
    c.run.vtk_every = vtk_every;
    c.to_toml()
}

fn run_t<T: Real>(cfg: &Config, scene: Scene, opts: &RunOptions) -> Result<Summary> {
    let steps = opts.steps.or(cfg.run.steps).unwrap_or(scene.steps);
    let dir = output_dir(cfg, opts);
    if let Some(ck) = &opts.restart {
        if ck.step > steps {
            return Err(Error::Config(format!(
                "run.steps = {steps}, but checkpoint {} is at step {}; ask for at least that many (--steps)",
                ck.path.display(),
                ck.step
            )));
        }
    }
    // Before anything is allocated or written: the memory estimate, then the output folder.
    check_memory(cfg, &scene)?;
    check_writable(&dir)?;
    let ck_dir = dir.join("checkpoints");
    let checkpointing = cfg.run.checkpoint_every.is_some() || cfg.run.checkpoint_wall.is_some();
    if checkpointing {
        check_writable(&ck_dir)?;
    }
    let _ = std::fs::remove_file(dir.join("summary.json"));
    let vtk_every = opts.vtk_every.or(cfg.run.vtk_every);
    let eff_text = effective_text(cfg, steps, &dir, vtk_every);
    write_atomic(&dir.join("effective.toml"), eff_text.as_bytes())?;
    let mut sim = build_sim::<T>(cfg, &scene)?;
    let mut pipe = make_pipeline(cfg, &sim)?;
    pipe.no_skip = cfg.run.no_skip;
    if let Some(ck) = &opts.restart {
        let owners = pipe.owners().to_vec();
        ck.restore(&mut sim, &owners, pipe.executor())?;
        pipe.resume_at(sim.step);
        if let (Some(b), Some(st)) = (pipe.balancer.as_mut(), ck.balance.as_ref()) {
            st.restore(b);
        }
    }
    let start_step = sim.step;
    if opts.trace.is_some() {
        pipe.enable_trace();
    }
    let series_every = cfg.run.series_every.unwrap_or((steps / 100).max(10));
    // Time series are written to `.partial` files and renamed when the run ends: a run that fails
    // leaves no file that looks like a finished result.
    let series_path = dir.join("series.csv");
    let pseries_path = dir.join("particles.csv");
    let partial = |p: &Path| {
        let mut s = p.as_os_str().to_owned();
        s.push(".partial");
        PathBuf::from(s)
    };
    let mut series = Series::create(&partial(&series_path))?;
    series.push(sim.step, &sim.diagnostics())?;
    let mut pseries = match particle_row(&sim) {
        Some(row) => {
            let mut ps = ParticleSeries::create(&partial(&pseries_path))?;
            ps.push(&row)?;
            Some(ps)
        }
        None => None,
    };
    // Body 0 over time (position, velocity, hydrodynamic force) for scenes with few bodies: recorded after
    // every graph run (so that peaks are not missed between series rows), in lattice units and, for scenes
    // set up in SI units, in SI units as well.
    let few_bodies = sim.particles.as_ref().is_some_and(|p| p.bodies(sim.step).len() <= 16);
    let mut trajectory: Vec<(f64, blockflow_kernels::rigid::Body)> = Vec::new();
    let mut traj_text = String::from("step,time,x,y,z,vx,vy,vz,wx,wy,wz,fx,fy,fz\n");
    let mut traj_si = String::from("step,time_s,x_m,y_m,z_m,vx_m_s,vy_m_s,vz_m_s,fx_n,fy_n,fz_n\n");
    let units = scene.units;
    let mut record = |sim: &Simulation<T>, text: &mut String, si: &mut String| {
        if !few_bodies {
            return;
        }
        if let Some(p) = sim.particles.as_ref() {
            if let Some(b) = p.bodies(sim.step).first() {
                let t = sim.step as f64 * p.dt;
                trajectory.push((t, *b));
                let (x, v, w, f) = (b.position, b.velocity, b.angular_velocity, b.force);
                *text += &format!(
                    "{},{t:.9e},{:.12e},{:.12e},{:.12e},{:.12e},{:.12e},{:.12e},{:.12e},{:.12e},{:.12e},{:.12e},{:.12e},{:.12e}\n",
                    sim.step, x.x, x.y, x.z, v.x, v.y, v.z, w.x, w.y, w.z, f.x, f.y, f.z
                );
                if let Some(u) = units {
                    let (lv, lf) = (u.dx / u.dt, u.density * u.dx.powi(4) / (u.dt * u.dt));
                    *si += &format!(
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
    };
    record(&sim, &mut traj_text, &mut traj_si);
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
        b.set_position(sim.step);
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
        restarted_from: opts.restart.as_ref().map(|c| c.path.display().to_string()),
        restart_step: opts.restart.as_ref().map(|c| c.step),
        units: scene.units,
        ..Default::default()
    };
    if let Some(p) = sim.particles.as_mut() {
        let bodies = p.bodies(start_step);
        p.update_active(1, &bodies);
    }
    let tasks_per_step = pipe.tasks_per_step(&sim);
    let mut loop_time = 0.0;
    let mut failure = None;
    let ck_every = cfg.run.checkpoint_every;
    let next_event = |s: u64| {
        let mut n = steps;
        n = n.min((s / series_every + 1) * series_every);
        if let Some(e) = vtk_every {
            n = n.min((s / e + 1) * e);
        }
        if let Some(e) = ck_every {
            n = n.min((s / e + 1) * e);
        }
        n.min(s + 256)
    };
    // The run loop advances one graph run (processes.steps_per_graph steps) at a time, so that a signal is
    // answered at the end of the graph run under way (the graph runs are the same as with longer chunks).
    let chunk = cfg.processes.steps_per_graph.max(1) as u64;
    let mut last_checkpoint: Option<(u64, PathBuf)> = None;
    let (mut ck_count, mut ck_seconds, mut ck_bytes) = (0u64, 0.0, 0u64);
    let mut last_checkpoint_time = Instant::now();
    let save = |sim: &Simulation<T>, pipe: &Pipeline<T>| -> Result<checkpoint::Written> {
        let input = CheckpointInput {
            config: &eff_text,
            scene: scene.name,
            balance: pipe.balancer.as_ref().map(|b| BalanceState::of(cfg, b)),
        };
        checkpoint::write(&ck_dir, sim, &input, cfg.run.checkpoints_kept)
    };
    let mut interrupted = None;
    while sim.step < steps {
        if let Some(sig) = checkpoint::interrupted() {
            interrupted = Some(sig);
            break;
        }
        let target = next_event(sim.step);
        let ts = Instant::now();
        let todo = (target - sim.step).min(chunk);
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
        }
        record(&sim, &mut traj_text, &mut traj_si);
        if let (Some(v), Some(every)) = (vtk.as_mut(), vtk_every) {
            if s % every == 0 {
                vtk_step(v, pvtk.as_mut(), &sim)?;
            }
        }
        let due = ck_every.is_some_and(|n| s % n == 0)
            || cfg
                .run
                .checkpoint_wall
                .is_some_and(|w| last_checkpoint_time.elapsed().as_secs_f64() >= w);
        if due {
            let w = save(&sim, &pipe)?;
            (ck_count, ck_seconds, ck_bytes) = (ck_count + 1, ck_seconds + w.seconds, w.bytes);
            last_checkpoint = Some((s, w.path));
            last_checkpoint_time = Instant::now();
        }
        bar.set_position(s);
    }
    // Interrupted: a checkpoint of the step reached (unless one was just written).
    if interrupted.is_some() && last_checkpoint.as_ref().is_none_or(|(s, _)| *s != sim.step) {
        if !checkpointing {
            std::fs::create_dir_all(&ck_dir).map_err(|e| io_err(&ck_dir, e))?;
        }
        let w = save(&sim, &pipe)?;
        (ck_count, ck_seconds, ck_bytes) = (ck_count + 1, ck_seconds + w.seconds, w.bytes);
        last_checkpoint = Some((sim.step, w.path));
    }
    bar.finish_and_clear();
    pipe.close_interval(&sim);
    series.finish()?;
    std::fs::rename(partial(&series_path), &series_path).map_err(|e| io_err(&series_path, e))?;
    if let Some(ps) = pseries {
        ps.finish()?;
        std::fs::rename(partial(&pseries_path), &pseries_path).map_err(|e| io_err(&pseries_path, e))?;
    }
    if few_bodies {
        write_atomic(&dir.join("trajectory.csv"), traj_text.as_bytes())?;
        if units.is_some() {
            write_atomic(&dir.join("trajectory_si.csv"), traj_si.as_bytes())?;
        }
    }
    if let Some(path) = &opts.trace {
        pipe.write_trace(path).map_err(|e| io_err(path, e))?;
    }
    write_intervals(&dir.join("intervals.csv"), &pipe.intervals)?;
    let done = sim.step - start_step;
    summary.steps = sim.step;
    summary.wall_seconds = loop_time;
    summary.mlups = if loop_time > 0.0 {
        (sim.fluid_cells() as f64 * done as f64) / loop_time / 1e6
    } else {
        0.0
    };
    summary.checkpoint = last_checkpoint.as_ref().map(|(_, p)| p.display().to_string());
    if ck_count > 0 {
        summary.checkpoints_written = Some(ck_count);
        summary.checkpoint_seconds = Some(ck_seconds);
        summary.checkpoint_bytes = Some(ck_bytes);
    }
    let t = &pipe.totals;
    summary.no_skip = pipe.no_skip;
    summary.tasks_by_kind = crate::pipeline::TASK_KINDS
        .iter()
        .zip(t.tasks_by_kind)
        .filter(|(_, n)| *n > 0)
        .map(|(k, n)| (k.to_string(), n))
        .collect();
    summary.tasks_cpu_seconds_by_kind = crate::pipeline::TASK_KINDS
        .iter()
        .zip(t.tasks_by_kind.iter().zip(t.cpu_by_kind))
        .filter(|(_, (n, _))| **n > 0)
        .map(|(k, (_, c))| (k.to_string(), c))
        .collect();
    let rules = crate::pipeline::SKIP_RULES.iter().map(|r| r.to_string());
    summary.unskipped_by_rule = pipe.no_skip.then(|| rules.clone().zip(t.unskipped).collect());
    summary.unskipped_cpu_seconds_by_rule = pipe.no_skip.then(|| rules.zip(t.unskipped_cpu).collect());
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
        imbalance_median: if imbalance.is_empty() {
            0.0
        } else {
            crate::estimator::stats::median(&imbalance)
        },
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
    if let Some(signal) = interrupted {
        let e = Error::Interrupted {
            signal,
            step: sim.step,
            checkpoint: summary.checkpoint.clone(),
        };
        summary.status = "interrupted".to_string();
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
