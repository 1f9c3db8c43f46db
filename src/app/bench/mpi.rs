//! `blockflow bench mpi [--quick] [--max N] [--steps S] [--out DIR]`: hopper-small on N = 1 … max
//! ranks of an MPI job (`mpirun -np N` of this binary; in a build without MPI, or without `mpirun`, the
//! in-process ranks of `--ranks N`) against the same scene on N virtual processes: time per step,
//! MLUPS, the messages between ranks per step and their bytes per rank pair, and for the virtual processes
//! the time the recorded task graph models on N dedicated cores. On a machine with fewer cores than
//! ranks this shows the ranks' overhead, not a speed-up.

use crate::error::{Error, Result};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;

/// One run of the bench.
#[derive(Clone, Debug)]
pub struct Row {
    /// Ranks or processes.
    pub n: usize,
    /// `"mpi ranks"`, `"in-process ranks"` or `"virtual processes"`.
    pub mode: String,
    /// Steps.
    pub steps: u64,
    /// Wall seconds of the time loop.
    pub wall: f64,
    /// MLUPS.
    pub mlups: f64,
    /// Messages between ranks (or processes) per step.
    pub messages: f64,
    /// Their bytes per step.
    pub bytes: f64,
    /// Modeled seconds per step (virtual processes).
    pub modeled: Option<f64>,
    /// Bytes per step from each rank (row) to each rank (ranks).
    pub pairs: Option<Vec<Vec<f64>>>,
    /// The fluid checksum.
    pub checksum: String,
}

/// How the ranks of the bench are started.
fn launcher() -> (&'static str, bool) {
    let mpirun = Command::new("mpirun")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    if cfg!(feature = "mpi") && mpirun {
        ("mpi ranks", true)
    } else {
        ("in-process ranks", false)
    }
}

fn summary(dir: &Path) -> Result<serde_json::Value> {
    let p = dir.join("summary.json");
    let text = std::fs::read_to_string(&p).map_err(|e| crate::error::io_err(&p, e))?;
    serde_json::from_str(&text).map_err(|e| Error::Io(format!("{}: {e}", p.display())))
}

fn run(cmd: &mut Command, out: &Path) -> Result<serde_json::Value> {
    let o = cmd
        .output()
        .map_err(|e| Error::Io(format!("bench mpi: {cmd:?}: {e}")))?;
    if !o.status.success() {
        return Err(Error::Io(format!(
            "bench mpi: {cmd:?} failed: {}",
            String::from_utf8_lossy(&o.stderr)
                .lines()
                .find(|l| l.starts_with("error"))
                .unwrap_or("")
        )));
    }
    summary(out)
}

/// Runs the bench (`max` ranks at most, `steps` steps each) into `out`.
pub fn bench(max: usize, steps: u64, out: &Path, configs: &Path) -> Result<Vec<Row>> {
    let exe = std::env::current_exe().map_err(|e| Error::Io(format!("bench mpi: this program's path: {e}")))?;
    let scene = configs.join("hopper-small.toml");
    // More ranks than blocks would hold nothing (and start as many processes under mpirun).
    let cfg = crate::config::load(&scene, &[])?;
    let blocks = crate::scenes::domain_for(&cfg.domain, &crate::scenes::build(&cfg)?)?.num_blocks();
    if max > blocks {
        return Err(Error::Config(format!(
            "bench mpi: --max {max}: at most {blocks}, the blocks of {}: more ranks would hold none",
            scene.display()
        )));
    }
    let (mode, mpi) = launcher();
    let mut rows = Vec::new();
    for n in 1..=max {
        let steps_s = steps.to_string();
        let base = |dir: &PathBuf| -> Vec<String> {
            vec![
                "run".into(),
                scene.display().to_string(),
                "--steps".into(),
                steps_s.clone(),
                "--balance".into(),
                "none".into(),
                "--out".into(),
                dir.display().to_string(),
            ]
        };
        let dir = out.join(format!("processes-{n}"));
        let mut c = Command::new(&exe);
        c.args(base(&dir)).args(["--processes", &n.to_string()]);
        let s = run(&mut c, &dir)?;
        rows.push(row(n, "virtual processes", &s, false));
        let dir = out.join(format!("ranks-{n}"));
        let mut c = if mpi {
            let mut c = Command::new("mpirun");
            c.args(blockflow_scheduler::transport::MPIRUN_SMALL_MACHINE)
                .arg("-np")
                .arg(n.to_string())
                .arg(&exe)
                .args(base(&dir));
            c
        } else {
            let mut c = Command::new(&exe);
            c.args(base(&dir)).args(["--ranks", &n.to_string()]);
            c
        };
        let s = run(&mut c, &dir)?;
        rows.push(row(n, mode, &s, true));
    }
    Ok(rows)
}

fn row(n: usize, mode: &str, s: &serde_json::Value, ranks: bool) -> Row {
    let steps = s["steps"].as_u64().unwrap_or(0).max(1);
    let per = |x: f64| x / steps as f64;
    let (messages, bytes) = if ranks {
        s["rank_messages"].as_object().map_or((0.0, 0.0), |m| {
            m.values().fold((0.0, 0.0), |(a, b), v| {
                (
                    a + v["messages"].as_f64().unwrap_or(0.0),
                    b + v["bytes"].as_f64().unwrap_or(0.0),
                )
            })
        })
    } else {
        (
            s["balance"]["remote_messages"].as_f64().unwrap_or(0.0),
            s["balance"]["message_bytes"].as_f64().unwrap_or(0.0),
        )
    };
    Row {
        n,
        mode: mode.to_string(),
        steps,
        wall: s["wall_seconds"].as_f64().unwrap_or(0.0),
        mlups: s["mlups"].as_f64().unwrap_or(0.0),
        messages: per(messages),
        bytes: per(bytes),
        modeled: (!ranks).then(|| per(s["balance"]["modeled_seconds"].as_f64().unwrap_or(0.0))),
        pairs: s["rank_pair_bytes"].as_array().map(|rows| {
            rows.iter()
                .map(|r| {
                    r.as_array().map_or(Vec::new(), |v| {
                        v.iter().map(|x| per(x.as_f64().unwrap_or(0.0))).collect()
                    })
                })
                .collect()
        }),
        checksum: s["checksum"]["fluid"].as_str().unwrap_or("").to_string(),
    }
}

/// The table of the rows, then the bytes per rank pair of every ranks row.
pub fn to_markdown(rows: &[Row]) -> String {
    let mut t = String::from(
        "hopper-small (96 blocks of 12³, 60 spheres), no rebalancing; messages: between processes (ghost regions) or \
         ranks (everything)\n\n| N | mode | ms per step | MLUPS | messages per step | kB per step | modeled ms per step | checksum |\n\
         |---:|---|---:|---:|---:|---:|---:|---|\n",
    );
    for r in rows {
        let _ = writeln!(
            t,
            "| {} | {} | {:.2} | {:.1} | {:.0} | {:.1} | {} | {} |",
            r.n,
            r.mode,
            1e3 * r.wall / r.steps as f64,
            r.mlups,
            r.messages,
            r.bytes / 1e3,
            r.modeled.map_or("–".into(), |m| format!("{:.2}", 1e3 * m)),
            r.checksum
        );
    }
    for r in rows.iter().filter(|r| r.pairs.as_ref().is_some_and(|p| !p.is_empty())) {
        let _ = writeln!(
            t,
            "\n{} {}: kB per step from rank (row) to rank (column)\n",
            r.n, r.mode
        );
        let p = r.pairs.as_ref().expect("filtered");
        let _ = writeln!(
            t,
            "| from \\ to |{}",
            (0..p.len()).map(|j| format!(" {j} |")).collect::<String>()
        );
        let _ = writeln!(t, "|---:|{}", "---:|".repeat(p.len()));
        for (i, row) in p.iter().enumerate() {
            let cells: String = row.iter().map(|b| format!(" {:.1} |", b / 1e3)).collect();
            let _ = writeln!(t, "| {i} |{cells}");
        }
    }
    t
}
