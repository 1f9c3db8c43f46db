//! `blockflow bench skip [--quick] [--out DIR]`: runs
//! channel, calibration, hopper-small and granular_box with the skip rules of DESIGN.md principle 2 and
//! with `run.no_skip` (every task on every block, see [`crate::pipeline`]), the same steps both ways,
//! alternating the order over the repeats and keeping the fastest run of each way. Per scene it reports
//! the tasks run per kind both ways, the work skipped per rule (outside blocks, blocks without boundary
//! cells, blocks without particles, static geometry mapped once, the fused kernel), the wall seconds both
//! ways, the time saved and whether the checksums (fluid and particles) are equal; `skip.csv` and
//! `skip.md` go to the output folder.

use crate::app::run::{self, RunOptions};
use crate::error::{Error, Result};
use crate::io::summary::Summary;
use crate::pipeline::kinds::TaskKind;
use crate::pipeline::SkipRule;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

/// Human names of the skip rules (index as [`SkipRule::ALL`]).
const RULE_LABELS: [&str; 5] = [
    "outside blocks (no fluid cell / no ghost region)",
    "blocks without boundary cells",
    "no particles (blocks no body reaches)",
    "static geometry mapped once",
    "fused kernel (sweeps on the general path)",
];

/// One scene of the bench.
struct Case {
    name: &'static str,
    file: &'static str,
    sets: &'static [&'static str],
    steps_quick: u64,
    steps_full: u64,
}

fn suite() -> Vec<Case> {
    vec![
        Case {
            name: "channel",
            file: "channel.toml",
            sets: &[],
            steps_quick: 2000,
            steps_full: 10000,
        },
        Case {
            name: "calibration",
            file: "calibration.toml",
            sets: &[],
            steps_quick: 20,
            steps_full: 60,
        },
        Case {
            name: "hopper-small",
            file: "hopper-small.toml",
            sets: &[],
            steps_quick: 40,
            steps_full: 150,
        },
        Case {
            name: "granular_box",
            file: "granular_box.toml",
            sets: &[],
            steps_quick: 100,
            steps_full: 400,
        },
    ]
}

/// One way of running a scene (with the skip rules or with `run.no_skip`).
#[derive(Clone, Debug, Default)]
pub struct SkipRun {
    /// Fastest wall-clock seconds of the time loop over the repeats.
    pub wall_seconds: f64,
    /// Tasks executed per kind over the run (every repeat runs the same tasks).
    pub tasks_by_kind: BTreeMap<String, u64>,
    /// Work done only because the skip rules were off, per rule (zero with the skip rules on).
    pub unskipped: BTreeMap<String, u64>,
    /// CPU seconds per task kind (of the fastest repeat).
    pub cpu_by_kind: BTreeMap<String, f64>,
    /// CPU seconds of the work in `unskipped`, per rule (of the fastest repeat).
    pub unskipped_cpu: BTreeMap<String, f64>,
    /// Fluid checksum (hex) of the final state.
    pub fluid_checksum: String,
    /// Particle checksum (hex) of the final state (`-` without bodies).
    pub particle_checksum: String,
    /// Whether every repeat ended with the same checksums.
    pub repeats_agree: bool,
    /// Fluid sweeps over the run.
    pub sweeps: u64,
    /// Whether the scene has bodies.
    pub particles: bool,
}

/// One scene's result.
#[derive(Clone, Debug)]
pub struct SkipScene {
    /// Scene name.
    pub name: String,
    /// Steps run each way.
    pub steps: u64,
    /// Repeats each way.
    pub repeats: usize,
    /// With the skip rules (the default).
    pub skip: SkipRun,
    /// With `run.no_skip`.
    pub no_skip: SkipRun,
}

impl SkipScene {
    /// Whether both ways (and every repeat) ended with bitwise the same fluid and particle checksums.
    pub fn checksums_equal(&self) -> bool {
        self.skip.repeats_agree
            && self.no_skip.repeats_agree
            && self.skip.fluid_checksum == self.no_skip.fluid_checksum
            && self.skip.particle_checksum == self.no_skip.particle_checksum
    }

    /// Task CPU seconds (thread CPU time of every task, summed) both ways: less sensitive than the wall
    /// time to other load on the machine.
    pub fn task_cpu(&self) -> (f64, f64) {
        (
            self.skip.cpu_by_kind.values().sum(),
            self.no_skip.cpu_by_kind.values().sum(),
        )
    }

    /// Seconds saved by the skip rules (no-skip minus skip) and the share of the no-skip time.
    pub fn saved(&self) -> (f64, f64) {
        let s = self.no_skip.wall_seconds - self.skip.wall_seconds;
        (s, 100.0 * s / self.no_skip.wall_seconds.max(1e-12))
    }

    /// CPU seconds saved per rule (index as [`SkipRule::ALL`]; `None` where the rule does not apply): the
    /// CPU time of the tasks the rule removes, and for `fused_kernel` the general-path sweeps' time
    /// minus the fused sweeps' time.
    pub fn cpu_saved(&self) -> [Option<f64>; 5] {
        let applies = self.skipped();
        std::array::from_fn(|r| {
            applies[r]?;
            let rule = SkipRule::ALL[r];
            let c = self.no_skip.unskipped_cpu.get(rule.name()).copied().unwrap_or(0.0);
            Some(if rule == SkipRule::FusedKernel {
                c - self
                    .skip
                    .cpu_by_kind
                    .get(TaskKind::Sweep.name())
                    .copied()
                    .unwrap_or(0.0)
            } else {
                c
            })
        })
    }

    /// Work skipped per rule (index as [`SkipRule::ALL`]); `None` where the rule does not apply to the
    /// scene (no bodies: nothing to map or move; no fluid sweep: no kernel to choose).
    pub fn skipped(&self) -> [Option<u64>; 5] {
        std::array::from_fn(|r| {
            let rule = SkipRule::ALL[r];
            let applies = match rule {
                SkipRule::NoParticles => self.skip.particles,
                SkipRule::FusedKernel => self.skip.sweeps > 0,
                _ => true,
            };
            applies.then(|| self.no_skip.unskipped.get(rule.name()).copied().unwrap_or(0))
        })
    }
}

fn one_run(configs: &Path, c: &Case, steps: u64, no_skip: bool, out: &Path) -> Result<Summary> {
    let mut sets: Vec<String> = c.sets.iter().map(|s| s.to_string()).collect();
    sets.push(format!("run.steps={steps}"));
    sets.push(format!("run.no_skip={no_skip}"));
    let cfg = crate::config::load(&configs.join(c.file), &sets)?;
    let opts = RunOptions {
        out: Some(out.to_path_buf()),
        ..Default::default()
    };
    run::run(&cfg, &opts)
}

fn particle_checksum(s: &Summary) -> String {
    s.checksum.particles.clone().unwrap_or_else(|| "-".to_string())
}

fn absorb(run: &mut SkipRun, s: &Summary, first: bool) {
    if first || s.wall_seconds < run.wall_seconds {
        run.cpu_by_kind = s.tasks_cpu_seconds_by_kind.clone();
        run.unskipped_cpu = s.unskipped_cpu_seconds_by_rule.clone().unwrap_or_default();
    }
    if first {
        run.wall_seconds = s.wall_seconds;
        run.tasks_by_kind = s.tasks_by_kind.clone();
        run.unskipped = s.unskipped_by_rule.clone().unwrap_or_default();
        run.fluid_checksum = s.checksum.fluid.clone();
        run.particle_checksum = particle_checksum(s);
        run.repeats_agree = true;
        run.sweeps = s.tasks_by_kind.get("sweep").copied().unwrap_or(0);
        run.particles = s.particles.is_some();
    } else {
        run.wall_seconds = run.wall_seconds.min(s.wall_seconds);
        run.repeats_agree &= run.fluid_checksum == s.checksum.fluid && run.particle_checksum == particle_checksum(s);
    }
}

/// Runs the four scenes both ways into `out/<scene>/`; `configs` is the folder holding the scene files.
pub fn run(quick: bool, out: &Path, configs: &Path) -> Result<Vec<SkipScene>> {
    let repeats = if quick { 3 } else { 5 };
    let mut res = Vec::new();
    for c in suite() {
        let steps = if quick { c.steps_quick } else { c.steps_full };
        let mut skip = SkipRun::default();
        let mut no_skip = SkipRun::default();
        for r in 0..repeats {
            // Alternate which way goes first, so drift of the machine's speed hits both alike.
            let order = if r % 2 == 0 { [false, true] } else { [true, false] };
            for ns in order {
                let dir = out.join(c.name).join(if ns { "no-skip" } else { "skip" });
                let s = one_run(configs, &c, steps, ns, &dir)?;
                if s.status != "ok" {
                    return Err(Error::Config(format!(
                        "bench skip: {} ended with status {}",
                        c.name, s.status
                    )));
                }
                absorb(if ns { &mut no_skip } else { &mut skip }, &s, r == 0);
            }
        }
        res.push(SkipScene {
            name: c.name.to_string(),
            steps,
            repeats,
            skip,
            no_skip,
        });
    }
    let md = to_markdown(&res);
    let csv = to_csv(&res);
    std::fs::create_dir_all(out).map_err(|e| Error::Io(format!("{}: {e}", out.display())))?;
    for (name, text) in [("skip.md", md), ("skip.csv", csv)] {
        let p = out.join(name);
        std::fs::write(&p, text).map_err(|e| Error::Io(format!("{}: {e}", p.display())))?;
    }
    Ok(res)
}

fn fmt_opt(v: Option<u64>) -> String {
    v.map_or_else(|| "n/a".to_string(), |n| n.to_string())
}

/// Per scene: tasks per kind both ways, work skipped per rule, wall time both ways and saved, checksums;
/// then one overview line per scene.
pub fn to_markdown(scenes: &[SkipScene]) -> String {
    let mut s = String::new();
    for sc in scenes {
        let _ = writeln!(
            s,
            "### {} ({} steps each way, fastest of {})\n",
            sc.name, sc.steps, sc.repeats
        );
        s += "| task kind | with skip rules | --no-skip | extra |\n|---|---:|---:|---:|\n";
        let (mut a_tot, mut b_tot) = (0u64, 0u64);
        for k in TaskKind::ALL.map(TaskKind::name) {
            let a = sc.skip.tasks_by_kind.get(k).copied().unwrap_or(0);
            let b = sc.no_skip.tasks_by_kind.get(k).copied().unwrap_or(0);
            if a == 0 && b == 0 {
                continue;
            }
            a_tot += a;
            b_tot += b;
            let _ = writeln!(s, "| {k} | {a} | {b} | {} |", b as i64 - a as i64);
        }
        let _ = writeln!(s, "| **all** | {a_tot} | {b_tot} | {} |\n", b_tot as i64 - a_tot as i64);
        s += "| skip rule | work skipped (tasks; sweeps for the kernel) | CPU s saved |\n|---|---:|---:|\n";
        for ((label, v), c) in RULE_LABELS.iter().zip(sc.skipped()).zip(sc.cpu_saved()) {
            let c = c.map_or_else(|| "n/a".to_string(), |c| format!("{c:.3}"));
            let _ = writeln!(s, "| {label} | {} | {c} |", fmt_opt(v));
        }
        let (saved, pct) = sc.saved();
        let (ca, cb) = sc.task_cpu();
        let _ = writeln!(
            s,
            "\nwall: {:.3} s with skip rules, {:.3} s with --no-skip; saved {:.3} s ({:.1} %); task CPU {:.3} s and \
             {:.3} s, saved {:.3} s ({:.1} %); checksums equal: {} (fluid {}, particles {})\n",
            sc.skip.wall_seconds,
            sc.no_skip.wall_seconds,
            saved,
            pct,
            ca,
            cb,
            cb - ca,
            100.0 * (cb - ca) / cb.max(1e-12),
            if sc.checksums_equal() { "yes" } else { "NO" },
            sc.skip.fluid_checksum,
            sc.skip.particle_checksum
        );
    }
    s += "### Overview\n\n| scene | steps | tasks skip | tasks no-skip | outside | no boundary | no particles | static map \
          | fused kernel | wall skip s | wall no-skip s | saved s | saved % | task CPU saved s | task CPU saved % \
          | checksums equal |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|\n";
    for sc in scenes {
        let sum = |r: &SkipRun| r.tasks_by_kind.values().sum::<u64>();
        let k = sc.skipped();
        let (saved, pct) = sc.saved();
        let (ca, cb) = sc.task_cpu();
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {:.3} | {:.3} | {:.3} | {:.1} | {:.3} | {:.1} | {} |",
            sc.name,
            sc.steps,
            sum(&sc.skip),
            sum(&sc.no_skip),
            fmt_opt(k[0]),
            fmt_opt(k[1]),
            fmt_opt(k[2]),
            fmt_opt(k[3]),
            fmt_opt(k[4]),
            sc.skip.wall_seconds,
            sc.no_skip.wall_seconds,
            saved,
            pct,
            cb - ca,
            100.0 * (cb - ca) / cb.max(1e-12),
            if sc.checksums_equal() { "yes" } else { "NO" }
        );
    }
    s += "\nn/a: the rule does not apply (no bodies: nothing to map or move; no fluid: no kernel to choose). \
          The fused kernel is the configured kernel of every block (fluid.kernel), not only of obstacle-free \
          blocks; --no-skip sweeps with runs found cell by cell and the split kernels. Fixed bodies (mapped \
          once at set-up) are not re-mapped by --no-skip; none of these scenes has any.\n";
    s
}

/// One row per scene: steps, wall seconds both ways, saved, checksums, work skipped and CPU seconds saved
/// per rule (empty: n/a), tasks per kind both ways.
pub fn to_csv(scenes: &[SkipScene]) -> String {
    let mut s = String::from(
        "scene,steps,repeats,wall_skip_s,wall_no_skip_s,saved_s,saved_pct,task_cpu_skip_s,task_cpu_no_skip_s,\
         checksums_equal",
    );
    for r in SkipRule::ALL.map(SkipRule::name) {
        let _ = write!(s, ",skipped_{r}");
    }
    for r in SkipRule::ALL.map(SkipRule::name) {
        let _ = write!(s, ",cpu_saved_s_{r}");
    }
    for k in TaskKind::ALL.map(TaskKind::name) {
        let _ = write!(s, ",tasks_{k}_skip,tasks_{k}_no_skip");
    }
    s.push('\n');
    for sc in scenes {
        let (saved, pct) = sc.saved();
        let (ca, cb) = sc.task_cpu();
        let _ = write!(
            s,
            "{},{},{},{:.6},{:.6},{:.6},{:.3},{:.6},{:.6},{}",
            sc.name,
            sc.steps,
            sc.repeats,
            sc.skip.wall_seconds,
            sc.no_skip.wall_seconds,
            saved,
            pct,
            ca,
            cb,
            sc.checksums_equal()
        );
        for v in sc.skipped() {
            let _ = write!(s, ",{}", v.map_or_else(String::new, |n| n.to_string()));
        }
        for v in sc.cpu_saved() {
            let _ = write!(s, ",{}", v.map_or_else(String::new, |c| format!("{c:.6}")));
        }
        for k in TaskKind::ALL.map(TaskKind::name) {
            let a = sc.skip.tasks_by_kind.get(k).copied().unwrap_or(0);
            let b = sc.no_skip.tasks_by_kind.get(k).copied().unwrap_or(0);
            let _ = write!(s, ",{a},{b}");
        }
        s.push('\n');
    }
    s
}
