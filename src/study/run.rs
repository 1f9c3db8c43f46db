//! `blockflow study SCENE --processes P [--threads-per-process T] --strategies ... [--weights W]
//! [--steps N] [--live] [--out DIR]`: one recorded run replayed under every strategy (Table 3, figures 10
//! and 11), and with `--live` every strategy run for real, modeled against measured.
//!
//! The recording run uses one process with `record_threads` threads (by default the machine's cores) and
//! never moves a block; the counterfactual strategies are assigned to `P` processes of `T` threads each,
//! whatever the machine. `none` is the paper's baseline (static Hilbert split by fluid cells), `steal-global`
//! the same assignment with any idle thread taking any ready task, and every other strategy starts from its
//! own split by `--weights` (or the `@weights` suffix of its name, e.g. `hilbert@estimator`) and rebalances
//! every `balance.interval` steps.

use super::report::{self, Row};
use super::{Counterfactual, Strategy};
use crate::config::{self, Config, Precision, StealConfig, Weights};
use crate::error::{io_err, Error, Result};
use crate::pipeline::Pipeline;
use crate::runner;
use crate::scenes::{self, Scene};
use crate::sim::Simulation;
use blockflow_kernels::Real;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Strategies `blockflow study` knows, in the default table order.
pub const STRATEGIES: [&str; 6] = ["none", "hilbert", "morton", "diffusive", "metis", "steal-global"];

/// Options of `blockflow study`.
#[derive(Clone, Debug)]
pub struct StudyOptions {
    /// Scene file.
    pub scene: PathBuf,
    /// `--set KEY=VALUE` overrides.
    pub sets: Vec<String>,
    /// Processes of the strategies.
    pub processes: usize,
    /// Threads per process of the strategies.
    pub threads_per_process: usize,
    /// Strategy names (see [`STRATEGIES`]).
    pub strategies: Vec<String>,
    /// Block weights of the rebalancing strategies (default: the scene's `balance.weights`).
    pub weights: Option<Weights>,
    /// Steps (default: the scene's).
    pub steps: Option<u64>,
    /// Also run every strategy for real.
    pub live: bool,
    /// Output folder.
    pub out: PathBuf,
    /// Threads of the recording run (default: the machine's cores).
    pub record_threads: Option<usize>,
}

/// One strategy run for real (`--live`).
#[derive(Clone, Debug, Serialize)]
pub struct LiveRow {
    /// Strategy.
    pub name: String,
    /// The study's modeled seconds (`graph`, balancing included) from the recording.
    pub study_modeled_seconds: f64,
    /// The live run's modeled seconds from its own task durations.
    pub live_modeled_seconds: f64,
    /// The live run's measured wall seconds (graph runs and balancing steps).
    pub live_wall_seconds: f64,
    /// Median measured load imbalance of the live run.
    pub live_imbalance_median: f64,
    /// Whether replaying the live strategy on the live run's durations gave its LI series exactly.
    pub replay_reproduces_li: bool,
    /// Whether both checksums equal the recording run's.
    pub checksums_equal: bool,
    /// Blocks the live run moved.
    pub migrated_blocks: u64,
}

/// What `study.json` holds.
#[derive(Clone, Debug, Serialize)]
pub struct StudyReport {
    /// Scene file.
    pub scene: String,
    /// Processes and threads per process of the strategies.
    pub processes: usize,
    /// Threads per process.
    pub threads_per_process: usize,
    /// Steps run.
    pub steps: u64,
    /// Balancing interval.
    pub interval: u64,
    /// Block weights.
    pub weights: String,
    /// Message latency α (s) and bandwidth β (B/s) of the models.
    pub latency: f64,
    /// β.
    pub bandwidth: f64,
    /// Wall seconds of the recording run.
    pub recording_wall_seconds: f64,
    /// Threads of the recording run.
    pub recording_threads: usize,
    /// Checksums of the recording run (fluid, particles).
    pub checksums: (String, Option<String>),
    /// Table 3, one row per strategy.
    pub strategies: Vec<Row>,
    /// Live runs (empty without `--live`).
    pub live: Vec<LiveRow>,
}

/// Strategy and optional block weights of a name `strategy[@weights]` (e.g. `hilbert@estimator`).
fn parse_name(name: &str) -> Option<(config::Strategy, Option<Weights>)> {
    let (base, weights) = match name.split_once('@') {
        Some((b, w)) => (b, Some(parse_weights(w)?)),
        None => (name, None),
    };
    Some((parse_strategy(base)?, weights))
}

/// `cells`, `estimator`, `measured` or `corrected`.
pub fn parse_weights(w: &str) -> Option<Weights> {
    serde_json::from_value(serde_json::Value::String(w.to_string())).ok()
}

fn parse_strategy(name: &str) -> Option<config::Strategy> {
    Some(match name {
        "none" | "steal-global" => config::Strategy::None,
        "hilbert" => config::Strategy::Hilbert,
        "morton" => config::Strategy::Morton,
        "diffusive" => config::Strategy::Diffusive,
        "metis" => config::Strategy::Metis,
        _ => return None,
    })
}

/// Runs the study and writes `table3.md`, `table3.csv`, `study.json`, `study_intervals.csv`,
/// `figure10.png` and `figure11.png` into `opts.out`.
pub fn study(opts: &StudyOptions) -> Result<StudyReport> {
    if opts.processes == 0 || opts.threads_per_process == 0 {
        return Err(Error::Config(
            "--processes and --threads-per-process must be at least 1".to_string(),
        ));
    }
    if opts.strategies.is_empty() {
        return Err(Error::Config(format!(
            "--strategies: name at least one of {}",
            STRATEGIES.join(", ")
        )));
    }
    for s in &opts.strategies {
        if parse_name(s).is_none() {
            return Err(Error::Config(format!(
                "--strategies: unknown strategy {s:?}; known: {} (optionally with @cells, @estimator, @measured \
                 or @corrected for the block weights)",
                STRATEGIES.join(", ")
            )));
        }
    }
    let mut cfg = config::load(&opts.scene, &opts.sets)?;
    if let Some(w) = opts.weights {
        cfg.balance.weights = w;
    }
    let scene = scenes::build(&cfg)?;
    std::fs::create_dir_all(&opts.out).map_err(|e| io_err(&opts.out, e))?;
    match cfg.fluid.precision {
        Precision::F64 => study_t::<f64>(&cfg, &scene, opts),
        Precision::F32 => study_t::<f32>(&cfg, &scene, opts),
    }
}

/// The configuration of strategy `name` on `P × T`.
fn strategy_config(cfg: &Config, name: &str, processes: usize, threads: usize) -> Config {
    let mut c = cfg.clone();
    c.processes.count = processes;
    c.processes.threads_per_process = threads;
    let (strategy, weights) = parse_name(name).expect("checked");
    c.balance.strategy = strategy;
    if let Some(w) = weights {
        c.balance.weights = w;
    }
    if c.balance.strategy == config::Strategy::None {
        // The paper's baseline: the static Hilbert split by fluid cells.
        c.balance.weights = Weights::Cells;
    }
    if name.starts_with("steal-global") {
        c.processes.steal = StealConfig::Global;
    }
    c
}

/// The counterfactuals of `names` on `processes × threads`, each starting from its own initial split.
fn counterfactual<T: Real>(
    cfg: &Config,
    sim: &Simulation<T>,
    names: &[String],
    processes: usize,
    threads: usize,
) -> Result<Counterfactual> {
    let mut strategies = Vec::new();
    for name in names {
        let c = strategy_config(cfg, name, processes, threads);
        let owners = runner::assignment_weighted(&c, sim)?;
        let weights = runner::block_weights(&c, sim)?;
        let balancer = runner::make_balancer(&c, sim)?;
        strategies.push(Strategy::new(
            name,
            balancer,
            name.starts_with("steal-global"),
            owners,
            &weights,
            processes,
        ));
    }
    Ok(Counterfactual {
        strategies,
        processes,
        threads,
        comm: super::model::CommModel {
            latency: cfg.balance.latency,
            bandwidth: cfg.balance.bandwidth,
        },
    })
}

/// Runs `pipe` over `steps` steps, printing progress every tenth to stderr; closes the last interval.
fn advance<T: Real>(pipe: &mut Pipeline<T>, sim: &mut Simulation<T>, steps: u64, label: &str) -> Result<f64> {
    let t0 = Instant::now();
    let chunk = (steps / 10).max(1);
    let mut done = 0;
    while done < steps {
        let k = chunk.min(steps - done);
        pipe.advance(sim, k)?;
        done += k;
        eprintln!("  {label}: step {done}/{steps} ({:.0} s)", t0.elapsed().as_secs_f64());
    }
    pipe.close_interval(sim);
    Ok(t0.elapsed().as_secs_f64())
}

fn checksums<T: Real>(sim: &Simulation<T>) -> (String, Option<String>) {
    (
        format!("{:016x}", sim.checksum()),
        sim.particles.as_ref().map(|p| format!("{:016x}", p.checksum(sim.step))),
    )
}

fn study_t<T: Real>(cfg: &Config, scene: &Scene, opts: &StudyOptions) -> Result<StudyReport> {
    let steps = opts.steps.or(cfg.run.steps).unwrap_or(scene.steps);
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let record_threads = opts.record_threads.unwrap_or(cores).max(1);
    let mut rec = strategy_config(cfg, "none", 1, record_threads);
    rec.processes.pin = config::PinConfig::default();
    let mut sim = runner::build_sim::<T>(&rec, scene)?;
    let mut pipe = runner::make_pipeline(&rec, &sim)?;
    pipe.study = Some(counterfactual(
        cfg,
        &sim,
        &opts.strategies,
        opts.processes,
        opts.threads_per_process,
    )?);
    eprintln!(
        "study: recording {steps} steps of {} on {record_threads} threads, replayed on {} × {}",
        opts.scene.display(),
        opts.processes,
        opts.threads_per_process
    );
    let wall = advance(&mut pipe, &mut sim, steps, "recording")?;
    let cf = pipe.study.take().expect("set above");
    let rows = report::rows(&cf.strategies);
    let sums = checksums(&sim);
    let mut live = Vec::new();
    if opts.live {
        for r in &rows {
            live.push(live_run::<T>(cfg, scene, opts, steps, r, &sums)?);
        }
    }
    let report = StudyReport {
        scene: opts.scene.display().to_string(),
        processes: opts.processes,
        threads_per_process: opts.threads_per_process,
        steps,
        interval: cfg.balance.interval,
        weights: format!("{:?}", cfg.balance.weights).to_lowercase(),
        latency: cf.comm.latency,
        bandwidth: cf.comm.bandwidth,
        recording_wall_seconds: wall,
        recording_threads: record_threads,
        checksums: sums,
        strategies: rows,
        live,
    };
    write(&opts.out, &report)?;
    Ok(report)
}

/// Runs strategy `row.name` for real on `P × T` threads, with a counterfactual of itself attached.
fn live_run<T: Real>(
    cfg: &Config,
    scene: &Scene,
    opts: &StudyOptions,
    steps: u64,
    row: &Row,
    sums: &(String, Option<String>),
) -> Result<LiveRow> {
    let c = strategy_config(cfg, &row.name, opts.processes, opts.threads_per_process);
    let mut sim = runner::build_sim::<T>(&c, scene)?;
    let mut pipe = runner::make_pipeline(&c, &sim)?;
    pipe.study = Some(counterfactual(
        cfg,
        &sim,
        std::slice::from_ref(&row.name),
        opts.processes,
        opts.threads_per_process,
    )?);
    advance(&mut pipe, &mut sim, steps, &format!("live {}", row.name))?;
    let cf = pipe.study.take().expect("set above");
    let replayed: Vec<u64> = cf.strategies[0]
        .intervals
        .iter()
        .map(|i| i.imbalance.to_bits())
        .collect();
    let measured: Vec<u64> = pipe.intervals.iter().map(|i| i.imbalance.to_bits()).collect();
    let bal: f64 = pipe.intervals.iter().map(|i| i.balance_seconds).sum();
    Ok(LiveRow {
        name: row.name.clone(),
        study_modeled_seconds: row.graph_seconds,
        live_modeled_seconds: pipe.intervals.iter().map(|i| i.modeled_seconds).sum::<f64>() + bal,
        live_wall_seconds: pipe.intervals.iter().map(|i| i.wall_seconds).sum::<f64>() + bal,
        live_imbalance_median: report::median(pipe.intervals.iter().map(|i| i.imbalance)),
        replay_reproduces_li: replayed == measured,
        checksums_equal: checksums(&sim) == *sums,
        migrated_blocks: pipe.intervals.iter().map(|i| i.migrated_blocks).sum(),
    })
}

/// Markdown of the live rows.
pub fn live_markdown(rows: &[LiveRow]) -> String {
    let mut s = String::from(
        "| strategy | study modeled (s) | live modeled (s) | live measured (s) | live median LI | replay = live LI \
         | checksums equal | blocks migrated |\n|---|---:|---:|---:|---:|---|---|---:|\n",
    );
    for r in rows {
        s += &format!(
            "| {} | {:.3} | {:.3} | {:.3} | {:.1} % | {} | {} | {} |\n",
            r.name,
            r.study_modeled_seconds,
            r.live_modeled_seconds,
            r.live_wall_seconds,
            100.0 * r.live_imbalance_median,
            r.replay_reproduces_li,
            r.checksums_equal,
            r.migrated_blocks
        );
    }
    s
}

fn write(dir: &Path, r: &StudyReport) -> Result<()> {
    let put = |name: &str, text: String| {
        let p = dir.join(name);
        std::fs::write(&p, text).map_err(|e| io_err(&p, e))
    };
    let mut md = format!(
        "Table 3: {} on {} processes × {} threads, {} steps, interval {}, weights {} (unless a name carries \
         @weights; `none` and `steal-global`: cells); modeled from one recording (α = {:.1} µs, β = {:.1} GB/s).\n\n",
        r.scene,
        r.processes,
        r.threads_per_process,
        r.steps,
        r.interval,
        r.weights,
        r.latency * 1e6,
        r.bandwidth / 1e9
    );
    md += &report::markdown(&r.strategies);
    if !r.live.is_empty() {
        md += "\nLive runs, modeled against measured:\n\n";
        md += &live_markdown(&r.live);
    }
    put("table3.md", md)?;
    put("table3.csv", report::csv(&r.strategies))?;
    let json = serde_json::to_string_pretty(r).map_err(|e| Error::Io(format!("study.json: {e}")))?;
    put("study.json", json)?;
    let mut iv = String::from(
        "strategy,interval,start,end,graph_seconds,bsp_seconds,imbalance,predicted_imbalance,edge_cut_mean,\
         migrated_blocks,migrated_bytes,partition_seconds,migration_seconds\n",
    );
    for s in &r.strategies {
        for (i, x) in s.intervals.iter().enumerate() {
            iv += &format!(
                "{},{i},{},{},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{},{},{:.6e},{:.6e}\n",
                s.name,
                x.start,
                x.end,
                x.graph_seconds,
                x.bsp_seconds,
                x.imbalance,
                x.predicted_imbalance,
                x.edge_cut_mean,
                x.migrated_blocks,
                x.migrated_bytes,
                x.partition_seconds,
                x.migration_seconds
            );
        }
    }
    put("study_intervals.csv", iv)?;
    let lines = |f: fn(&super::StrategyInterval) -> f64| -> Vec<(String, Vec<(f64, f64)>)> {
        r.strategies
            .iter()
            .map(|s| {
                (
                    s.name.clone(),
                    s.intervals.iter().map(|i| (i.end as f64, f(i))).collect(),
                )
            })
            .collect()
    };
    crate::io::plots_balance::figure10(
        &dir.join("figure10.png"),
        &lines(|i| i.graph_seconds + i.balance_seconds()),
    )?;
    crate::io::plots_balance::figure11(&dir.join("figure11.png"), &lines(|i| i.imbalance))?;
    Ok(())
}
