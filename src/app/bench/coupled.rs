//! `blockflow bench coupled [--quick] [--threads T] [--baseline BINARY [--baseline-set KEY=VALUE]...] [--out DIR]`: the cost structure
//! of the coupled step. Every particulate scene runs twice on the same blocks and geometry, with its
//! bodies and fluid-only (`particles.enabled = false`), and a periodic fluid box on two big blocks gives
//! the kernel's speed in the same run. Per run: MLUPS (fluid cells × steps / wall seconds), the LBM part's
//! MLUPS per core (fluid cells × steps / CPU seconds of the sweeps), and every part's share of the thread
//! time (P × T × wall seconds): LBM, boundary, exchange, map, reconstruct, rigid body, forces, and what no
//! task used (scheduling and idle), next to the shares of the paper's figure 7. With `--baseline`, the
//! coupled runs are repeated with another `blockflow` binary (its `run` command), side by side on the
//! same machine. With `--rounds N` every run of a scene is repeated N times, the order of a scene's runs
//! rotating from round to round, so that no run always goes first while the machine's speed drifts
//! (±10 % between runs on a 2-core VM); each row is then the run with the median MLUPS, and the MLUPS of
//! every round are listed beside it. Every run, this program's and the baseline's, is a `blockflow run`
//! in a process of its own.

use crate::app::run::{self, RunOptions};
use crate::config;
use crate::error::{Error, Result};
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// The shares of the paper's figure 7 for comparison (LBM ≈ 45 %, boundary ≈ 35 %, coupling and rigid
/// body below 5 % each).
pub const PAPER_SHARES: &str = "LBM ≈ 45 %, boundary ≈ 35 %, map + reconstruct < 5 %, rigid body < 5 %";

/// The parts a row reports, in column order, with the task kinds each sums.
const PARTS: [(&str, &[&str]); 7] = [
    ("lbm", &["sweep"]),
    ("boundary", &["boundary"]),
    ("exchange", &["send", "comm"]),
    ("map", &["map", "static_map"]),
    ("reconstruct", &["reconstruct"]),
    ("rigid_body", &["rb", "rb_sync"]),
    ("forces", &["forces"]),
];

/// One scene of the bench: a scene file with overrides and a step count.
#[derive(Clone, Debug)]
pub struct Case {
    /// Name in the table.
    pub name: &'static str,
    /// Scene file in `configs/`.
    pub file: &'static str,
    /// Overrides.
    pub sets: Vec<String>,
    /// Steps.
    pub steps: u64,
    /// Whether the scene has bodies (else it is the kernel's reference on big blocks).
    pub particulate: bool,
}

/// The scenes: hopper-small, the hopper, the calibration scene at b_s = 16 and 32, the settling sphere
/// (E4, D = 9) and the kernel on two big blocks; `quick` runs a few steps of three of them.
pub fn cases(quick: bool) -> Vec<Case> {
    let case = |name, file, sets: &[&str], steps, particulate| Case {
        name,
        file,
        sets: sets.iter().map(|s| s.to_string()).collect(),
        steps,
        particulate,
    };
    let kernel = case(
        "kernel, 2 blocks of 80x160x160",
        "taylor_green.toml",
        &["scene.resolution=160", "domain.blocks=[2,1,1]"],
        if quick { 3 } else { 20 },
        false,
    );
    if quick {
        return vec![
            case("hopper-small", "hopper-small.toml", &[], 40, true),
            case(
                "calibration b_s=16",
                "calibration.toml",
                &["domain.block_size=[16,16,16]"],
                20,
                true,
            ),
            case(
                "settling E4 D=6",
                "settling_sphere.toml",
                &["scene.case=\"E4\"", "scene.resolution=6"],
                60,
                true,
            ),
            kernel,
        ];
    }
    vec![
        case("hopper-small", "hopper-small.toml", &[], 600, true),
        case("hopper", "hopper.toml", &[], 150, true),
        case(
            "calibration b_s=16",
            "calibration.toml",
            &["domain.block_size=[16,16,16]"],
            300,
            true,
        ),
        case(
            "calibration b_s=32",
            "calibration.toml",
            &["domain.block_size=[32,32,32]", "scene.diameter=10"],
            60,
            true,
        ),
        case(
            "settling E4 D=9",
            "settling_sphere.toml",
            &["scene.case=\"E4\"", "scene.resolution=9"],
            1500,
            true,
        ),
        kernel,
    ]
}

/// What one run measured.
#[derive(Clone, Debug, Default)]
pub struct Row {
    /// Scene name.
    pub scene: String,
    /// `coupled`, `fluid-only`, `kernel` or `baseline` (the coupled run of `--baseline`).
    pub variant: String,
    /// Fluid cells.
    pub fluid_cells: u64,
    /// Steps run.
    pub steps: u64,
    /// Threads (P × T).
    pub threads: u64,
    /// Wall seconds of the time loop.
    pub wall_seconds: f64,
    /// Fluid cell updates per second / 1e6.
    pub mlups: f64,
    /// Fluid cell updates per CPU second of the LBM sweeps / 1e6 (the kernel's speed per core).
    pub lbm_mlups_per_core: f64,
    /// Share of the thread time per part of [`PARTS`], then the share no task used (last), in percent.
    pub shares: Vec<f64>,
    /// Fluid and particle checksums.
    pub checksums: (String, String),
    /// MLUPS of every round of this scene and run, in round order (the row is the median one's).
    pub rounds_mlups: Vec<f64>,
}

impl Row {
    /// The row of a run's `summary.json` (as a JSON value, so that another binary's summary reads too).
    fn of(scene: &str, variant: &str, s: &serde_json::Value) -> Result<Row> {
        let num = |k: &str| s[k].as_f64().unwrap_or(f64::NAN);
        let by_kind = s["tasks_cpu_seconds_by_kind"].as_object().cloned().unwrap_or_default();
        let cpu = |kinds: &[&str]| kinds.iter().filter_map(|k| by_kind.get(*k)?.as_f64()).sum::<f64>();
        let threads = (num("processes") * num("threads_per_process")) as u64;
        let wall = num("wall_seconds");
        let total = threads as f64 * wall;
        if total.is_nan() || total <= 0.0 {
            return Err(Error::Config(format!(
                "bench coupled: {scene} ({variant}) measured no time"
            )));
        }
        let mut shares: Vec<f64> = PARTS.iter().map(|(_, k)| 100.0 * cpu(k) / total).collect();
        shares.push(100.0 - shares.iter().sum::<f64>());
        let cells = num("fluid_cells");
        let steps = s["steps"].as_u64().unwrap_or(0) - s["restart_step"].as_u64().unwrap_or(0);
        let lbm = cpu(PARTS[0].1);
        Ok(Row {
            scene: scene.to_string(),
            variant: variant.to_string(),
            fluid_cells: cells as u64,
            steps,
            threads,
            wall_seconds: wall,
            mlups: num("mlups"),
            lbm_mlups_per_core: if lbm > 0.0 {
                cells * steps as f64 / lbm / 1e6
            } else {
                0.0
            },
            shares,
            checksums: (
                s["checksum"]["fluid"].as_str().unwrap_or("").to_string(),
                s["checksum"]["particles"].as_str().unwrap_or("-").to_string(),
            ),
            rounds_mlups: vec![num("mlups")],
        })
    }

    /// Share (percent of the thread time) of the part named `name` (or `idle`).
    pub fn share(&self, name: &str) -> f64 {
        match PARTS.iter().position(|(n, _)| *n == name) {
            Some(i) => self.shares[i],
            None if name == "idle" => self.shares[PARTS.len()],
            None => f64::NAN,
        }
    }
}

/// Options of `blockflow bench coupled`.
#[derive(Clone, Debug)]
pub struct CoupledOptions {
    /// The CI size.
    pub quick: bool,
    /// Threads of every run (one virtual process).
    pub threads: usize,
    /// Another `blockflow` binary whose `run` repeats the coupled runs.
    pub baseline: Option<PathBuf>,
    /// Overrides (`KEY=VALUE`) the baseline's runs get after the scene's own.
    pub baseline_sets: Vec<String>,
    /// Times every run is repeated, in an order that rotates from round to round (at least 1).
    pub rounds: usize,
    /// This program, to run each of its own runs in a fresh process as the baseline's are (`None`: in
    /// this process, as the unit test does). A run in a process that has already run others was up to
    /// 6 % slower here (the calibration scene at b_s = 32, every round), which biased the comparison
    /// with the baseline.
    pub program: Option<PathBuf>,
    /// Output folder.
    pub out: PathBuf,
    /// Folder of the scene files.
    pub configs: PathBuf,
}

fn sets_of(c: &Case, threads: usize, fluid_only: bool) -> Vec<String> {
    let mut sets = c.sets.clone();
    sets.push(format!("run.steps={}", c.steps));
    sets.push(format!("processes.threads_per_process={threads}"));
    if fluid_only {
        sets.push("particles.enabled=false".into());
    }
    sets
}

fn own_run(o: &CoupledOptions, c: &Case, fluid_only: bool, dir: &Path) -> Result<serde_json::Value> {
    if let Some(program) = &o.program {
        return child_run(program, &[], o, c, fluid_only, dir);
    }
    let cfg = config::load(&o.configs.join(c.file), &sets_of(c, o.threads, fluid_only))?;
    let opts = RunOptions {
        out: Some(dir.to_path_buf()),
        ..Default::default()
    };
    let s = run::run(&cfg, &opts)?;
    serde_json::to_value(&s).map_err(|e| Error::Io(format!("summary of {}: {e}", c.name)))
}

/// One run of `bin` (`blockflow run` with the case's overrides, then `extra`) in a process of its own; its
/// summary.
fn child_run(
    bin: &Path,
    extra: &[String],
    o: &CoupledOptions,
    c: &Case,
    fluid_only: bool,
    dir: &Path,
) -> Result<serde_json::Value> {
    let mut cmd = std::process::Command::new(bin);
    cmd.arg("run").arg(o.configs.join(c.file)).arg("--out").arg(dir);
    for s in sets_of(c, o.threads, fluid_only).iter().chain(extra) {
        cmd.arg("--set").arg(s);
    }
    let out = cmd
        .output()
        .map_err(|e| Error::Config(format!("bench coupled: cannot run {}: {e}", bin.display())))?;
    if !out.status.success() {
        return Err(Error::Config(format!(
            "bench coupled: {} failed on {}: {}",
            bin.display(),
            c.name,
            String::from_utf8_lossy(&out.stderr).trim()
        )));
    }
    let p = dir.join("summary.json");
    let text = std::fs::read_to_string(&p).map_err(|e| Error::Io(format!("{}: {e}", p.display())))?;
    serde_json::from_str(&text).map_err(|e| Error::Io(format!("{}: {e}", p.display())))
}

/// Runs the bench; writes `coupled.md` and `coupled.csv` into `o.out`.
pub fn run(o: &CoupledOptions) -> Result<Vec<Row>> {
    if o.threads == 0 {
        return Err(Error::Config("bench coupled: --threads must be at least 1".into()));
    }
    if o.rounds == 0 {
        return Err(Error::Config("bench coupled: --rounds must be at least 1".into()));
    }
    let mut rows = Vec::new();
    for c in cases(o.quick) {
        let dir = o.out.join(c.name.replace([' ', ',', '='], "_"));
        let variants: Vec<&str> = match (c.particulate, &o.baseline) {
            (false, _) => vec!["kernel"],
            (true, Some(_)) => vec!["baseline", "coupled", "fluid-only"],
            (true, None) => vec!["coupled", "fluid-only"],
        };
        let mut runs: Vec<Vec<Row>> = vec![Vec::new(); variants.len()];
        for round in 0..o.rounds {
            for k in 0..variants.len() {
                let v = (k + round) % variants.len();
                let mut at = if c.particulate {
                    dir.join(variants[v])
                } else {
                    dir.clone()
                };
                if o.rounds > 1 {
                    at = at.join(format!("round-{round}"));
                }
                let s = match (variants[v], &o.baseline) {
                    ("baseline", Some(bin)) => child_run(bin, &o.baseline_sets, o, &c, false, &at).map_err(|e| {
                        Error::Config(format!(
                            "{e} (an older baseline may need its own settings: --baseline-set KEY=VALUE, e.g. \
                             balance.coefficients=\"OLD.toml\")"
                        ))
                    })?,
                    (variant, _) => own_run(o, &c, variant == "fluid-only", &at)?,
                };
                runs[v].push(Row::of(c.name, variants[v], &s)?);
            }
        }
        rows.extend(runs.into_iter().map(median_run));
    }
    std::fs::create_dir_all(&o.out).map_err(|e| Error::Io(format!("{}: {e}", o.out.display())))?;
    for (name, text) in [("coupled.md", to_markdown(&rows)), ("coupled.csv", to_csv(&rows))] {
        let p = o.out.join(name);
        std::fs::write(&p, text).map_err(|e| Error::Io(format!("{}: {e}", p.display())))?;
    }
    Ok(rows)
}

/// The run with the median MLUPS of one scene and variant's rounds (the lower of the middle two for an
/// even count), with every round's MLUPS in round order.
fn median_run(rounds: Vec<Row>) -> Row {
    let all: Vec<f64> = rounds.iter().map(|r| r.mlups).collect();
    let mut order: Vec<usize> = (0..rounds.len()).collect();
    order.sort_by(|&a, &b| all[a].total_cmp(&all[b]));
    let mut row = rounds[order[(order.len() - 1) / 2]].clone();
    row.rounds_mlups = all;
    row
}

/// The ratios of a scene: coupled over fluid-only MLUPS, coupled over the kernel on big blocks, and the
/// baseline's coupled MLUPS over the coupled ones (the speed-up), where the rows exist.
pub fn ratios(rows: &[Row]) -> BTreeMap<String, (f64, f64, f64)> {
    let kernel = rows
        .iter()
        .find(|r| r.variant == "kernel")
        .map_or(f64::NAN, |r| r.mlups);
    let mut out = BTreeMap::new();
    for r in rows.iter().filter(|r| r.variant == "coupled") {
        let of = |v: &str| {
            rows.iter()
                .find(|x| x.scene == r.scene && x.variant == v)
                .map_or(f64::NAN, |x| x.mlups)
        };
        out.insert(
            r.scene.clone(),
            (r.mlups / of("fluid-only"), r.mlups / kernel, r.mlups / of("baseline")),
        );
    }
    out
}

/// The table as markdown.
pub fn to_markdown(rows: &[Row]) -> String {
    let mut s = String::from(
        "| scene | run | fluid cells | steps | threads | wall s | MLUPS | LBM MLUPS/core | LBM | boundary | exchange \
         | map | reconstruct | rigid body | forces | no task |\n|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for r in rows {
        let _ = write!(
            s,
            "| {} | {} | {} | {} | {} | {:.2} | {:.1} | {:.1} |",
            r.scene, r.variant, r.fluid_cells, r.steps, r.threads, r.wall_seconds, r.mlups, r.lbm_mlups_per_core
        );
        for &x in &r.shares {
            // Parts a run does not have measure 0; a rounding below 0.05 % prints as 0.0 %.
            let x = if x.abs() < 0.05 { 0.0 } else { x };
            let _ = write!(s, " {x:.1} % |");
        }
        s.push('\n');
    }
    if rows.iter().any(|r| r.rounds_mlups.len() > 1) {
        s += "\nMLUPS of every round (the rows above are the median runs):\n\n| scene | run | MLUPS by round |\n|---|---|---|\n";
        for r in rows {
            let all: Vec<String> = r.rounds_mlups.iter().map(|m| format!("{m:.1}")).collect();
            let _ = writeln!(s, "| {} | {} | {} |", r.scene, r.variant, all.join(" / "));
        }
    }
    s += "\n| scene | coupled / fluid-only | coupled / kernel on big blocks | coupled / baseline |\n|---|---:|---:|---:|\n";
    for (scene, (a, b, c)) in ratios(rows) {
        let f = |x: f64| {
            if x.is_finite() {
                format!("{x:.2}")
            } else {
                "–".to_string()
            }
        };
        let _ = writeln!(s, "| {scene} | {} | {} | {} |", f(a), f(b), f(c));
    }
    let _ = writeln!(
        s,
        "\nShares are of the thread time (threads × wall seconds); \"no task\" is scheduling and idle time. \
         Paper, figure 7: {PAPER_SHARES}."
    );
    s
}

/// The table as CSV.
pub fn to_csv(rows: &[Row]) -> String {
    let mut s = String::from("scene,run,fluid_cells,steps,threads,wall_seconds,mlups,lbm_mlups_per_core");
    for (p, _) in PARTS {
        let _ = write!(s, ",share_{p}");
    }
    s += ",share_no_task,checksum_fluid,checksum_particles,mlups_by_round\n";
    for r in rows {
        let _ = write!(
            s,
            "{},{},{},{},{},{:.6},{:.6},{:.6}",
            r.scene, r.variant, r.fluid_cells, r.steps, r.threads, r.wall_seconds, r.mlups, r.lbm_mlups_per_core
        );
        for x in &r.shares {
            let _ = write!(s, ",{x:.4}");
        }
        let all: Vec<String> = r.rounds_mlups.iter().map(|m| format!("{m:.6}")).collect();
        let _ = writeln!(s, ",{},{},{}", r.checksums.0, r.checksums.1, all.join(";"));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A scene's row over several rounds is the median run (the lower middle one for an even count),
    /// with every round's MLUPS kept in round order.
    #[test]
    fn rounds_keep_the_median_run_and_every_rounds_mlups() {
        let row = |mlups: f64, wall: f64| Row {
            mlups,
            wall_seconds: wall,
            rounds_mlups: vec![mlups],
            ..Default::default()
        };
        let m = median_run(vec![row(50.0, 2.0), row(40.0, 2.5), row(45.0, 2.2)]);
        assert_eq!((m.mlups, m.wall_seconds), (45.0, 2.2));
        assert_eq!(m.rounds_mlups, vec![50.0, 40.0, 45.0]);
        let m = median_run(vec![row(50.0, 2.0), row(40.0, 2.5)]);
        assert_eq!(m.mlups, 40.0);
        assert_eq!(median_run(vec![row(7.0, 1.0)]).rounds_mlups, vec![7.0]);
    }

    /// A baseline's runs get the case's overrides and then `--baseline-set`'s, last, so they win; its
    /// failure names the binary and the case and says how to give it its own settings. The baseline
    /// here is a script that prints its arguments and fails.
    #[cfg(unix)]
    #[test]
    fn baseline_gets_its_overrides_last_and_its_failure_is_one_line() {
        use std::os::unix::fs::PermissionsExt;
        let out = std::env::temp_dir().join(format!("blockflow-bench-baseline-{}", std::process::id()));
        std::fs::create_dir_all(&out).expect("temp dir");
        let script = out.join("old-blockflow");
        std::fs::write(&script, "#!/bin/sh\necho \"$@\" >&2\nexit 3\n").expect("script");
        std::fs::set_permissions(&script, std::fs::Permissions::from_mode(0o755)).expect("chmod");
        let o = CoupledOptions {
            quick: true,
            threads: 2,
            baseline: Some(script.clone()),
            baseline_sets: vec!["balance.coefficients=\"old.toml\"".into()],
            rounds: 1,
            program: None,
            out: out.clone(),
            configs: PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("configs"),
        };
        let e = run(&o).expect_err("the script fails").to_string();
        assert!(!e.contains('\n'), "{e}");
        assert!(
            e.contains(&format!("{} failed on hopper-small", script.display())),
            "{e}"
        );
        let args = e.split("hopper-small: ").nth(1).expect("the script's output");
        assert!(args.starts_with("run "), "{e}");
        assert!(
            args.contains("--set processes.threads_per_process=2 --set balance.coefficients=\"old.toml\" ("),
            "{e}"
        );
        assert!(e.contains("--baseline-set KEY=VALUE"), "{e}");
        std::fs::remove_dir_all(&out).ok();
    }

    /// The quick table as the CI runs it: every row's part times fit in its thread time, the two runs of
    /// a scene share their blocks and fluid cells, only the coupled run has coupling and rigid-body
    /// work, and MLUPS and the ratios follow from the measured times.
    #[test]
    fn quick_table_is_consistent() {
        let out = std::env::temp_dir().join(format!("blockflow-bench-coupled-{}", std::process::id()));
        let o = CoupledOptions {
            quick: true,
            threads: 2,
            baseline: None,
            baseline_sets: Vec::new(),
            rounds: 1,
            program: None,
            out: out.clone(),
            configs: PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("configs"),
        };
        let rows = run(&o).expect("quick bench");
        assert_eq!(rows.len(), 2 * 3 + 1, "three scenes twice and the kernel");
        for r in &rows {
            // Task CPU time never exceeds the thread time (a task's CPU time is at most its wall time).
            assert!(r.shares[..PARTS.len()].iter().all(|&s| s >= 0.0), "{r:?}");
            assert!(r.share("idle") > -0.5, "parts exceed the thread time: {r:?}");
            let mlups = r.fluid_cells as f64 * r.steps as f64 / r.wall_seconds / 1e6;
            assert!((r.mlups - mlups).abs() <= 1e-9 * mlups, "{r:?}");
            // The sweeps' CPU time is part of the thread time: per core at least the run's MLUPS / T.
            assert!(
                r.lbm_mlups_per_core >= r.mlups / r.threads as f64 * (1.0 - 1e-9),
                "{r:?}"
            );
            assert!(r.share("lbm") > 0.0 && r.share("exchange") > 0.0, "{r:?}");
        }
        for pair in rows.chunks(2).filter(|p| p.len() == 2 && p[0].variant == "coupled") {
            let (c, f) = (&pair[0], &pair[1]);
            assert_eq!((f.scene.as_str(), f.variant.as_str()), (c.scene.as_str(), "fluid-only"));
            assert_eq!(
                (c.fluid_cells, c.steps),
                (f.fluid_cells, f.steps),
                "same blocks and cells"
            );
            for part in ["map", "reconstruct", "rigid_body", "forces"] {
                assert_eq!(f.share(part), 0.0, "{part} in the fluid-only run of {}", f.scene);
                assert!(c.share(part) > 0.0, "no {part} in the coupled run of {}", c.scene);
            }
            assert_eq!(f.checksums.1, "-", "a fluid-only run has no particle checksum");
            assert_ne!(
                c.checksums.0, f.checksums.0,
                "the bodies change the fluid of {}",
                c.scene
            );
            let (to_fluid, _, _) = ratios(&rows)[&c.scene];
            assert!((to_fluid - c.mlups / f.mlups).abs() <= 1e-12 * to_fluid);
        }
        let table = std::fs::read_to_string(out.join("coupled.md")).expect("coupled.md");
        assert!(table.contains("| hopper-small | coupled |") && table.contains(PAPER_SHARES));
        let _ = std::fs::remove_dir_all(&out);
    }
}
