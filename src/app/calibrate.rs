//! `blockflow calibrate`: the workload-estimator calibration of section 3.3. Runs the calibration scene
//! for every block size and diameter, drops the first 50 steps, records one sample per block per step
//! (the Table 1 quantities, the tasks' work counters and the measured part times m_X from the task
//! records' thread CPU time), fits both forms of the workload functions ([`Model`]) by weighted least
//! squares on the same samples summed per block over balancing intervals (`--interval`: the loads the
//! balancer's weights stand for), and reports for each the statistics of section 3.4 per step and per
//! balancing interval, in-sample and held out (fit without one run, test on it), and the timing noise
//! floor. The chosen model's coefficients go to `coefficients.toml`.
//!
//! Blocks that never hold fluid in a run are left out of the fit and of every statistic: their m_tot
//! is a few task-clock reads (or 0), so a relative error says nothing of them, and a balancer gives
//! them whatever the rigid-body terms predict.
//!
//! Every run uses one virtual process with one step per graph, so each task's CPU time belongs to
//! exactly one block and step; its workers (`--threads`, default one) are pinned to cores of their own.

use crate::config::{self, Config};
use crate::error::{io_err, Error, Result};
use crate::estimator::{
    self, BlockKind, Coefficients, Evaluation, Model, PartTimes, Provenance, Quantities, Sample, Scores,
};
use crate::io::plots;
use crate::scenes;
use crate::timeloop::{Observer, Recording, RunContext, RunEnd, TimeLoop};
use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;
use std::collections::BTreeMap;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Calibrate the workload estimator (paper section 3.3).
#[derive(clap::Args, Debug)]
pub struct CalibrateArgs {
    /// Calibration scene (default configs/calibration.toml).
    #[arg(default_value = "configs/calibration.toml")]
    pub scene: PathBuf,
    /// Block edge lengths in cells, comma-separated; with --diameters, every combination is run
    /// (default: b_s = 16 with D = 6 and 10, b_s = 32 with D = 10 and 15; --quick 12 with D = 4, 6;
    /// --paper 24,32,48,64 with D = 10, 20).
    #[arg(long, value_delimiter = ',')]
    pub block_sizes: Vec<usize>,
    /// Sphere diameters in cells, comma-separated (see --block-sizes).
    #[arg(long, value_delimiter = ',')]
    pub diameters: Vec<f64>,
    /// A short campaign (under a minute), for tests.
    #[arg(long)]
    pub quick: bool,
    /// The form of the workload functions written to coefficients.toml: blockflow (this engine's
    /// regressors) or paper (eqs. 10-14). Both are fitted and reported.
    #[arg(long, default_value = "blockflow")]
    pub model: String,
    /// Steps of a balancing interval for the per-interval statistics.
    #[arg(long, default_value_t = 100)]
    pub interval: u64,
    /// Fit and score the samples of an earlier campaign (its samples.csv) instead of running one.
    #[arg(long, value_name = "SAMPLES_CSV")]
    pub samples: Option<PathBuf>,
    /// The paper's sizes (block sizes 24, 32, 48, 64; D = 10, 20; 2.5 T), for big machines.
    #[arg(long, conflicts_with = "quick")]
    pub paper: bool,
    /// Further scenes recorded as they are (their own blocks, walls and spheres) for `--with-steps`
    /// steps each (repeatable). Without it, the default campaign adds configs/hopper.toml,
    /// configs/hopper-paper32.toml and configs/hopper-small.toml: blocks that walls cut, which the
    /// calibration scene does not have, at three block sizes (so that leaving one run out still leaves
    /// wall-cut blocks in the fit).
    #[arg(long = "with", value_name = "SCENE")]
    pub with: Vec<PathBuf>,
    /// Steps of each `--with` scene (the first 50 are dropped as in every run).
    #[arg(long, default_value_t = 400)]
    pub with_steps: u64,
    /// Record only the calibration scene: no `--with` scenes, not even the default campaign's.
    #[arg(long, conflicts_with = "with")]
    pub calibration_only: bool,
    /// Worker threads of every recording run, each pinned to a core of its own. 1 (the default) times
    /// each block alone on its core; the machine's core count times it in the memory contention of a
    /// run that uses every core. The coefficients are valid for runs in the regime they were timed in
    /// (`threads` in their provenance; `blockflow study` records in it).
    #[arg(long, default_value_t = 1)]
    pub threads: usize,
    /// Output folder.
    #[arg(long, default_value = "out/calibration")]
    pub out: PathBuf,
}

/// The scenes the default campaign records beside the calibration scene (`--with-steps` steps each):
/// the hoppers at both block sizes, whose funnel walls cut blocks into short fluid runs.
pub const DEFAULT_WITH: [&str; 3] = [
    "configs/hopper.toml",
    "configs/hopper-paper32.toml",
    "configs/hopper-small.toml",
];

/// Runs `blockflow calibrate` and prints the coefficient table and error statistics.
pub fn execute(a: CalibrateArgs) -> Result<()> {
    if a.block_sizes.contains(&0) || a.diameters.iter().any(|d| !(d.is_finite() && *d > 0.0)) {
        return Err(Error::Config(
            "calibrate: --block-sizes and --diameters must be positive".into(),
        ));
    }
    let model = Model::parse(&a.model).ok_or_else(|| {
        Error::Config(format!(
            "calibrate: --model {}: unknown; use blockflow or paper",
            a.model
        ))
    })?;
    if a.interval == 0 {
        return Err(Error::Config("calibrate: --interval must be at least 1 step".into()));
    }
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    if a.threads == 0 || a.threads > cores {
        return Err(Error::Config(format!(
            "calibrate: --threads {}: must be between 1 and this machine's {cores} cores (each worker is pinned to a core of its own)",
            a.threads
        )));
    }
    let preset = !a.quick && !a.paper && a.samples.is_none() && a.block_sizes.is_empty() && a.diameters.is_empty();
    let with = if a.with.is_empty() && preset && !a.calibration_only {
        if let Some(missing) = DEFAULT_WITH.iter().find(|p| !Path::new(p).exists()) {
            return Err(Error::Config(format!(
                "calibrate: the default campaign records {missing}, which is not in this folder; run from the repository root, name scenes with --with, or pass --calibration-only"
            )));
        }
        DEFAULT_WITH.iter().map(PathBuf::from).collect()
    } else {
        a.with
    };
    let opts = CalibrateOptions {
        scene: a.scene,
        block_sizes: a.block_sizes,
        diameters: a.diameters,
        quick: a.quick,
        paper: a.paper,
        model,
        interval: a.interval,
        samples: a.samples,
        with,
        with_steps: a.with_steps,
        threads: a.threads,
        out: a.out.clone(),
    };
    let report = run(&opts)?;
    let coeffs = Coefficients::load(&a.out.join("coefficients.toml"))?;
    super::print_out(&to_markdown(&report, &coeffs));
    super::print_out(&format!("results in {}\n", a.out.display()));
    Ok(())
}

/// Options of `blockflow calibrate`.
#[derive(Clone, Debug)]
pub struct CalibrateOptions {
    /// The calibration scene file.
    pub scene: PathBuf,
    /// Block edge lengths b_s (cells); empty: the preset's.
    pub block_sizes: Vec<usize>,
    /// Sphere diameters D (cells); empty: the preset's.
    pub diameters: Vec<f64>,
    /// A short campaign for tests (seconds).
    pub quick: bool,
    /// The paper's sizes (b_s = 24, 32, 48, 64; D = 10, 20; 2.5 T): for big machines.
    pub paper: bool,
    /// The model whose coefficients are written.
    pub model: Model,
    /// Steps of a balancing interval (per-interval statistics).
    pub interval: u64,
    /// A recorded samples.csv to refit instead of running the campaign.
    pub samples: Option<PathBuf>,
    /// Further scenes recorded as they are, `with_steps` steps each.
    pub with: Vec<PathBuf>,
    /// Steps of each scene of `with`.
    pub with_steps: u64,
    /// Worker threads of every recording run, each pinned to a core of its own.
    pub threads: usize,
    /// Output folder.
    pub out: PathBuf,
}

/// Steps dropped at the start of every run (the paper's warm-up).
pub const WARMUP: u64 = 50;

/// The samples of one calibration run: after every step past the warm-up, every block's Table 1
/// quantities and measured part times (one step per graph run, so each task's CPU time belongs to one
/// block and step).
struct Sampler {
    run: usize,
    block_size: usize,
    diameter: f64,
    t_unit: f64,
    bar: ProgressBar,
    samples: Vec<Sample>,
    /// Figure 6's series (fluid cells and LBM time per block over time), recorded for the first run.
    fig6: Option<Vec<plots::BlockSeries>>,
    csv: String,
}

impl Observer<f64> for Sampler {
    fn after_run(&mut self, cx: &RunContext<'_, f64>) -> crate::error::Result<()> {
        self.bar.inc(1);
        let sim = cx.sim;
        if sim.step <= WARMUP {
            return Ok(());
        }
        let times = cx
            .run
            .and_then(|r| r.block_part_ns)
            .expect("calibration records part times");
        for (b, t) in times.iter().enumerate().take(sim.blocks.len()) {
            let q = Quantities::of(sim, b);
            let m = PartTimes::from_part_ns(t);
            let row = sim.domain.coords(b)[2];
            let t_star = sim.step as f64 / self.t_unit;
            let (r, bs, d) = (self.run, self.block_size, self.diameter);
            let counts = [
                q.c,
                q.f,
                q.nb,
                q.pl,
                q.ps,
                q.k,
                q.s,
                q.runs,
                q.breaks,
                q.wall_links,
                q.particle_links,
                q.link_cells,
                q.map_active,
                q.map_bodies,
                q.box_cells,
                q.rows_derived,
                q.turned,
                q.covered,
                q.rb_active,
                q.contacts_seen,
                q.scanned,
                q.wall_lines,
                q.tail_runs,
                q.shifted_runs,
                q.row_pitch,
            ];
            let counts: Vec<String> = counts.iter().map(|x| x.to_string()).collect();
            self.csv += &format!(
                "{r},{bs},{d},{},{t_star:.6},{b},{row},{},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e}\n",
                sim.step,
                counts.join(","),
                m.lbm,
                m.bh,
                m.coup1,
                m.coup2,
                m.rb
            );
            if let Some(series) = self.fig6.as_mut().and_then(|f| f.get_mut(b)) {
                series.points.push((t_star, q.f, m.lbm));
            }
            self.samples.push(Sample {
                run: self.run,
                step: sim.step,
                block: b,
                q,
                m,
            });
        }
        Ok(())
    }
}

/// One run of the campaign.
#[derive(Clone, Debug, Serialize)]
pub struct RunInfo {
    /// Block edge b_s.
    pub block_size: usize,
    /// Diameter D.
    pub diameter: f64,
    /// Steps run.
    pub steps: u64,
    /// Samples kept.
    pub samples: usize,
    /// Wall seconds.
    pub seconds: f64,
}

/// What `calibrate` found (also `calibration.json`).
#[derive(Clone, Debug, Serialize)]
pub struct CalibrationReport {
    /// The runs.
    pub runs: Vec<RunInfo>,
    /// Worker threads of every recording run, each on a core of its own.
    pub threads: usize,
    /// Samples in the fit (blocks with fluid).
    pub samples: usize,
    /// Samples of never-fluid blocks, left out of fit and statistics.
    pub never_fluid_samples: usize,
    /// Steps of a balancing interval in the per-interval statistics.
    pub interval: u64,
    /// The model written to coefficients.toml.
    pub model: String,
    /// The written model's shares within 10 % (see [`ModelReport`]).
    pub share_within_10pct: BTreeMap<String, f64>,
    /// The written model's median of E_X per part (and `total`).
    pub median: BTreeMap<String, f64>,
    /// The written model's MAD of E_X per part (and `total`).
    pub mad: BTreeMap<String, f64>,
    /// Both models on the same samples.
    pub models: BTreeMap<String, ModelReport>,
    /// The written model's interval statistics per run (scene), in-sample and held out.
    pub by_run: Vec<RunScores>,
    /// What timing noise alone allows.
    pub noise_floor: NoiseReport,
    /// Median share m_X / m_tot per part.
    pub part_share_median: BTreeMap<String, f64>,
    /// Wall seconds of the whole campaign.
    pub seconds: f64,
}

/// The runs of the campaign: (block size, diameter, duration in units of T). The default covers the
/// hopper scenes' regime (16³ blocks with D = 7.5, 32³ with D = 15): about 12 minutes on 2 cores.
fn preset(o: &CalibrateOptions) -> Vec<(usize, f64, f64)> {
    let given = !o.block_sizes.is_empty() || !o.diameters.is_empty();
    let base: Vec<(usize, f64, f64)> = if o.paper {
        [24, 32, 48, 64]
            .iter()
            .flat_map(|&b| [10.0, 20.0].map(|d| (b, d, 2.5)))
            .collect()
    } else if o.quick {
        vec![(12, 4.0, 0.25), (12, 6.0, 0.25)]
    } else {
        vec![(16, 6.0, 1.5), (16, 10.0, 1.5), (32, 10.0, 0.4), (32, 15.0, 0.4)]
    };
    if !given {
        return base;
    }
    let sizes: Vec<usize> = if o.block_sizes.is_empty() {
        let mut v: Vec<usize> = base.iter().map(|r| r.0).collect();
        v.dedup();
        v
    } else {
        o.block_sizes.clone()
    };
    let diams: Vec<f64> = if o.diameters.is_empty() {
        let mut v: Vec<f64> = base.iter().map(|r| r.1).collect();
        v.sort_by(f64::total_cmp);
        v.dedup();
        v
    } else {
        o.diameters.clone()
    };
    // A duration that gives every block size about as many steps as the default's.
    let duration = |b: usize| {
        if o.quick {
            0.25
        } else if o.paper {
            2.5
        } else {
            (1.5 * 16.0 / b as f64).min(2.5)
        }
    };
    sizes
        .iter()
        .flat_map(|&b| diams.iter().map(move |&d| (b, d, duration(b))))
        .collect()
}

/// Keys every run of a campaign is recorded with, its workers' count aside ([`recording`]).
const RECORDING: [&str; 4] = [
    // One process whose workers stay on their cores for the whole run (the paper pinned every
    // process with LIKWID).
    "processes.count=1",
    "processes.steps_per_graph=1",
    "processes.pin=\"compact\"",
    // The campaign does not read the coefficients it is about to replace.
    "balance.weights=\"cells\"",
];

/// The keys of a recording run of `o`: [`RECORDING`] and the workers' count.
fn recording(o: &CalibrateOptions) -> impl Iterator<Item = String> {
    RECORDING
        .map(String::from)
        .into_iter()
        .chain([format!("processes.threads_per_process={}", o.threads)])
}

fn run_config(o: &CalibrateOptions, bs: usize, d: f64, duration: f64) -> Result<Config> {
    let sets: Vec<String> = [
        format!("domain.block_size=[{bs},{bs},{bs}]"),
        format!("scene.diameter={d}"),
        format!("scene.duration={duration}"),
    ]
    .into_iter()
    .chain(recording(o))
    .collect();
    config::load(&o.scene, &sets)
}

fn git_commit() -> String {
    std::process::Command::new("git")
        .args(["rev-parse", "--short=12", "HEAD"])
        .output()
        .ok()
        .filter(|o| o.status.success())
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
        .unwrap_or_else(|| "unknown".to_string())
}

fn machine() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|t| {
            t.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|s| s.trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".to_string());
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    format!("{cpu}, {cores} cores")
}

fn today() -> String {
    std::process::Command::new("date")
        .arg("+%Y-%m-%d")
        .output()
        .ok()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
        .unwrap_or_default()
}

/// The `calibration.json` of the campaign that wrote `samples` (in the same folder), if it is there.
fn recorded_report(samples: &Path) -> Option<serde_json::Value> {
    let text = std::fs::read_to_string(samples.with_file_name("calibration.json")).ok()?;
    serde_json::from_str(&text).ok()
}

/// The scenes of the runs of the campaign whose report is `json` (in run order); `None` where it names
/// no runs.
fn recorded_scenes(json: &serde_json::Value) -> Option<Vec<String>> {
    let names: Option<Vec<String>> = json["by_run"]
        .as_array()?
        .iter()
        .map(|r| r["scene"].as_str().map(str::to_string))
        .collect();
    names.filter(|n| !n.is_empty())
}

/// Runs the campaign, fits, evaluates and writes `samples.csv`, `coefficients.toml`, `calibration.json`
/// and the figures 6–8 into `o.out`.
pub fn run(o: &CalibrateOptions) -> Result<CalibrationReport> {
    let t0 = Instant::now();
    std::fs::create_dir_all(&o.out).map_err(|e| io_err(&o.out, e))?;
    let (c, scenes, origin, threads) = match &o.samples {
        Some(path) => {
            let c = read_samples(path)?;
            // samples.csv does not name the scene a run recorded (it may be a --with scene); the
            // campaign's calibration.json beside it does.
            let report = recorded_report(path);
            let scenes = match report.as_ref().and_then(recorded_scenes) {
                Some(names) if names.len() == c.runs.len() => names,
                _ => c
                    .runs
                    .iter()
                    .enumerate()
                    .map(|(k, r)| {
                        format!(
                            "run {k} of {}: b_s = {}, D = {}",
                            path.display(),
                            r.block_size,
                            r.diameter
                        )
                    })
                    .collect(),
            };
            // Campaigns from before `--threads` recorded on one worker.
            let threads = report.and_then(|j| j["threads"].as_u64()).map_or(1, |t| t as usize);
            (c, scenes, format!("refit of {}", path.display()), threads)
        }
        None => {
            let (c, scenes) = campaign(o)?;
            (c, scenes, String::from("blockflow calibrate"), o.threads)
        }
    };
    if c.samples.is_empty() {
        return Err(Error::Config(format!(
            "calibrate: no samples (every run is shorter than the {WARMUP}-step warm-up); raise scene.duration"
        )));
    }
    if o.samples.is_none() {
        let path = o.out.join("samples.csv");
        std::fs::write(&path, &c.csv).map_err(|e| io_err(&path, e))?;
    }
    fit_and_report(o, &c, scenes, threads, &origin, t0)
}

/// Runs the campaign of `o`; returns it and a description of every run.
fn campaign(o: &CalibrateOptions) -> Result<(Campaign, Vec<String>)> {
    // Build every configuration first: bad input fails before any run, and the bar knows the total.
    let mut plans = Vec::new();
    for (bs, d, duration) in preset(o) {
        let cfg = run_config(o, bs, d, duration)?;
        let scene = scenes::build(&cfg)?;
        plans.push(Plan {
            block_size: bs,
            diameter: d,
            duration,
            cfg,
            steps: scene.steps,
        });
    }
    let mut scenes: Vec<String> = plans
        .iter()
        .map(|p| format!("{} with b_s = {}, D = {}", o.scene.display(), p.block_size, p.diameter))
        .collect();
    for path in &o.with {
        let sets: Vec<String> = recording(o)
            .chain([String::from("balance.strategy=\"none\"")])
            .collect();
        let cfg = config::load(path, &sets)?;
        let scene = scenes::build(&cfg)?;
        let diameter = scene
            .particles
            .as_ref()
            .and_then(|p| p.bodies.iter().map(|b| 2.0 * b.radius).reduce(f64::max))
            .unwrap_or(0.0);
        let block_size = cfg.domain.block_size.map(|b| b[0]).unwrap_or_else(|| {
            let blocks = cfg.domain.blocks.unwrap_or(scene.default_blocks);
            scene.cells.map_or(0, |c| c[0] / blocks[0].max(1))
        });
        scenes.push(format!("{} ({} steps)", path.display(), o.with_steps));
        plans.push(Plan {
            block_size,
            diameter,
            duration: 1.0,
            cfg,
            steps: o.with_steps,
        });
    }
    let c = record(&plans)?;
    Ok((c, scenes))
}

/// Fits both models to the campaign's samples, scores them, writes `coefficients.toml`,
/// `calibration.json` and figures 6–8.
fn fit_and_report(
    o: &CalibrateOptions,
    c: &Campaign,
    scenes: Vec<String>,
    threads: usize,
    origin: &str,
    t0: Instant,
) -> Result<CalibrationReport> {
    let n_runs = scenes.len();
    // Never-fluid blocks are out of the fit and of every statistic (module documentation).
    let fluid: Vec<Sample> = c
        .samples
        .iter()
        .filter(|s| !c.never_fluid[s.run][s.block])
        .copied()
        .collect();
    let prov = Provenance {
        machine: machine(),
        date: today(),
        commit: git_commit(),
        scenes,
        samples: fluid.len(),
        threads,
        fit_quality: BTreeMap::new(),
        note: format!(
            "{origin}: {} runs, first {WARMUP} steps of each dropped, one sample per block per step; \
             blocks that never hold fluid left out; weighted (1/m_tot) least squares over sums of {} steps per block{}",
            n_runs,
            o.interval,
            if o.model.non_negative() {
                ", coefficients >= 0"
            } else {
                ""
            }
        ),
    };
    let mut models = BTreeMap::new();
    let mut chosen = None;
    let mut by_run = Vec::new();
    for model in [Model::Paper, Model::Blockflow] {
        let coeffs = estimator::fit(&fluid, prov.clone(), model, o.interval);
        let ev: Evaluation = estimator::evaluate(&coeffs, &fluid);
        let in_sample = estimator::score(&coeffs, &fluid, o.interval);
        let held_by_run = estimator::cross_validate_by_run(&fluid, model, o.interval);
        let mut held = Scores::default();
        for (_, sc) in &held_by_run {
            held.add(sc);
        }
        let r = ModelReport::of(&ev, &in_sample, &held);
        if model == o.model {
            by_run = held_by_run
                .iter()
                .map(|(run, h)| {
                    let own: Vec<Sample> = fluid.iter().filter(|s| s.run == *run).copied().collect();
                    RunScores::of(
                        prov.scenes.get(*run).cloned().unwrap_or_else(|| format!("run {run}")),
                        &estimator::score(&coeffs, &own, o.interval),
                        h,
                    )
                })
                .collect();
            chosen = Some(coeffs);
        }
        models.insert(model.name().to_string(), r);
    }
    let mut coeffs = chosen.expect("the chosen model is one of the two");
    let report_chosen = &models[o.model.name()];
    coeffs.provenance.fit_quality = report_chosen
        .share_within_10pct
        .iter()
        .filter(|(_, v)| v.is_finite())
        .map(|(k, v)| (k.clone(), *v))
        .collect();
    let path = o.out.join("coefficients.toml");
    std::fs::write(&path, coeffs.to_toml()).map_err(|e| io_err(&path, e))?;
    let share_median = figures(&o.out, c, &fluid, &coeffs)?;
    let noise = estimator::noise_floor(&fluid, o.interval);
    let report = CalibrationReport {
        runs: c.runs.clone(),
        threads: prov.threads,
        samples: fluid.len(),
        never_fluid_samples: c.samples.len() - fluid.len(),
        interval: o.interval,
        model: o.model.name().to_string(),
        share_within_10pct: report_chosen.share_within_10pct.clone(),
        median: report_chosen.median.clone(),
        mad: report_chosen.mad.clone(),
        models,
        by_run,
        noise_floor: NoiseReport {
            step: noise.step.share(),
            interval: noise.interval.share(),
            step_samples: noise.step.total,
            interval_samples: noise.interval.total,
            step_mad: noise.step_mad,
            between_blocks: noise.between_blocks.share(),
            between_blocks_samples: noise.between_blocks.total,
            between_blocks_by_kind: kind_shares(&noise.between_blocks_by_kind),
        },
        part_share_median: share_median,
        seconds: t0.elapsed().as_secs_f64(),
    };
    let path = o.out.join("calibration.json");
    let text = serde_json::to_string_pretty(&report).expect("report serialises");
    std::fs::write(&path, text + "\n").map_err(|e| io_err(&path, e))?;
    Ok(report)
}

/// One calibration run: block size, diameter, duration (units of T), configuration, steps.
struct Plan {
    block_size: usize,
    diameter: f64,
    duration: f64,
    cfg: Config,
    steps: u64,
}

/// The statistics of one model on the campaign's samples.
#[derive(Clone, Debug, Serialize)]
pub struct ModelReport {
    /// Shares within 10 %: `step_in_sample` (the paper's statistic), `step_held_out`,
    /// `interval_in_sample`, `interval_held_out` (block shares of each interval's load,
    /// leave-one-run-out), `interval_predictive` (held out, predicted at the interval's start as
    /// `estimator` weights are: forecast), `interval_predictive_plain` (the same with the estimate at the
    /// start itself, the paper's weights) and `interval_predictive_in_sample`.
    pub share_within_10pct: BTreeMap<String, f64>,
    /// Median of E_X per part (and `total`), in-sample.
    pub median: BTreeMap<String, f64>,
    /// MAD of E_X per part (and `total`), in-sample.
    pub mad: BTreeMap<String, f64>,
    /// `interval_held_out` by kind of block ([`BlockKind::label`]).
    pub interval_held_out_by_kind: BTreeMap<String, KindShare>,
    /// `interval_predictive` by kind of block.
    pub interval_predictive_by_kind: BTreeMap<String, KindShare>,
}

/// The interval share within 10 % of one kind of block ([`BlockKind`]) and how many block intervals it
/// counts.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct KindShare {
    /// Share within 10 % (NaN when none was scored).
    pub share: f64,
    /// Block intervals scored.
    pub intervals: usize,
}

/// Hits per kind of block ([`BlockKind::index`]) keyed by the kinds' labels.
fn kind_shares(hits: &[estimator::Hits; 3]) -> BTreeMap<String, KindShare> {
    BlockKind::ALL
        .iter()
        .map(|k| {
            let h = hits[k.index()];
            (
                k.label().to_string(),
                KindShare {
                    share: h.share(),
                    intervals: h.total,
                },
            )
        })
        .collect()
}

impl ModelReport {
    fn of(ev: &Evaluation, in_sample: &Scores, held: &Scores) -> Self {
        let mut share = BTreeMap::new();
        share.insert("step_in_sample".to_string(), in_sample.step.share());
        share.insert("step_held_out".to_string(), held.step.share());
        share.insert("interval_in_sample".to_string(), in_sample.interval.share());
        share.insert("interval_held_out".to_string(), held.interval.share());
        share.insert("interval_predictive".to_string(), held.predictive.share());
        share.insert("interval_predictive_plain".to_string(), held.predictive_plain.share());
        share.insert(
            "interval_predictive_in_sample".to_string(),
            in_sample.predictive.share(),
        );
        let mut median = BTreeMap::new();
        let mut mad = BTreeMap::new();
        for (k, v) in &ev.per_part {
            median.insert(k.clone(), v.median);
            mad.insert(k.clone(), v.mad);
        }
        median.insert("total".to_string(), ev.total.median);
        mad.insert("total".to_string(), ev.total.mad);
        ModelReport {
            share_within_10pct: share,
            median,
            mad,
            interval_held_out_by_kind: kind_shares(&held.interval_by_kind),
            interval_predictive_by_kind: kind_shares(&held.predictive_by_kind),
        }
    }
}

/// The interval statistics of one run (scene) of the campaign: the fit of all runs scored on it, and
/// the fit without it.
#[derive(Clone, Debug, Serialize)]
pub struct RunScores {
    /// What the run recorded (as in the provenance's scene list).
    pub scene: String,
    /// Block shares of each interval within 10 %, the fit of all runs.
    pub interval_in_sample: f64,
    /// The same, fitted without this run.
    pub interval_held_out: f64,
    /// Predicted at the interval's start, fitted without this run.
    pub interval_predictive: f64,
    /// `interval_held_out` by kind of block ([`BlockKind::label`]).
    pub interval_held_out_by_kind: BTreeMap<String, KindShare>,
}

impl RunScores {
    fn of(scene: String, in_sample: &Scores, held: &Scores) -> Self {
        RunScores {
            scene,
            interval_in_sample: in_sample.interval.share(),
            interval_held_out: held.interval.share(),
            interval_predictive: held.predictive.share(),
            interval_held_out_by_kind: kind_shares(&held.interval_by_kind),
        }
    }
}

/// The timing noise floor (see [`estimator::NoiseFloor`]).
#[derive(Clone, Debug, Serialize)]
pub struct NoiseReport {
    /// Share of per-step samples within 10 % of their unchanged group's median.
    pub step: f64,
    /// Same for interval sums.
    pub interval: f64,
    /// Per-step samples in such groups.
    pub step_samples: usize,
    /// Interval sums in such groups.
    pub interval_samples: usize,
    /// Median relative MAD of m_tot within a group.
    pub step_mad: f64,
    /// Share of interval sums of identical blocks within 10 % of their group's median
    /// ([`estimator::NoiseFloor::between_blocks`]).
    pub between_blocks: f64,
    /// Interval sums in such groups.
    pub between_blocks_samples: usize,
    /// `between_blocks` by the groups' kind of block ([`BlockKind::label`]).
    pub between_blocks_by_kind: BTreeMap<String, KindShare>,
}

/// What the campaign recorded: the samples, which blocks of each run never hold fluid, the runs, the
/// first run's figure 6 series and `samples.csv`.
struct Campaign {
    samples: Vec<Sample>,
    never_fluid: Vec<Vec<bool>>,
    runs: Vec<RunInfo>,
    fig6: Vec<plots::BlockSeries>,
    csv: String,
}

/// Runs every planned configuration (block size, diameter, configuration, steps) with a [`Sampler`].
fn record(plans: &[Plan]) -> Result<Campaign> {
    let total: u64 = plans.iter().map(|p| p.steps).sum();
    let bar = if std::io::stderr().is_terminal() {
        let b = ProgressBar::new(total);
        b.set_style(
            ProgressStyle::with_template("{spinner} [{elapsed_precise}] {wide_bar} {pos}/{len} steps, ETA {eta} {msg}")
                .expect("valid template"),
        );
        b
    } else {
        ProgressBar::hidden()
    };
    let mut c = Campaign {
        samples: Vec::new(),
        never_fluid: Vec::new(),
        runs: Vec::new(),
        fig6: Vec::new(),
        csv: String::from(
            "run,block_size,diameter,step,t_star,block,row,C,F,NB,PL,PS,K,S,runs,breaks,wall_links,particle_links,\
             link_cells,map_active,map_bodies,box_cells,rows_derived,turned,covered,rb_active,contacts_seen,\
             scanned,wall_lines,tail_runs,shifted_runs,row_pitch,m_lbm,m_bh,m_coup1,m_coup2,m_rb\n",
        ),
    };
    for (r, p) in plans.iter().enumerate() {
        let (bs, d, cfg, steps) = (&p.block_size, &p.diameter, &p.cfg, &p.steps);
        bar.set_message(format!("b_s = {bs}, D = {d}"));
        let ts = Instant::now();
        let scene = scenes::build(cfg)?;
        let recording = Recording {
            trace: false,
            block_parts: true,
        };
        let mut tl = TimeLoop::<f64>::from_config(cfg, &scene, recording)?;
        let sim = tl.sim();
        c.never_fluid
            .push(sim.blocks.iter().map(|b| b.fluid_cells == 0).collect());
        let first = (r == 0).then(|| {
            (0..sim.blocks.len())
                .map(|b| plots::BlockSeries {
                    row: sim.domain.coords(b)[2],
                    points: Vec::new(),
                })
                .collect()
        });
        let h = tl.add_observer(Sampler {
            run: r,
            block_size: *bs,
            diameter: *d,
            t_unit: *steps as f64 / p.duration,
            bar: bar.clone(),
            samples: Vec::new(),
            fig6: first,
            csv: String::new(),
        });
        let ran = tl.run_to(*steps);
        tl.finish(&match &ran {
            Ok(_) => RunEnd::Done,
            Err(e) => RunEnd::Failed(e),
        })?;
        ran?;
        let s = tl.observer(h);
        c.csv += &s.csv;
        if let Some(f) = &s.fig6 {
            c.fig6 = f.clone();
        }
        c.samples.extend_from_slice(&s.samples);
        c.runs.push(RunInfo {
            block_size: *bs,
            diameter: *d,
            steps: *steps,
            samples: s.samples.len(),
            seconds: ts.elapsed().as_secs_f64(),
        });
        if bar.is_hidden() {
            // No progress bar (stderr is not a terminal): one line per run for logs.
            eprintln!(
                "calibrate: run {}/{} (b_s = {bs}, D = {d}): {steps} steps in {:.0} s",
                r + 1,
                plans.len(),
                ts.elapsed().as_secs_f64()
            );
        }
    }
    bar.finish_and_clear();
    Ok(c)
}

/// Figures 6–8 (fluid cells and LBM time per block over time, the parts' shares m_X / m_tot, the errors
/// E_X); returns the median share of every part.
fn figures(out: &Path, c: &Campaign, samples: &[Sample], coeffs: &Coefficients) -> Result<BTreeMap<String, f64>> {
    let part_of = |m: &PartTimes, k: usize| m.as_array()[k];
    let timed: Vec<&Sample> = samples.iter().filter(|s| s.m.total() > 0.0).collect();
    let mut shares = Vec::new();
    let mut errors = Vec::new();
    let mut share_median = BTreeMap::new();
    for (k, name) in estimator::PARTS.iter().enumerate() {
        let v: Vec<f64> = timed.iter().map(|s| part_of(&s.m, k) / s.m.total()).collect();
        share_median.insert(name.to_string(), estimator::median(&v));
        shares.push((name.to_string(), v));
        let e: Vec<f64> = timed
            .iter()
            .map(|s| (part_of(&coeffs.predict(&s.q), k) - part_of(&s.m, k)) / s.m.total())
            .collect();
        errors.push((name.to_string(), e));
    }
    let etot: Vec<f64> = timed
        .iter()
        .map(|s| (coeffs.total(&s.q) - s.m.total()) / s.m.total())
        .collect();
    errors.push(("total".to_string(), etot));
    plots::figure6(&out.join("figure6.png"), &c.fig6)?;
    plots::figure7(&out.join("figure7.png"), &shares)?;
    plots::figure8(&out.join("figure8.png"), &errors)?;
    Ok(share_median)
}

/// The report as Markdown: the coefficient table of the written model (the shape of Table 2), its
/// error statistics, and both models' shares within 10 % on the same samples next to the noise floor.
pub fn to_markdown(r: &CalibrationReport, c: &Coefficients) -> String {
    let mut s = format!(
        "Coefficients ({} model; seconds per block and step)\n\n",
        c.model.name()
    );
    s += "| part | term | coefficient |\n|---|---|---:|\n";
    for (p, name) in estimator::PARTS.iter().enumerate() {
        for (v, (key, meaning)) in c.parts[p].iter().zip(c.model.terms(p)) {
            s += &format!("| {name} | {key} ({meaning}) | {v:.3e} |\n");
        }
    }
    s += "\nErrors E_X = (WL_X - m_X) / m_tot, per step, in-sample\n\n| part | median | MAD | median share of m_tot |\n|---|---:|---:|---:|\n";
    for (k, v) in &r.median {
        s += &format!(
            "| {k} | {:.2} % | {:.2} % | {} |\n",
            100.0 * v,
            100.0 * r.mad[k],
            r.part_share_median
                .get(k)
                .map_or("".to_string(), |x| format!("{:.1} %", 100.0 * x))
        );
    }
    s += &format!(
        "\nShare within 10 % (paper, per step in-sample: over 85 %; interval = {} steps, as shares of the interval's total)\n\n",
        r.interval
    );
    let keys = [
        "step_in_sample",
        "step_held_out",
        "interval_in_sample",
        "interval_held_out",
        "interval_predictive",
        "interval_predictive_plain",
    ];
    s += "| model |";
    for k in keys {
        s += &format!(" {k} |");
    }
    s += "\n|---|";
    s += &"---:|".repeat(keys.len());
    s += "\n";
    for (name, m) in &r.models {
        s += &format!("| {name} |");
        for k in keys {
            s += &format!(" {} |", pct(m.share_within_10pct[k]));
        }
        s += "\n";
    }
    s += &format!(
        "| noise floor | {} | | | {} | | |\n",
        pct(r.noise_floor.step),
        pct(r.noise_floor.interval)
    );
    s += &per_run_table(r);
    s += &noise_floor_lines(r);
    s += &format!(
        "{} samples from {} runs in {:.0} s ({} samples of never-fluid blocks left out)\n",
        r.samples,
        r.runs.len(),
        r.seconds,
        r.never_fluid_samples
    );
    s
}

/// Percent with one decimal, "-" for a statistic that has no samples (NaN).
fn pct(v: f64) -> String {
    if v.is_finite() {
        format!("{:.1} %", 100.0 * v)
    } else {
        "-".into()
    }
}

/// The per-run table of the report: interval shares within 10 % in-sample, held out and predictive, and
/// held out by kind of block, with the rows of all runs and of the noise floor (empty without runs).
fn per_run_table(r: &CalibrationReport) -> String {
    let mut s = String::new();
    if r.by_run.is_empty() {
        return s;
    }
    // Held out by kind of block: share (block intervals scored), "-" where the run has none.
    let kind = |m: &BTreeMap<String, KindShare>, k: BlockKind| {
        let x = m[k.label()];
        if x.intervals == 0 {
            "-".to_string()
        } else {
            format!("{} ({})", pct(x.share), x.intervals)
        }
    };
    s += &format!(
        "\nPer run ({} model): interval shares within 10 %; held out by kind of block (block intervals)\n\n",
        r.model
    );
    s += "| run | in-sample | held out | predictive |";
    for k in BlockKind::ALL {
        s += &format!(" held out, {} |", k.label());
    }
    s += "\n|---|---:|---:|---:|---:|---:|---:|\n";
    for x in &r.by_run {
        s += &format!(
            "| {} | {} | {} | {} |",
            x.scene,
            pct(x.interval_in_sample),
            pct(x.interval_held_out),
            pct(x.interval_predictive)
        );
        for k in BlockKind::ALL {
            s += &format!(" {} |", kind(&x.interval_held_out_by_kind, k));
        }
        s += "\n";
    }
    let chosen = &r.models[&r.model];
    s += "| all runs | | | |";
    for k in BlockKind::ALL {
        s += &format!(" {} |", kind(&chosen.interval_held_out_by_kind, k));
    }
    s += "\n| all runs, predictive | | | |";
    for k in BlockKind::ALL {
        s += &format!(" {} |", kind(&chosen.interval_predictive_by_kind, k));
    }
    s += "\n| noise floor between identical blocks | | | |";
    for k in BlockKind::ALL {
        s += &format!(" {} |", kind(&r.noise_floor.between_blocks_by_kind, k));
    }
    s += "\n";
    s
}

/// The noise-floor lines of the report: unchanged blocks against their own median, and blocks with the
/// same quantities against their group's.
fn noise_floor_lines(r: &CalibrationReport) -> String {
    if r.noise_floor.step_samples == 0 {
        "\nnoise floor: no block was timed on 10 consecutive steps with nothing changed\n".to_string()
    } else {
        format!(
            "\nnoise floor: unchanged blocks within 10 % of their own median ({} steps, {} interval sums; median relative MAD {:.1} %)\n",
            r.noise_floor.step_samples,
            r.noise_floor.interval_samples,
            100.0 * r.noise_floor.step_mad
        ) + &if r.noise_floor.between_blocks_samples == 0 {
            "noise floor between blocks: no 3 blocks had the same quantities through an interval\n".to_string()
        } else {
            format!(
                "noise floor between blocks: interval loads of blocks with the same quantities within 10 % of their group's median: {} ({} interval sums)\n",
                pct(r.noise_floor.between_blocks),
                r.noise_floor.between_blocks_samples
            )
        }
    }
}

/// The columns of `samples.csv` that [`read_samples`] reads, in the order [`parse_sample_row`] takes them.
const SAMPLE_COLUMNS: [&str; 37] = [
    "run",
    "block_size",
    "diameter",
    "step",
    "t_star",
    "block",
    "row",
    "C",
    "F",
    "NB",
    "PL",
    "PS",
    "K",
    "S",
    "runs",
    "wall_links",
    "particle_links",
    "link_cells",
    "map_active",
    "map_bodies",
    "box_cells",
    "rows_derived",
    "turned",
    "covered",
    "rb_active",
    "contacts_seen",
    "scanned",
    "m_lbm",
    "m_bh",
    "m_coup1",
    "m_coup2",
    "m_rb",
    "breaks",
    "wall_lines",
    "tail_runs",
    "shifted_runs",
    "row_pitch",
];

/// One line of `samples.csv`: where the sample was taken, its quantities and its measured part times.
struct SampleRow {
    run: usize,
    block_size: usize,
    diameter: f64,
    step: u64,
    t_star: f64,
    block: usize,
    row: usize,
    q: Quantities,
    m: PartTimes,
}

/// The values `v` of one line, in the order of [`SAMPLE_COLUMNS`].
fn parse_sample_row(v: &[f64]) -> SampleRow {
    SampleRow {
        run: v[0] as usize,
        block_size: v[1] as usize,
        diameter: v[2],
        step: v[3] as u64,
        t_star: v[4],
        block: v[5] as usize,
        row: v[6] as usize,
        q: Quantities {
            c: v[7],
            f: v[8],
            nb: v[9],
            pl: v[10],
            ps: v[11],
            k: v[12],
            s: v[13],
            runs: v[14],
            breaks: v[32],
            wall_links: v[15],
            wall_lines: v[33],
            particle_links: v[16],
            link_cells: v[17],
            map_active: v[18],
            map_bodies: v[19],
            box_cells: v[20],
            rows_derived: v[21],
            turned: v[22],
            covered: v[23],
            rb_active: v[24],
            contacts_seen: v[25],
            scanned: v[26],
            tail_runs: v[34],
            shifted_runs: v[35],
            row_pitch: v[36],
        },
        m: PartTimes {
            lbm: v[27],
            bh: v[28],
            coup1: v[29],
            coup2: v[30],
            rb: v[31],
        },
    }
}

impl Campaign {
    /// Adds one sample: its run (created at first sight), whether its block held fluid, and for the first
    /// run its point of the figure 6 series.
    fn add(&mut self, r: SampleRow, fluid_seen: &mut Vec<Vec<bool>>) {
        while self.runs.len() <= r.run {
            self.runs.push(RunInfo {
                block_size: r.block_size,
                diameter: r.diameter,
                steps: 0,
                samples: 0,
                seconds: 0.0,
            });
            fluid_seen.push(Vec::new());
        }
        let info = &mut self.runs[r.run];
        info.steps = info.steps.max(r.step);
        info.samples += 1;
        let seen = &mut fluid_seen[r.run];
        if seen.len() <= r.block {
            seen.resize(r.block + 1, false);
        }
        seen[r.block] |= r.q.f > 0.0;
        if r.run == 0 {
            if self.fig6.len() <= r.block {
                self.fig6.resize(
                    r.block + 1,
                    plots::BlockSeries {
                        row: 0,
                        points: Vec::new(),
                    },
                );
            }
            let series = &mut self.fig6[r.block];
            series.row = r.row;
            series.points.push((r.t_star, r.q.f, r.m.lbm));
        }
        self.samples.push(Sample {
            run: r.run,
            step: r.step,
            block: r.block,
            q: r.q,
            m: r.m,
        });
    }
}

/// Reads the samples of an earlier campaign from its `samples.csv` (the columns [`record`] writes):
/// the samples, the runs, which blocks never held fluid (F = 0 in every sample of the run) and the
/// first run's figure 6 series.
fn read_samples(path: &Path) -> Result<Campaign> {
    let text = std::fs::read_to_string(path).map_err(|e| io_err(path, e))?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or_default().split(',').collect();
    let idx: Vec<usize> = SAMPLE_COLUMNS
        .iter()
        .map(|name| {
            header.iter().position(|h| h == name).ok_or_else(|| {
                Error::Config(format!(
                    "{}: no column {name:?} (not a samples.csv of this version)",
                    path.display()
                ))
            })
        })
        .collect::<Result<_>>()?;
    let mut c = Campaign {
        samples: Vec::new(),
        never_fluid: Vec::new(),
        runs: Vec::new(),
        fig6: Vec::new(),
        csv: String::new(),
    };
    let mut fluid_seen: Vec<Vec<bool>> = Vec::new();
    for (n, line) in lines.enumerate() {
        let f: Vec<&str> = line.split(',').collect();
        // Counts and times are finite: a NaN or infinity (a hand-edited or damaged file) would reach the
        // fit and the figures.
        let v: Vec<f64> = idx
            .iter()
            .zip(SAMPLE_COLUMNS)
            .map(|(&i, name)| {
                f.get(i)
                    .and_then(|x| x.parse::<f64>().ok())
                    .filter(|v| v.is_finite())
                    .ok_or_else(|| {
                        Error::Config(format!(
                            "{}:{}: column {name} is not a finite number",
                            path.display(),
                            n + 2
                        ))
                    })
            })
            .collect::<Result<_>>()?;
        c.add(parse_sample_row(&v), &mut fluid_seen);
    }
    c.never_fluid = fluid_seen
        .into_iter()
        .map(|v| v.into_iter().map(|x| !x).collect())
        .collect();
    Ok(c)
}
