//! `blockflow calibrate`: the workload-estimator calibration of section 3.3. Runs the calibration scene
//! for every block size and diameter, drops the first 50 steps, records one sample per block per step
//! (the Table 1 quantities and the measured part times m_X from the task records' thread CPU time), fits
//! eqs. (10)–(14) by linear least squares, and reports the error statistics of section 3.4 in-sample and
//! held out (fit without one run, test on it), with and without the blocks that never hold fluid.
//!
//! Every run uses one virtual process with one thread and one step per graph, so each task's CPU time
//! belongs to exactly one block and step.

use crate::config::{self, Config};
use crate::error::{io_err, Error, Result};
use crate::estimator::{self, Coefficients, Evaluation, PartTimes, Provenance, Quantities, Sample};
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
    /// Block edge lengths in cells, comma-separated (default 12,16; --quick 12; --paper 24,32,48,64).
    #[arg(long, value_delimiter = ',')]
    pub block_sizes: Vec<usize>,
    /// Sphere diameters in cells, comma-separated (default 4,6; --paper 10,20).
    #[arg(long, value_delimiter = ',')]
    pub diameters: Vec<f64>,
    /// A short campaign (about two minutes), for tests.
    #[arg(long)]
    pub quick: bool,
    /// The paper's sizes (block sizes 24, 32, 48, 64; D = 10, 20; 2.5 T), for big machines.
    #[arg(long, conflicts_with = "quick")]
    pub paper: bool,
    /// Output folder.
    #[arg(long, default_value = "out/calibration")]
    pub out: PathBuf,
}

/// Runs `blockflow calibrate` and prints the coefficient table and error statistics.
pub fn execute(a: CalibrateArgs) -> Result<()> {
    if a.block_sizes.contains(&0) || a.diameters.iter().any(|d| !(d.is_finite() && *d > 0.0)) {
        return Err(Error::Config(
            "calibrate: --block-sizes and --diameters must be positive".into(),
        ));
    }
    let opts = CalibrateOptions {
        scene: a.scene,
        block_sizes: a.block_sizes,
        diameters: a.diameters,
        quick: a.quick,
        paper: a.paper,
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
    /// A short campaign for tests (about two minutes).
    pub quick: bool,
    /// The paper's sizes (b_s = 24, 32, 48, 64; D = 10, 20; 2.5 T): for big machines.
    pub paper: bool,
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
            self.csv += &format!(
                "{r},{bs},{d},{},{t_star:.6},{b},{row},{},{},{},{},{},{},{},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e}\n",
                sim.step, q.c, q.f, q.nb, q.pl, q.ps, q.k, q.s, m.lbm, m.bh, m.coup1, m.coup2, m.rb
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
    /// Samples in the fit.
    pub samples: usize,
    /// Share of samples with |E_tot| < 10 %: `in_sample`, `held_out`, and both without the blocks that
    /// never hold fluid.
    pub share_within_10pct: BTreeMap<String, f64>,
    /// Median of E_X per part (and `total`).
    pub median: BTreeMap<String, f64>,
    /// MAD of E_X per part (and `total`).
    pub mad: BTreeMap<String, f64>,
    /// Median share m_X / m_tot per part.
    pub part_share_median: BTreeMap<String, f64>,
    /// Wall seconds of the whole campaign.
    pub seconds: f64,
}

fn preset(o: &CalibrateOptions) -> (Vec<usize>, Vec<f64>, f64) {
    let (bs, d, dur) = if o.paper {
        (vec![24, 32, 48, 64], vec![10.0, 20.0], 2.5)
    } else if o.quick {
        (vec![12], vec![4.0, 6.0], 0.25)
    } else {
        (vec![12, 16], vec![4.0, 6.0], 2.5)
    };
    (
        if o.block_sizes.is_empty() {
            bs
        } else {
            o.block_sizes.clone()
        },
        if o.diameters.is_empty() { d } else { o.diameters.clone() },
        dur,
    )
}

fn run_config(o: &CalibrateOptions, bs: usize, d: f64, duration: f64) -> Result<Config> {
    let sets = vec![
        format!("domain.block_size=[{bs},{bs},{bs}]"),
        format!("scene.diameter={d}"),
        format!("scene.duration={duration}"),
        "processes.count=1".to_string(),
        "processes.threads_per_process=1".to_string(),
        "processes.steps_per_graph=1".to_string(),
    ];
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

/// Runs the campaign, fits, evaluates and writes `samples.csv`, `coefficients.toml`, `calibration.json`
/// and the figures 6–8 into `o.out`.
pub fn run(o: &CalibrateOptions) -> Result<CalibrationReport> {
    let t0 = Instant::now();
    let (sizes, diams, duration) = preset(o);
    std::fs::create_dir_all(&o.out).map_err(|e| io_err(&o.out, e))?;
    // Build every configuration first: bad input fails before any run, and the bar knows the total.
    let mut plans = Vec::new();
    for &bs in &sizes {
        for &d in &diams {
            let cfg = run_config(o, bs, d, duration)?;
            let scene = scenes::build(&cfg)?;
            plans.push((bs, d, cfg, scene.steps));
        }
    }
    let c = record(&plans, duration)?;
    if c.samples.is_empty() {
        return Err(Error::Config(format!(
            "calibrate: no samples (every run is shorter than the {WARMUP}-step warm-up); raise scene.duration"
        )));
    }
    let path = o.out.join("samples.csv");
    std::fs::write(&path, &c.csv).map_err(|e| io_err(&path, e))?;
    let prov = Provenance {
        machine: machine(),
        date: today(),
        commit: git_commit(),
        scenes: plans
            .iter()
            .map(|p| format!("{} with b_s = {}, D = {}", o.scene.display(), p.0, p.1))
            .collect(),
        samples: c.samples.len(),
        fit_quality: BTreeMap::new(),
        note: format!(
            "blockflow calibrate: {} runs, first {WARMUP} steps of each dropped, one sample per block per step",
            plans.len()
        ),
    };
    let mut coeffs = estimator::fit(&c.samples, prov.clone());
    let fluid_only: Vec<Sample> = c
        .samples
        .iter()
        .filter(|s| !c.never_fluid[s.run][s.block])
        .copied()
        .collect();
    let ev: Evaluation = estimator::evaluate(&coeffs, &c.samples);
    let ev_fluid = estimator::evaluate(&coeffs, &fluid_only);
    let multi_run = plans.len() > 1;
    let held = |s: &[Sample]| {
        if multi_run {
            estimator::held_out(s, prov.clone())
        } else {
            f64::NAN
        }
    };
    let mut share = BTreeMap::new();
    share.insert("in_sample".to_string(), ev.share_within_10pct);
    share.insert("held_out".to_string(), held(&c.samples));
    share.insert("in_sample_fluid_blocks".to_string(), ev_fluid.share_within_10pct);
    share.insert("held_out_fluid_blocks".to_string(), held(&fluid_only));
    coeffs.provenance.fit_quality = share.clone();
    let path = o.out.join("coefficients.toml");
    std::fs::write(&path, coeffs.to_toml()).map_err(|e| io_err(&path, e))?;
    let mut median = BTreeMap::new();
    let mut mad = BTreeMap::new();
    for (k, v) in &ev.per_part {
        median.insert(k.clone(), v.median);
        mad.insert(k.clone(), v.mad);
    }
    median.insert("total".to_string(), ev.total.median);
    mad.insert("total".to_string(), ev.total.mad);
    let share_median = figures(&o.out, &c, &coeffs)?;
    let report = CalibrationReport {
        runs: c.runs,
        samples: c.samples.len(),
        share_within_10pct: share,
        median,
        mad,
        part_share_median: share_median,
        seconds: t0.elapsed().as_secs_f64(),
    };
    let path = o.out.join("calibration.json");
    let text = serde_json::to_string_pretty(&report).expect("report serialises");
    std::fs::write(&path, text + "\n").map_err(|e| io_err(&path, e))?;
    Ok(report)
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
fn record(plans: &[(usize, f64, Config, u64)], duration: f64) -> Result<Campaign> {
    let total: u64 = plans.iter().map(|p| p.3).sum();
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
            "run,block_size,diameter,step,t_star,block,row,C,F,NB,PL,PS,K,S,m_lbm,m_bh,m_coup1,m_coup2,m_rb\n",
        ),
    };
    for (r, (bs, d, cfg, steps)) in plans.iter().enumerate() {
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
            t_unit: *steps as f64 / duration,
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
    }
    bar.finish_and_clear();
    Ok(c)
}

/// Figures 6–8 (fluid cells and LBM time per block over time, the parts' shares m_X / m_tot, the errors
/// E_X); returns the median share of every part.
fn figures(out: &Path, c: &Campaign, coeffs: &Coefficients) -> Result<BTreeMap<String, f64>> {
    let part_of = |m: &PartTimes, k: usize| m.as_array()[k];
    let timed: Vec<&Sample> = c.samples.iter().filter(|s| s.m.total() > 0.0).collect();
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

/// The report as Markdown: the coefficient table (the shape of Table 2), the error statistics and the
/// shares within 10 %.
pub fn to_markdown(r: &CalibrationReport, c: &Coefficients) -> String {
    let mut s = String::from("Coefficients (eqs. 10-14; seconds per step)\n\n| part | a1 | a2 | a3 | a4 | a5 |\n|---|---:|---:|---:|---:|---:|\n");
    let row = |name: &str, v: &[f64]| {
        let mut l = format!("| {name} |");
        for k in 0..5 {
            l += &v.get(k).map_or(" |".to_string(), |x| format!(" {x:.3e} |"));
        }
        l + "\n"
    };
    s += &row("LBM (C, F, 1)", &c.lbm);
    s += &row("BH (C, NB, 1)", &c.bh);
    s += &row("Coup1 (C, F, PL, PS, 1)", &c.coup1);
    s += &row("Coup2 (C, F, PL, PS, 1)", &c.coup2);
    s += &row("RB S·((PL+PS)², PL, PS, K, 1)", &c.rb);
    s += "\nErrors E_X = (WL_X - m_X) / m_tot\n\n| part | median | MAD | median share of m_tot |\n|---|---:|---:|---:|\n";
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
    s += "\nShare of samples with |E_tot| < 10 % (paper: over 85 %)\n\n";
    for (k, v) in &r.share_within_10pct {
        s += &format!("- {k}: {:.1} %\n", 100.0 * v);
    }
    s += &format!(
        "\n{} samples from {} runs in {:.0} s\n",
        r.samples,
        r.runs.len(),
        r.seconds
    );
    s
}
