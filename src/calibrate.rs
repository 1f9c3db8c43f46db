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
use crate::pipeline::Pipeline;
use crate::runner::{assignment, build_sim, make_executor};
use crate::scenes;
use crate::sim::Simulation;
use blockflow_kernels::Real;
use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;
use std::collections::BTreeMap;
use std::io::IsTerminal;
use std::path::PathBuf;
use std::time::Instant;

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

/// The Table 1 quantities of block `b` after the last step: C, F, NB from the block and its particle
/// overlay, P_L and P_S from the block's last rigid-body sub-step, K the contacts it owned averaged over
/// the step's sub-steps, S the sub-steps (0 for a block without rigid-body tasks).
pub fn quantities<T: Real>(sim: &Simulation<T>, b: usize) -> Quantities {
    let blk = &sim.blocks[b];
    let (f, nb) = match blk.particle_cells() {
        Some(pc) => (pc.fluid_cells, pc.near_boundary_cells),
        None => (blk.fluid_cells, blk.near_boundary_cells),
    };
    let mut q = Quantities {
        c: blk.layout.interior_cells() as f64,
        f: f as f64,
        nb: nb as f64,
        ..Default::default()
    };
    if let Some(p) = sim.particles.as_ref().filter(|p| p.active[b]) {
        // SAFETY: called between graph runs.
        let w = unsafe { p.blocks[b].work() };
        let s = p.subcycles as f64;
        q.pl = w.locals as f64;
        q.ps = (w.bodies.len() - w.locals) as f64;
        q.k = w.contacts_step as f64 / s;
        q.s = s;
    }
    q
}

/// The part times m_X of block `b` in step `kk` of the last graph run, from [`Pipeline::block_times`].
pub fn part_times(times: &[[u64; 6]], blocks: usize, kk: usize, b: usize) -> PartTimes {
    let t = times[kk * blocks + b];
    let s = |i: usize| t[i] as f64 * 1e-9;
    PartTimes {
        lbm: s(0),
        bh: s(1),
        coup1: s(4),
        coup2: s(5),
        rb: s(3),
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
    let mut samples: Vec<Sample> = Vec::new();
    let mut never_fluid: Vec<Vec<bool>> = Vec::new();
    let mut runs = Vec::new();
    let mut fig6: Vec<plots::BlockSeries> = Vec::new();
    let mut csv = String::from(
        "run,block_size,diameter,step,t_star,block,row,C,F,NB,PL,PS,K,S,m_lbm,m_bh,m_coup1,m_coup2,m_rb\n",
    );
    for (r, (bs, d, cfg, steps)) in plans.iter().enumerate() {
        bar.set_message(format!("b_s = {bs}, D = {d}"));
        let ts = Instant::now();
        let scene = scenes::build(cfg)?;
        let mut sim = build_sim::<f64>(cfg, &scene)?;
        never_fluid.push(sim.blocks.iter().map(|b| b.fluid_cells == 0).collect());
        let owners = assignment(cfg, &sim);
        let mut pipe = Pipeline::new(&sim, make_executor(cfg)?, owners, 1, u64::MAX);
        pipe.surface = cfg.particles.boundary;
        pipe.force_averaging = cfg.particles.force_averaging;
        pipe.block_times = Some(Vec::new());
        pipe.first_touch(&sim);
        let nb = sim.blocks.len();
        let t_unit = *steps as f64 / duration;
        if r == 0 {
            fig6 = (0..nb)
                .map(|b| plots::BlockSeries {
                    row: sim.domain.coords(b)[2],
                    points: Vec::new(),
                })
                .collect();
        }
        let mut kept = 0;
        for _ in 0..*steps {
            pipe.advance(&mut sim, 1)?;
            bar.inc(1);
            if sim.step <= WARMUP {
                continue;
            }
            let times = pipe.block_times.as_ref().expect("recording");
            for b in 0..nb {
                let q = quantities(&sim, b);
                let m = part_times(times, nb, 0, b);
                let row = sim.domain.coords(b)[2];
                let t_star = sim.step as f64 / t_unit;
                csv += &format!(
                    "{r},{bs},{d},{},{t_star:.6},{b},{row},{},{},{},{},{},{},{},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e}\n",
                    sim.step, q.c, q.f, q.nb, q.pl, q.ps, q.k, q.s, m.lbm, m.bh, m.coup1, m.coup2, m.rb
                );
                if let Some(series) = fig6.get_mut(b).filter(|_| r == 0) {
                    series.points.push((t_star, q.f, m.lbm));
                }
                samples.push(Sample {
                    run: r,
                    step: sim.step,
                    block: b,
                    q,
                    m,
                });
                kept += 1;
            }
        }
        runs.push(RunInfo {
            block_size: *bs,
            diameter: *d,
            steps: *steps,
            samples: kept,
            seconds: ts.elapsed().as_secs_f64(),
        });
    }
    bar.finish_and_clear();
    if samples.is_empty() {
        return Err(Error::Config(format!(
            "calibrate: no samples (every run is shorter than the {WARMUP}-step warm-up); raise scene.duration"
        )));
    }
    let path = o.out.join("samples.csv");
    std::fs::write(&path, csv).map_err(|e| io_err(&path, e))?;
    let prov = Provenance {
        machine: machine(),
        date: today(),
        commit: git_commit(),
        scenes: plans
            .iter()
            .map(|p| format!("{} with b_s = {}, D = {}", o.scene.display(), p.0, p.1))
            .collect(),
        samples: samples.len(),
        fit_quality: BTreeMap::new(),
        note: format!(
            "blockflow calibrate: {} runs, first {WARMUP} steps of each dropped, one sample per block per step",
            plans.len()
        ),
    };
    let mut coeffs = estimator::fit(&samples, prov.clone());
    let fluid_only: Vec<Sample> = samples
        .iter()
        .filter(|s| !never_fluid[s.run][s.block])
        .copied()
        .collect();
    let ev: Evaluation = estimator::evaluate(&coeffs, &samples);
    let ev_fluid = estimator::evaluate(&coeffs, &fluid_only);
    let multi_run = plans.len() > 1;
    let held = if multi_run {
        estimator::held_out(&samples, prov.clone())
    } else {
        f64::NAN
    };
    let held_fluid = if multi_run {
        estimator::held_out(&fluid_only, prov)
    } else {
        f64::NAN
    };
    let mut share = BTreeMap::new();
    share.insert("in_sample".to_string(), ev.share_within_10pct);
    share.insert("held_out".to_string(), held);
    share.insert("in_sample_fluid_blocks".to_string(), ev_fluid.share_within_10pct);
    share.insert("held_out_fluid_blocks".to_string(), held_fluid);
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
    // Figures 7 and 8: shares m_X / m_tot and errors E_X.
    let part_of = |m: &PartTimes, k: usize| [m.lbm, m.bh, m.coup1, m.coup2, m.rb][k];
    let mut shares = Vec::new();
    let mut errors = Vec::new();
    let mut share_median = BTreeMap::new();
    for (k, name) in estimator::PARTS.iter().enumerate() {
        let v: Vec<f64> = samples
            .iter()
            .filter(|s| s.m.total() > 0.0)
            .map(|s| part_of(&s.m, k) / s.m.total())
            .collect();
        share_median.insert(name.to_string(), estimator::median(&v));
        shares.push((name.to_string(), v));
        let e: Vec<f64> = samples
            .iter()
            .filter(|s| s.m.total() > 0.0)
            .map(|s| (part_of(&coeffs.predict(&s.q), k) - part_of(&s.m, k)) / s.m.total())
            .collect();
        errors.push((name.to_string(), e));
    }
    let etot: Vec<f64> = samples
        .iter()
        .filter(|s| s.m.total() > 0.0)
        .map(|s| (coeffs.total(&s.q) - s.m.total()) / s.m.total())
        .collect();
    errors.push(("total".to_string(), etot));
    plots::figure6(&o.out.join("figure6.png"), &fig6)?;
    plots::figure7(&o.out.join("figure7.png"), &shares)?;
    plots::figure8(&o.out.join("figure8.png"), &errors)?;
    let report = CalibrationReport {
        runs,
        samples: samples.len(),
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
