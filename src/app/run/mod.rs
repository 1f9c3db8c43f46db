//! `blockflow run`: builds a scene, steps it through the time loop with its outputs attached as
//! observers, writes summary.json, series.csv, intervals.csv and the optional VTK, trace and
//! checkpoints.

mod outputs;
mod recap;
mod report;
pub mod resources;
mod snapshots;
mod summary;

use crate::app::signals;
use crate::checkpoint::{self, Checkpoint};
use crate::config::{Config, Precision};
use crate::error::{Error, Result};
use crate::io::plots;
use crate::io::summary::Summary;
use crate::metrics::interval::IntervalStats;
use crate::physics::simulation::Simulation;
use crate::ranks::World;
use crate::scenes::{self, FluidView, Scene};
use crate::timeloop::{Flow, Handle, Recording, RunEnd, TimeLoop};
use crate::util::fs::{ensure_writable, write_atomic};
use blockflow_kernels::rigid::Body;
use blockflow_kernels::Real;
use outputs::{CheckpointWriter, Progress, SeriesWriter, StopOnSignal, TrajectoryRecorder, VtkWriter};
use snapshots::SliceWriter;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Run a scene and write summary.json, series.csv (and VTK with --vtk) to the output folder. SIGINT /
/// SIGTERM stop the run at the end of the graph run under way, write a checkpoint and summary.json
/// (`"status": "interrupted"`) and exit with 128 + the signal number; a second signal ends it at once.
#[derive(clap::Args, Debug)]
#[allow(rustdoc::invalid_html_tags)] // the doc comments are the command-line help: `<step>` is literal there
pub struct RunArgs {
    /// Scene file (TOML), e.g. configs/hopper-small.toml. Without one, the demo built into the binary
    /// (configs/demo.toml: spheres settling through a hopper on 2 virtual processes, rebalanced every 100
    /// steps). With --restart it may be left out; if given, it must describe the checkpoint's physics.
    pub scene: Option<PathBuf>,
    /// Override a key of the scene file: --set fluid.tau=0.6 (repeatable; same dotted path as the file).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Output folder (default: run.out, else out/<scene file name>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Number of time steps (default: run.steps, else the scene's own).
    #[arg(long)]
    pub steps: Option<u64>,
    /// Write VTK output (fluid.pvd) every N steps.
    #[arg(long, value_name = "EVERY")]
    pub vtk: Option<u64>,
    /// Draw one plane of the flow every N steps: OUT/slices/step-<step>.png and OUT/slices.gif
    /// (run.png_every; the plane: run.png_normal, run.png_at).
    #[arg(long, value_name = "EVERY")]
    pub png: Option<u64>,
    /// Virtual processes P (processes.count).
    #[arg(long)]
    pub processes: Option<usize>,
    /// Ranks R that share no memory, run in this process (processes.ranks): each holds only its own
    /// blocks and everything between them is a message, the in-process stand-in for MPI ranks (each rank
    /// is one process of --threads-per-process threads).
    #[arg(long)]
    pub ranks: Option<usize>,
    /// Threads per process T (processes.threads_per_process).
    #[arg(long)]
    pub threads_per_process: Option<usize>,
    /// Pinning: compact, scatter, none or a core list such as 0,1 (processes.pin).
    #[arg(long)]
    pub pin: Option<String>,
    /// Assignment strategy: none, hilbert, morton, diffusive, metis (balance.strategy).
    #[arg(long)]
    pub balance: Option<String>,
    /// Steps per balancing / measurement interval (balance.interval).
    #[arg(long)]
    pub interval: Option<u64>,
    /// Write a Chrome trace (Perfetto, chrome://tracing) of every task to FILE.
    #[arg(long, value_name = "FILE")]
    pub trace: Option<PathBuf>,
    /// Write a checkpoint to OUT/checkpoints/step-<step> whenever the step is a multiple of N
    /// (run.checkpoint_every).
    #[arg(long, value_name = "N")]
    pub checkpoint_every: Option<u64>,
    /// Write a checkpoint when SECONDS of wall-clock time have passed since the last one
    /// (run.checkpoint_wall).
    #[arg(long, value_name = "SECONDS")]
    pub checkpoint_wall: Option<f64>,
    /// Checkpoints to keep, the newest (run.checkpoints_kept, default 2).
    #[arg(long, value_name = "K")]
    pub checkpoints_kept: Option<usize>,
    /// Continue from a checkpoint file (or the newest one in a folder or its checkpoints/ subfolder).
    /// The configuration is the checkpoint's, with this command line's overrides of run.*,
    /// processes.* and balance.* keys on top; the final state is bitwise the uninterrupted run's.
    #[arg(long, value_name = "PATH")]
    pub restart: Option<PathBuf>,
    /// Run every task on every block: switch off the skip rules (outside blocks, blocks without
    /// boundary cells, blocks without particles, static geometry mapped once, the fused kernel) to
    /// measure what they save (run.no_skip = true). Slower; the results are bitwise the same.
    #[arg(long)]
    pub no_skip: bool,
}

impl RunArgs {
    /// The `--set` overrides of the arguments: the command line's options are overrides of the stable
    /// keys, checked like the file's values.
    fn overrides(&self) -> Result<Vec<String>> {
        let mut set = self.set.clone();
        if let Some(n) = self.checkpoint_every {
            set.push(format!("run.checkpoint_every={n}"));
        }
        if let Some(w) = self.checkpoint_wall {
            if !w.is_finite() {
                return Err(Error::Config(format!(
                    "--checkpoint-wall {w}: must be a finite number of seconds > 0"
                )));
            }
            set.push(format!("run.checkpoint_wall={w:?}"));
        }
        if let Some(k) = self.checkpoints_kept {
            set.push(format!("run.checkpoints_kept={k}"));
        }
        if let Some(n) = self.png {
            set.push(format!("run.png_every={n}"));
        }
        if self.no_skip {
            set.push("run.no_skip=true".into());
        }
        if let Some(p) = self.processes {
            set.push(format!("processes.count={p}"));
        }
        if let Some(r) = self.ranks {
            set.push(format!("processes.ranks={r}"));
        }
        if let Some(t) = self.threads_per_process {
            set.push(format!("processes.threads_per_process={t}"));
        }
        if let Some(p) = &self.pin {
            set.push(format!("processes.pin=\"{}\"", p.replace('"', "")));
        }
        if let Some(b) = &self.balance {
            set.push(format!("balance.strategy=\"{}\"", b.replace('"', "")));
        }
        if let Some(i) = self.interval {
            set.push(format!("balance.interval={i}"));
        }
        Ok(set)
    }
}

/// Runs `blockflow run` and prints its one-paragraph result.
pub fn execute(args: RunArgs) -> Result<()> {
    if args.vtk == Some(0) {
        return Err(Error::Config("--vtk 0: must be at least 1".into()));
    }
    let set = args.overrides()?;
    let (cfg, restart) = match &args.restart {
        Some(path) => {
            let ck = Checkpoint::read(&checkpoint::resolve(path)?)?;
            let cfg = checkpoint::restart_config(&ck, args.scene.as_deref(), &set)?;
            (cfg, Some(Arc::new(ck)))
        }
        None => match args.scene.as_deref() {
            Some(path) => (crate::config::load(path, &set)?, None),
            None => (crate::config::parse(DEMO, DEMO_NAME, &set)?, None),
        },
    };
    signals::install_handlers()?;
    let opts = RunOptions {
        steps: args.steps,
        out: args.out,
        vtk_every: args.vtk,
        progress: true,
        scene_path: args
            .scene
            .or_else(|| args.restart.is_none().then(|| PathBuf::from(DEMO_NAME))),
        trace: args.trace,
        restart,
    };
    let dir = output_dir(&cfg, &opts);
    let s = run(&cfg, &opts)?;
    if crate::app::mpi::world().is_none_or(|w| w.is_root()) {
        report::write(&dir, &s, &command_line())?;
        crate::app::print_out(&recap::recap(&s, &cfg, &dir));
    }
    Ok(())
}

/// This process's command line, quoted for a POSIX shell where a word needs it.
fn command_line() -> String {
    let quote = |a: String| {
        if !a.is_empty() && a.chars().all(|c| c.is_ascii_alphanumeric() || "-_./=:,@+".contains(c)) {
            a
        } else {
            format!("'{}'", a.replace('\'', "'\\''"))
        }
    };
    let mut args = std::env::args();
    let program = args.next().map_or("blockflow".to_string(), |p| {
        Path::new(&p)
            .file_name()
            .map_or(p.clone(), |n| n.to_string_lossy().to_string())
    });
    std::iter::once(program)
        .chain(args.map(quote))
        .collect::<Vec<_>>()
        .join(" ")
}

/// The scene `blockflow run` runs without a scene file: `configs/demo.toml`, built into the binary.
pub const DEMO: &str = include_str!("../../../configs/demo.toml");

/// The name the demo's messages and output folder (`out/demo`) go by.
pub const DEMO_NAME: &str = "configs/demo.toml";

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
    pub restart: Option<Arc<Checkpoint>>,
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
/// error is returned. With `processes.ranks` = R > 1 the run is spread over R ranks in this process that
/// share no memory (`processes.count` is then R); rank 0's summary is returned, or the error of the rank
/// that failed first.
pub fn run(cfg: &Config, opts: &RunOptions) -> Result<Summary> {
    if let Some(world) = crate::app::mpi::world() {
        // An MPI job: this process is one rank of it.
        let n = world.ranks();
        if cfg.processes.ranks > 1 && cfg.processes.ranks != n {
            return Err(Error::Config(format!(
                "processes.ranks = {}, but mpirun started {n} ranks: the ranks are the MPI job's; leave --ranks \
                 out",
                cfg.processes.ranks
            )));
        }
        let mut cfg = cfg.clone();
        (cfg.processes.ranks, cfg.processes.count) = (n, n);
        let r = run_on(&cfg, opts, world.clone());
        if let Err(e) = &r {
            if !matches!(e, Error::Aborted { .. }) {
                world.abort(e);
            }
        }
        return r;
    }
    let ranks = cfg.processes.ranks;
    if ranks <= 1 {
        return run_on(cfg, opts, Arc::new(World::single()));
    }
    let mut cfg = cfg.clone();
    cfg.processes.count = ranks;
    resources::check_memory_of_copies(&cfg, &scenes::build(&cfg)?, ranks)?;
    let results = crate::ranks::run_loopback(ranks, None, |w| {
        let w = Arc::new(w);
        let r = run_on(&cfg, opts, w.clone());
        if let Err(e) = &r {
            if !matches!(e, Error::Aborted { .. }) {
                w.abort(e);
            }
        }
        r
    });
    first_failure(results)
}

/// Rank 0's result when every rank succeeded, else the first error in rank order that is not an echo
/// of another rank's abort (a rank that failed on its own), else the first error.
pub fn first_failure<R>(results: Vec<Result<R>>) -> Result<R> {
    let own = results
        .iter()
        .position(|r| matches!(r, Err(e) if !matches!(e, Error::Aborted { .. })));
    let pick = own.or_else(|| results.iter().position(|r| r.is_err())).unwrap_or(0);
    results.into_iter().nth(pick).expect("a result per rank")
}

/// Runs a configuration on this rank of `world` (every rank of the world calls this at once).
pub fn run_on(cfg: &Config, opts: &RunOptions, world: Arc<World>) -> Result<Summary> {
    let scene = scenes::build(cfg)?;
    match cfg.fluid.precision {
        Precision::F64 => run_t::<f64>(cfg, scene, opts, world),
        Precision::F32 => run_t::<f32>(cfg, scene, opts, world),
    }
}

/// The simulation plus what the run recorded over time, as the scenes' observables see it; under
/// ranks, rank 0's view of the whole state gathered from every rank.
struct RunView<'a, T: Real> {
    sim: &'a Simulation<T>,
    trajectory: &'a [(f64, Body)],
    gathered: Option<Gathered>,
}

/// The whole state rank 0 gathered for the observables.
struct Gathered {
    cells: Vec<crate::ranks::views::BlockCells>,
    bodies: Vec<Body>,
    forces: Vec<crate::physics::particle_cells::BodyForce>,
}

impl<T: Real> FluidView for RunView<'_, T> {
    fn visit(&self, f: &mut dyn FnMut([usize; 3], f64, [f64; 3])) {
        match &self.gathered {
            Some(g) => g.cells.iter().for_each(|c| c.visit(f)),
            None => self.sim.visit(f),
        }
    }
    fn steps_taken(&self) -> u64 {
        self.sim.step
    }
    fn bodies(&self) -> Vec<Body> {
        match &self.gathered {
            Some(g) => g.bodies.clone(),
            None => self.sim.bodies(),
        }
    }
    fn hydro_forces(&self) -> Vec<crate::physics::particle_cells::BodyForce> {
        match &self.gathered {
            Some(g) => g.forces.clone(),
            None => self.sim.hydro_forces(),
        }
    }
    fn trajectory(&self) -> Vec<(f64, Body)> {
        self.trajectory.to_vec()
    }
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

fn write_summary(dir: &Path, s: &Summary) -> Result<()> {
    let text = serde_json::to_string_pretty(s).expect("summary serialises");
    write_atomic(&dir.join("summary.json"), (text + "\n").as_bytes())
}

/// What a run writes where, settled before anything is allocated.
struct Plan {
    /// Total steps (the end of the run).
    steps: u64,
    /// The output folder.
    dir: PathBuf,
    /// VTK interval, if any.
    vtk_every: Option<u64>,
    /// The effective configuration as every checkpoint carries it (effective.toml's, with one rank).
    config_text: String,
}

/// Checks what can be checked before anything is allocated or written (the checkpoint's step, the
/// memory estimate, the output folders), then writes effective.toml (rank 0 does the writing).
fn plan(cfg: &Config, scene: &Scene, opts: &RunOptions, root: bool) -> Result<Plan> {
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
    resources::check_memory(cfg, scene)?;
    let vtk_every = opts.vtk_every.or(cfg.run.vtk_every);
    if root {
        ensure_writable(&dir)?;
        if cfg.run.checkpoint_every.is_some() || cfg.run.checkpoint_wall.is_some() {
            ensure_writable(&dir.join("checkpoints"))?;
        }
        let _ = std::fs::remove_file(dir.join("summary.json"));
        remove_old_pictures(&dir);
    }
    let config_text = effective_text(cfg, steps, &dir, vtk_every);
    if root {
        write_atomic(&dir.join("effective.toml"), config_text.as_bytes())?;
    }
    // A checkpoint is the same bytes whether ranks or virtual processes wrote it: its configuration
    // names the processes (`processes.count`), not whether they shared memory.
    let mut placed = cfg.clone();
    placed.processes.ranks = 1;
    let config_text = effective_text(&placed, steps, &dir, vtk_every);
    Ok(Plan {
        steps,
        dir,
        vtk_every,
        config_text,
    })
}

/// Removes the pictures of an earlier run in `dir` (`slices.gif`, `slices/step-*.png`), so that the
/// folder and its report show only this run's.
fn remove_old_pictures(dir: &Path) {
    let _ = std::fs::remove_file(dir.join("slices.gif"));
    if let Ok(entries) = std::fs::read_dir(dir.join("slices")) {
        for e in entries.flatten() {
            let name = e.file_name().to_string_lossy().to_string();
            if name.starts_with("step-") && name.ends_with(".png") {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }
}

/// The fields of summary.json known before the first step (collective under ranks: the PDF bytes and
/// cores of every rank).
fn summary_head<T: Real>(
    tl: &TimeLoop<T>,
    cfg: &Config,
    scene: &Scene,
    opts: &RunOptions,
    steps: u64,
) -> Result<Summary> {
    let sim = tl.sim();
    let world = tl.world();
    let mut pdf_bytes = [sim.blocks.iter().map(|b| b.pdf_bytes() as u64).sum::<u64>()];
    let mut cores = tl.pipeline().executor().cores().to_vec();
    if !world.is_single() {
        world.sum(&mut pdf_bytes)?;
        let mine: Vec<u8> = cores
            .iter()
            .flat_map(|c| c.map_or(u64::MAX, |c| c as u64).to_le_bytes())
            .collect();
        cores = world
            .allgather(&mine)?
            .iter()
            .flat_map(|r| {
                r.chunks_exact(8)
                    .map(|c| u64::from_le_bytes(c.try_into().expect("8 bytes")))
                    .collect::<Vec<_>>()
            })
            .map(|c| (c != u64::MAX).then_some(c as usize))
            .collect();
    }
    Ok(Summary {
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
        streaming: cfg.fluid.streaming.name().to_string(),
        ranks: cfg.processes.ranks.max(1),
        pdf_bytes: pdf_bytes[0],
        memory_estimate_bytes: resources::estimate_memory(cfg, scene).map_or(0, |m| m.total as u64),
        tau: sim.params.tau,
        magic: sim.params.magic,
        cores,
        restarted_from: opts.restart.as_ref().map(|c| c.path.display().to_string()),
        restart_step: opts.restart.as_ref().map(|c| c.step),
        units: scene.units,
        ..Default::default()
    })
}

/// The signal that asked this run to stop (under ranks, the one any rank received).
fn interrupted(world: &World) -> Result<Option<i32>> {
    let mine = signals::interrupted();
    if world.is_single() {
        return Ok(mine);
    }
    let mut v = [mine.map_or(0, |s| s as u64)];
    world.or(&mut v)?;
    Ok((v[0] != 0).then_some(v[0] as i32))
}

/// The trace file of this rank: `path` itself on rank 0, `<stem>.rank<r>.<ext>` beside it on the others.
fn trace_path(path: &Path, world: &World) -> PathBuf {
    if world.is_root() {
        return path.to_path_buf();
    }
    let stem = path
        .file_stem()
        .map_or("trace".into(), |s| s.to_string_lossy().to_string());
    let name = match path.extension() {
        Some(e) => format!("{stem}.rank{}.{}", world.rank(), e.to_string_lossy()),
        None => format!("{stem}.rank{}", world.rank()),
    };
    path.with_file_name(name)
}

/// Builds the run, attaches its outputs, steps it to the end (or a signal, or an instability), and
/// writes what it measured.
fn run_t<T: Real>(cfg: &Config, scene: Scene, opts: &RunOptions, world: Arc<World>) -> Result<Summary> {
    let plan = plan(cfg, &scene, opts, world.is_root())?;
    let (steps, dir) = (plan.steps, &plan.dir);
    let recording = Recording {
        trace: opts.trace.is_some(),
        block_parts: false,
    };
    let mut tl = TimeLoop::<T>::on_world(cfg, &scene, recording, world.clone())?;
    if let Some(ck) = &opts.restart {
        ck.restore_into(&mut tl)?;
    }
    let start_step = tl.sim().step;
    let outputs = attach_outputs(&mut tl, cfg, &scene, &plan, opts, &world, start_step)?;
    let mut summary = summary_head(&tl, cfg, &scene, opts, steps)?;
    let mut tasks_per_step = [tl.tasks_per_step()? as u64];
    if !world.is_single() {
        world.sum(&mut tasks_per_step)?;
    }
    let outcome = match interrupted(&world)? {
        Some(_) => Ok(Flow::Stop),
        None => tl.run_to(steps),
    };
    if let Err(e @ Error::Aborted { .. }) = outcome {
        // Another rank failed: nothing can be gathered from it any more.
        return Err(e);
    }
    let interrupted = if matches!(outcome, Ok(Flow::Stop)) {
        interrupted(&world)?
    } else {
        None
    };
    let failure = outcome.err();
    tl.finish(&match (&failure, interrupted) {
        (Some(e), _) => RunEnd::Failed(e),
        (None, Some(_)) => RunEnd::Stopped,
        (None, None) => RunEnd::Done,
    })?;
    if let Some(path) = &opts.trace {
        let path = trace_path(path, &world);
        tl.pipeline()
            .write_trace(&path)
            .map_err(|e| crate::error::io_err(&path, e))?;
    }
    if world.is_root() {
        crate::io::intervals::write(&dir.join("intervals.csv"), tl.intervals())?;
        figures(dir, cfg, tl.intervals(), tl.sim().particles.is_some())?;
    }
    time_and_checkpoints(&mut summary, &tl, &world, start_step, outputs.checkpoints)?;
    summary::fill(&mut summary, &tl, &cfg.balance, tasks_per_step[0] as usize)?;
    let error = match (failure, interrupted) {
        (Some(e), _) => Some(("unstable", e)),
        (None, Some(signal)) => Some((
            "interrupted",
            Error::Interrupted {
                signal,
                step: tl.sim().step,
                checkpoint: summary.checkpoint.clone(),
            },
        )),
        (None, None) => None,
    };
    if let Some((status, e)) = error {
        summary.status = status.to_string();
        summary.error = Some(e.to_string());
        if world.is_root() {
            write_summary(dir, &summary)?;
        }
        return Err(e);
    }
    let points: &[(f64, Body)] = outputs.trajectory.map_or(&[], |h| &tl.observer(h).points);
    let gathered = if world.is_single() {
        None
    } else {
        let cells = crate::ranks::views::cells(&world, tl.sim())?;
        let bodies = crate::ranks::views::bodies(&world, tl.sim())?;
        let forces = crate::ranks::views::hydro_forces(&world, tl.sim())?;
        match cells {
            Some(cells) => Some(Gathered { cells, bodies, forces }),
            // Rank 0 computes the observables and writes the summary.
            None => return Ok(summary),
        }
    };
    summary.observables = (scene.observe)(&RunView {
        sim: tl.sim(),
        trajectory: points,
        gathered,
    });
    summary.status = "ok".to_string();
    write_summary(dir, &summary)?;
    Ok(summary)
}

/// What [`run_t`] reads back from its outputs after the run.
struct Outputs {
    /// The trajectory of body 0, for scenes that record one.
    trajectory: Option<Handle<TrajectoryRecorder>>,
    /// The checkpoints written.
    checkpoints: Handle<CheckpointWriter>,
}

/// Attaches the run's outputs to the time loop: `series.csv`, the trajectory, VTK and PNG snapshots,
/// checkpoints, the progress bar and the signal handler.
fn attach_outputs<T: Real>(
    tl: &mut TimeLoop<T>,
    cfg: &Config,
    scene: &Scene,
    plan: &Plan,
    opts: &RunOptions,
    world: &Arc<World>,
    start_step: u64,
) -> Result<Outputs> {
    let (steps, dir) = (plan.steps, &plan.dir);
    let series_every = cfg.run.series_every.unwrap_or((steps / 100).max(10));
    // Threads of this driver: every virtual process's, or one rank's.
    let threads = if cfg.processes.ranks > 1 {
        cfg.processes.threads_per_process
    } else {
        cfg.processes.count * cfg.processes.threads_per_process
    };
    tl.add_observer(SeriesWriter::new(dir, tl.sim(), world, series_every, steps, threads)?);
    let trajectory = TrajectoryRecorder::new(dir, tl.sim(), world, scene.units)?.map(|r| tl.add_observer(r));
    if let Some(every) = plan.vtk_every {
        let w = VtkWriter::new(dir, tl.sim(), world, every, cfg.run.vtk_encoding)?;
        tl.add_observer(w);
    }
    if let Some(every) = cfg.run.png_every {
        let w = SliceWriter::new(
            dir,
            tl.sim(),
            world,
            tl.pipeline().owners(),
            cfg,
            every,
            scene.name,
            scene.units,
        )?;
        tl.add_observer(w);
    }
    let checkpoints = tl.add_observer(CheckpointWriter::new(
        dir.join("checkpoints"),
        cfg,
        plan.config_text.clone(),
        scene.name,
    ));
    tl.add_observer(Progress::new(start_step, steps, opts.progress && world.is_root()));
    tl.add_observer(StopOnSignal);
    Ok(Outputs {
        trajectory,
        checkpoints,
    })
}

/// Writes the stepping time (the slowest rank's), the MLUPS and what the checkpoints cost into `summary`.
fn time_and_checkpoints<T: Real>(
    summary: &mut Summary,
    tl: &TimeLoop<T>,
    world: &World,
    start_step: u64,
    checkpoints: Handle<CheckpointWriter>,
) -> Result<()> {
    let mut loop_time = [tl.stepping_seconds()];
    if !world.is_single() {
        world.max_f64(&mut loop_time)?;
    }
    let loop_time = loop_time[0];
    let done = tl.sim().step - start_step;
    summary.wall_seconds = loop_time;
    summary.mlups = if loop_time > 0.0 {
        (tl.sim().fluid_cells() as f64 * done as f64) / loop_time / 1e6
    } else {
        0.0
    };
    let ck = tl.observer(checkpoints);
    summary.checkpoint = ck.last.as_ref().map(|(_, p)| p.display().to_string());
    if ck.count > 0 {
        summary.checkpoints_written = Some(ck.count);
        summary.checkpoint_seconds = Some(ck.seconds);
        summary.checkpoint_bytes = Some(ck.bytes);
    }
    Ok(())
}

/// The run's figures: `balance.png` on several processes, `parts.png` with particles (none for a run
/// without a closed interval).
fn figures(dir: &Path, cfg: &Config, intervals: &[IntervalStats], particulate: bool) -> Result<()> {
    if intervals.is_empty() {
        return Ok(());
    }
    if cfg.processes.count > 1 {
        plots::run::balance_figure(&dir.join("balance.png"), intervals)?;
    }
    if particulate {
        plots::run::parts_figure(&dir.join("parts.png"), intervals)?;
    }
    Ok(())
}
