//! `blockflow study SCENE --processes P [--threads-per-process T] --strategies ... [--weights W]
//! [--steps N] [--live] [--out DIR]`: one recorded run replayed under every strategy (Table 3, figures 10
//! and 11), and with `--live` every strategy run for real, modeled against measured.
//!
//! The recording run uses one process with `record_threads` threads and never moves a block. By default
//! it has as many as the estimator's coefficients were timed with (their provenance's `threads`, 1 for
//! a default `blockflow calibrate`), so that estimator and measured weights describe the same memory
//! contention; with `--live`, or without estimator weights among the strategies, the machine's cores
//! (the live runs' regime); the counterfactual strategies are assigned to `P` processes of `T` threads each,
//! whatever the machine. `none` is the paper's baseline (static Hilbert split by fluid cells), `steal-global`
//! the same assignment with any idle thread taking any ready task, and every other strategy starts from its
//! own split by `--weights` (or the `@weights` suffix of its name, e.g. `hilbert@estimator`) and rebalances
//! every `balance.interval` steps.

use crate::config::{self, Config, Precision, StealConfig, Weights};
use crate::error::{io_err, Error, Result};
use crate::metrics::cost_model::{CommModel, Machine};
use crate::metrics::interval::IntervalStats;
use crate::physics::simulation::Simulation;
use crate::scenes::{self, Scene};
use crate::study::report::{self, Row};
use crate::study::{Candidate, Counterfactual};
use crate::timeloop::setup::{coefficients, InitialAssignment};
use crate::timeloop::{Flow, Handle, Observer, Recording, RunContext, TimeLoop};
use blockflow_kernels::Real;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Strategies `blockflow study` knows, in the default table order.
pub const STRATEGIES: [&str; 6] = ["none", "hilbert", "morton", "diffusive", "metis", "steal-global"];

/// The load-balancing study (paper section 4.3).
#[derive(clap::Args, Debug)]
pub struct StudyArgs {
    /// Scene file (TOML), e.g. configs/hopper.toml.
    pub scene: PathBuf,
    /// Processes P of the strategies (any number: the run is replayed, not executed, on them).
    #[arg(long)]
    pub processes: usize,
    /// Threads per process T of the strategies.
    #[arg(long, default_value_t = 1)]
    pub threads_per_process: usize,
    /// Strategies, comma-separated: none, hilbert, morton, diffusive, metis, steal-global; a suffix
    /// @cells, @estimator, @measured, @corrected or @uniform sets the block weights of one
    /// (hilbert@estimator; none@uniform is the static split by block counts, the paper's start).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "none,none@uniform,hilbert,morton,diffusive,metis,steal-global"
    )]
    pub strategies: Vec<String>,
    /// Block weights of the rebalancing strategies: cells, estimator, measured, corrected
    /// (default: the scene's balance.weights).
    #[arg(long)]
    pub weights: Option<String>,
    /// Number of time steps (default: run.steps, else the scene's own).
    #[arg(long)]
    pub steps: Option<u64>,
    /// Steps per balancing interval (balance.interval).
    #[arg(long)]
    pub interval: Option<u64>,
    /// Override a key of the scene file (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Also run every strategy for real on P × T threads: modeled against measured.
    #[arg(long)]
    pub live: bool,
    /// Rounds of live runs: every strategy once per round, in turn, so that slow and fast phases of
    /// the machine fall on all of them; each live column is the median over the rounds.
    #[arg(long, default_value_t = 1)]
    pub live_rounds: usize,
    /// Threads of the recording run (default: the threads the estimator's coefficients were timed with,
    /// their provenance's `threads`; with --live, or without estimator weights among the strategies,
    /// the machine's cores).
    #[arg(long)]
    pub record_threads: Option<usize>,
    /// Output folder.
    #[arg(long, default_value = "out/study")]
    pub out: PathBuf,
}

/// Runs `blockflow study` and prints Table 3 (and the live rows).
pub fn execute(a: StudyArgs) -> Result<()> {
    let mut set = a.set;
    if let Some(i) = a.interval {
        set.push(format!("balance.interval={i}"));
    }
    let weights = match a.weights {
        None => None,
        Some(w) => Some(parse_weights(&w).ok_or_else(|| {
            Error::Config(format!(
                "--weights {w}: unknown; use cells, estimator, measured, corrected or uniform"
            ))
        })?),
    };
    let opts = StudyOptions {
        scene: a.scene,
        sets: set,
        processes: a.processes,
        threads_per_process: a.threads_per_process,
        strategies: a.strategies,
        weights,
        steps: a.steps,
        live: a.live,
        live_rounds: a.live_rounds.max(1),
        out: a.out.clone(),
        record_threads: a.record_threads,
    };
    let r = study(&opts)?;
    let mut text = report::markdown(&r.strategies);
    if !r.live.is_empty() {
        text += "\nLive runs, modeled against measured:\n\n";
        text += &live_markdown(&r.live);
    }
    text += &format!("results in {}\n", a.out.display());
    super::print_out(&text);
    Ok(())
}

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
    /// Rounds of live runs (medians over them).
    pub live_rounds: usize,
    /// Output folder.
    pub out: PathBuf,
    /// Threads of the recording run (`None`: those the estimator's coefficients were timed with, or
    /// the machine's cores with `live` or where no strategy weighs by the estimator).
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
    /// The study's modeled run time relative to its `none` row, percent change (Table 3's column).
    pub modeled_gain: f64,
    /// The live run's measured wall time relative to the live `none` run, percent change.
    pub measured_gain: f64,
    /// Rounds the live columns are medians over.
    pub rounds: usize,
}

/// The median of one strategy's live rounds: seconds and LI by their medians, flags true only if true
/// in every round, blocks migrated of the first round.
fn median_row(rounds: &[LiveRow]) -> LiveRow {
    let med = |f: fn(&LiveRow) -> f64| report::median(rounds.iter().map(f));
    LiveRow {
        name: rounds[0].name.clone(),
        study_modeled_seconds: rounds[0].study_modeled_seconds,
        live_modeled_seconds: med(|r| r.live_modeled_seconds),
        live_wall_seconds: med(|r| r.live_wall_seconds),
        live_imbalance_median: med(|r| r.live_imbalance_median),
        replay_reproduces_li: rounds.iter().all(|r| r.replay_reproduces_li),
        checksums_equal: rounds.iter().all(|r| r.checksums_equal),
        migrated_blocks: rounds[0].migrated_blocks,
        modeled_gain: f64::NAN,
        measured_gain: f64::NAN,
        rounds: rounds.len(),
    }
}

/// Fills the gains of every live row against the row named `none` (NaN without one): what Table 3
/// claims beside what the live runs measured, so that their difference is in the output.
fn live_gains(rows: &mut [LiveRow]) {
    let base = rows
        .iter()
        .find(|r| r.name == "none")
        .map(|r| (r.study_modeled_seconds, r.live_wall_seconds));
    for r in rows.iter_mut() {
        let (m, w) = base.unwrap_or((f64::NAN, f64::NAN));
        r.modeled_gain = 100.0 * (r.study_modeled_seconds / m - 1.0);
        r.measured_gain = 100.0 * (r.live_wall_seconds / w - 1.0);
    }
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

/// `cells`, `estimator`, `measured`, `corrected` or `uniform`.
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
    let max = config::MAX_PROCESS_COUNT;
    for (flag, v) in [
        ("--processes", opts.processes),
        ("--threads-per-process", opts.threads_per_process),
    ] {
        if v == 0 || v > max {
            return Err(Error::Config(format!("{flag} {v}: must be between 1 and {max}")));
        }
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
                "--strategies: unknown strategy {s:?}; known: {} (optionally with @cells, @estimator, @measured, \
                 @corrected or @uniform for the block weights)",
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
    if c.balance.strategy == config::Strategy::None && weights.is_none() {
        // The baseline: the static Hilbert split by fluid cells (`none@uniform`: by block counts, the
        // paper's uniform start).
        c.balance.weights = Weights::Cells;
    }
    if name.starts_with("steal-global") {
        c.processes.steal = StealConfig::Global;
    }
    c
}

/// The worker threads the estimator's coefficients were timed with (provenance `threads`), where a
/// strategy of `names` weighs blocks by the estimator (`estimator` or `corrected`); `None` otherwise.
/// Per-block costs depend on the memory contention they were timed in, so the recording that the
/// estimator's weights are judged against is made in the same regime.
fn calibration_threads(cfg: &Config, names: &[String]) -> Result<Option<usize>> {
    for name in names {
        if let Some(c) = coefficients(&strategy_config(cfg, name, 1, 1))? {
            return Ok(Some(c.provenance.threads));
        }
    }
    Ok(None)
}

/// The counterfactuals of `names` on `processes × threads`, each starting from its own initial split.
fn counterfactual<T: Real>(
    cfg: &Config,
    sim: &Simulation<T>,
    names: &[String],
    processes: usize,
    threads: usize,
) -> Result<Counterfactual> {
    let mut candidates = Vec::new();
    for name in names {
        let c = strategy_config(cfg, name, processes, threads);
        let coeffs = coefficients(&c)?;
        let init = InitialAssignment::of(&c, sim, coeffs.as_ref());
        let machine = Machine {
            processes,
            threads,
            global: name.starts_with("steal-global"),
            comm: CommModel::of(&cfg.balance),
        };
        let balancer = crate::balance::Balancer::of(&c.balance, c.processes.count, coeffs, &sim.domain);
        candidates.push(Candidate::new(name, balancer, init.owners, &init.weights, machine));
    }
    Ok(Counterfactual::new(candidates, cfg))
}

/// Prints `label: step N/END (S s)` to stderr every tenth of the run.
struct StudyProgress {
    label: String,
    every: u64,
    end: u64,
    t0: Instant,
}

impl StudyProgress {
    fn new(label: String, end: u64) -> Self {
        StudyProgress {
            label,
            every: (end / 10).max(1),
            end,
            t0: Instant::now(),
        }
    }
}

impl<T: Real> Observer<T> for StudyProgress {
    fn next_stop(&self, step: u64) -> Option<u64> {
        Some(((step / self.every + 1) * self.every).min(self.end))
    }

    fn at_stop(&mut self, cx: &RunContext<'_, T>) -> Result<Flow> {
        let s = cx.sim.step;
        if s.is_multiple_of(self.every) || s == self.end {
            eprintln!(
                "  {}: step {s}/{} ({:.0} s)",
                self.label,
                self.end,
                self.t0.elapsed().as_secs_f64()
            );
        }
        Ok(Flow::Continue)
    }
}

/// Runs `tl` to `steps` with progress on stderr and the counterfactual attached; returns the wall
/// seconds and the counterfactual.
fn record<T: Real>(
    tl: &mut TimeLoop<T>,
    cf: Counterfactual,
    steps: u64,
    label: &str,
) -> Result<(f64, Handle<Counterfactual>)> {
    let t0 = Instant::now();
    let h = tl.add_observer(cf);
    tl.add_observer(StudyProgress::new(label.to_string(), steps));
    let end = tl.run_to(steps).map(|_| crate::timeloop::RunEnd::Done);
    match end {
        Ok(e) => tl.finish(&e)?,
        Err(e) => {
            tl.finish(&crate::timeloop::RunEnd::Failed(&e))?;
            return Err(e);
        }
    }
    Ok((t0.elapsed().as_secs_f64(), h))
}

fn checksums<T: Real>(sim: &Simulation<T>) -> (String, Option<String>) {
    (
        format!("{:016x}", sim.checksum()),
        sim.particles.as_ref().map(|p| format!("{:016x}", p.checksum(sim.step))),
    )
}

fn study_t<T: Real>(cfg: &Config, scene: &Scene, opts: &StudyOptions) -> Result<StudyReport> {
    let steps = opts.steps.or(cfg.run.steps).unwrap_or(scene.steps);
    if steps == 0 {
        // Nothing recorded leaves nothing to replay (the figures had no data to plot).
        return Err(Error::Config(
            "study: --steps 0 (or run.steps = 0): record at least one step".into(),
        ));
    }
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let record_threads = match opts.record_threads {
        Some(t) => t.max(1),
        // Live runs use every core: the modeled times they are compared with come from the same regime.
        None if opts.live => cores,
        None => calibration_threads(cfg, &opts.strategies)?.map_or(cores, |t| t.min(cores)),
    };
    let mut rec = strategy_config(cfg, "none", 1, record_threads);
    rec.processes.pin = config::PinConfig::default();
    let mut tl = TimeLoop::<T>::from_config(&rec, scene, Recording::default())?;
    let cf = counterfactual(
        cfg,
        tl.sim(),
        &opts.strategies,
        opts.processes,
        opts.threads_per_process,
    )?;
    eprintln!(
        "study: recording {steps} steps of {} on {record_threads} thread{}, replayed on {} × {}",
        opts.scene.display(),
        if record_threads == 1 { "" } else { "s" },
        opts.processes,
        opts.threads_per_process
    );
    let (wall, h) = record(&mut tl, cf, steps, "recording")?;
    let rows = report::rows(&tl.observer(h).candidates);
    let sums = checksums(tl.sim());
    let mut live = Vec::new();
    if opts.live {
        let mut rounds: Vec<Vec<LiveRow>> = vec![Vec::new(); rows.len()];
        for _ in 0..opts.live_rounds {
            for (i, r) in rows.iter().enumerate() {
                rounds[i].push(live_run::<T>(cfg, scene, opts, steps, r, &sums)?);
            }
        }
        live = rounds.into_iter().map(|v| median_row(&v)).collect();
        live_gains(&mut live);
    }
    let report = StudyReport {
        scene: opts.scene.display().to_string(),
        processes: opts.processes,
        threads_per_process: opts.threads_per_process,
        steps,
        interval: cfg.balance.interval,
        weights: format!("{:?}", cfg.balance.weights).to_lowercase(),
        latency: cfg.balance.latency,
        bandwidth: cfg.balance.bandwidth,
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
    let mut tl = TimeLoop::<T>::from_config(&c, scene, Recording::default())?;
    let cf = counterfactual(
        cfg,
        tl.sim(),
        std::slice::from_ref(&row.name),
        opts.processes,
        opts.threads_per_process,
    )?;
    let (_, h) = record(&mut tl, cf, steps, &format!("live {}", row.name))?;
    let replayed: Vec<u64> = tl.observer(h).candidates[0]
        .intervals()
        .iter()
        .map(|i| i.imbalance.to_bits())
        .collect();
    let iv = tl.intervals();
    let measured: Vec<u64> = iv.iter().map(|i| i.imbalance.to_bits()).collect();
    let bal: f64 = iv.iter().map(|i| i.balance_seconds).sum();
    Ok(LiveRow {
        name: row.name.clone(),
        study_modeled_seconds: row.graph_seconds,
        live_modeled_seconds: iv.iter().map(|i| i.modeled_seconds).sum::<f64>() + bal,
        live_wall_seconds: iv.iter().map(|i| i.wall_seconds).sum::<f64>() + bal,
        live_imbalance_median: report::median(iv.iter().map(|i| i.imbalance)),
        replay_reproduces_li: replayed == measured,
        checksums_equal: checksums(tl.sim()) == *sums,
        migrated_blocks: iv.iter().map(|i| i.migrated_blocks).sum(),
        modeled_gain: f64::NAN,
        measured_gain: f64::NAN,
        rounds: 1,
    })
}

/// Markdown of the live rows.
pub fn live_markdown(rows: &[LiveRow]) -> String {
    let mut s = String::from(
        "| strategy | study modeled (s) | live modeled (s) | live measured (s) | modeled gain | measured gain | difference \
         | live median LI | replay = live LI | checksums equal | blocks migrated |\n\
         |---|---:|---:|---:|---:|---:|---:|---:|---|---|---:|\n",
    );
    for r in rows {
        s += &format!(
            "| {} | {:.3} | {:.3} | {:.3} | {:+.1} % | {:+.1} % | {:+.1} pt | {:.1} % | {} | {} | {} |\n",
            r.name,
            r.study_modeled_seconds,
            r.live_modeled_seconds,
            r.live_wall_seconds,
            r.modeled_gain,
            r.measured_gain,
            r.measured_gain - r.modeled_gain,
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
         migrated_blocks,migrated_bytes,partition_seconds,recompile_seconds,migration_seconds\n",
    );
    for s in &r.strategies {
        for (i, x) in s.intervals.iter().enumerate() {
            iv += &format!(
                "{},{i},{},{},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{},{},{:.6e},{:.6e},{:.6e}\n",
                s.name,
                x.start,
                x.end,
                x.modeled_seconds,
                x.bsp_seconds,
                x.imbalance,
                x.predicted_imbalance,
                x.edge_cut_mean,
                x.migrated_blocks,
                x.migrated_bytes,
                x.partition_seconds,
                x.recompile_seconds,
                x.migration_seconds
            );
        }
    }
    put("study_intervals.csv", iv)?;
    let lines = |f: fn(&IntervalStats) -> f64| -> Vec<(String, Vec<(f64, f64)>)> {
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
    crate::io::plots::balance::figure10(
        &dir.join("figure10.png"),
        &lines(|i| i.modeled_seconds + i.balance_seconds),
    )?;
    crate::io::plots::balance::figure11(&dir.join("figure11.png"), &lines(|i| i.imbalance))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The recording follows the estimator's calibration regime only where a strategy weighs by the
    /// estimator.
    #[test]
    fn recording_threads_follow_the_coefficients_of_estimator_strategies() {
        let dir = std::env::temp_dir().join(format!("blockflow-study-threads-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("coefficients.toml");
        let text = crate::estimator::coefficients::BUILT_IN_COEFFICIENTS.replacen("threads = 1\n", "threads = 3\n", 1);
        assert_ne!(
            text,
            crate::estimator::coefficients::BUILT_IN_COEFFICIENTS,
            "the built-in file names its threads"
        );
        std::fs::write(&path, text).unwrap();
        let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/hopper-small.toml");
        let cfg = config::load(
            &scene,
            &[format!("balance.coefficients={:?}", path.display().to_string())],
        )
        .unwrap();
        let names = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        assert_eq!(
            calibration_threads(&cfg, &names(&["none", "hilbert@estimator"])).unwrap(),
            Some(3)
        );
        // `corrected` (the default weights) scales the estimator's predictions.
        assert_eq!(calibration_threads(&cfg, &names(&["metis"])).unwrap(), Some(3));
        assert_eq!(
            calibration_threads(&cfg, &names(&["none", "hilbert@measured", "steal-global"])).unwrap(),
            None
        );
        std::fs::remove_dir_all(&dir).ok();
    }
}
