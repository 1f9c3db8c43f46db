//! `report.md`: a run's result as a page to read on a git host or in an editor's preview: the headline
//! table, the figures, the time per part, the observables, the files and the commands that reproduce it.

use crate::error::Result;
use crate::io::summary::Summary;
use crate::util::fs::write_atomic;
use std::path::Path;

/// The files a run folder may hold, with what each is, in the order a reader wants them.
const FILES: [(&str, &str); 12] = [
    ("balance.png", "load imbalance per interval and each process's workload"),
    ("parts.png", "time per part of the step per interval"),
    (
        "slices.gif",
        "the pictured plane at every picture step, animated (with --png)",
    ),
    ("slices", "the pictured plane as one PNG per picture step (with --png)"),
    ("summary.json", "every number of this page and more (machine-readable)"),
    (
        "intervals.csv",
        "one row per balancing interval: times, imbalance, migration, loads",
    ),
    ("series.csv", "mass, kinetic energy and peak velocity over time"),
    (
        "particles.csv",
        "bodies, kinetic energy, peak speed and contacts over time",
    ),
    ("trajectory_si.csv", "the tracked body in SI units"),
    ("fluid.pvd", "VTK fluid fields for ParaView (with --vtk)"),
    ("particles.pvd", "VTK spheres for ParaView (with --vtk)"),
    (
        "effective.toml",
        "the configuration that ran, complete: `blockflow run` reproduces the run from it",
    ),
];

/// Writes `dir/report.md` for the finished run `s`; `command` is the command line that ran it.
pub fn write(dir: &Path, s: &Summary, command: &str) -> Result<()> {
    write_atomic(&dir.join("report.md"), text(dir, s, command).as_bytes())
}

/// The text of `report.md`.
fn text(dir: &Path, s: &Summary, command: &str) -> String {
    let mut t = format!("# blockflow run: {}\n\n{}\n\n", s.scene, s.description);
    t += "| | |\n|---|---|\n";
    let row = |t: &mut String, k: &str, v: String| *t += &format!("| {k} | {v} |\n");
    row(&mut t, "status", s.status.clone());
    row(&mut t, "steps", s.steps.to_string());
    row(
        &mut t,
        "blocks",
        format!(
            "{} ({} × {} × {}) of {} × {} × {} cells; {} fluid cells",
            s.blocks,
            s.block_grid[0],
            s.block_grid[1],
            s.block_grid[2],
            s.block_size[0],
            s.block_size[1],
            s.block_size[2],
            s.fluid_cells
        ),
    );
    row(
        &mut t,
        "processes × threads",
        format!("{} × {}", s.processes, s.threads_per_process),
    );
    row(
        &mut t,
        "wall time",
        format!("{:.2} s, {:.1} MLUPS ({})", s.wall_seconds, s.mlups, s.precision),
    );
    if let Some(b) = &s.balance {
        if b.imbalance.len() > 1 && s.processes > 1 {
            let after = crate::util::stats::median(&b.imbalance[1..]);
            row(
                &mut t,
                "load imbalance eq. (18)",
                format!(
                    "{:.0} % in the first interval, median {:.0} % after it ({}, every {} steps)",
                    100.0 * b.imbalance[0],
                    100.0 * after,
                    b.strategy,
                    b.interval
                ),
            );
        }
        if b.migrated_blocks > 0 {
            row(
                &mut t,
                "migrated",
                format!(
                    "{} blocks, {:.1} MB, {:.3} s of balancing",
                    b.migrated_blocks,
                    b.migrated_bytes as f64 / 1e6,
                    b.balance_seconds
                ),
            );
        }
    }
    let sums = match &s.checksum.particles {
        Some(p) => format!("fluid `{}`, particles `{p}`", s.checksum.fluid),
        None => format!("fluid `{}`", s.checksum.fluid),
    };
    row(&mut t, "checksums", sums);
    t += "\n";
    for (file, title) in [
        ("balance.png", "Load balance"),
        ("parts.png", "Time per part"),
        ("slices.gif", "The flow"),
    ] {
        if dir.join(file).exists() {
            t += &format!("## {title}\n\n![{title}]({file})\n\n");
        }
    }
    t += "## Task CPU time per part\n\n| part | seconds | share |\n|---|---:|---:|\n";
    let total: f64 = s.tasks_cpu_seconds_by_kind.values().sum();
    for (name, v) in s.parts_seconds.labelled() {
        if let Some(v) = v {
            let share = if total > 0.0 { 100.0 * v / total } else { 0.0 };
            t += &format!("| {name} | {v:.3} | {share:.1} % |\n");
        }
    }
    t += &format!("| all tasks | {total:.3} | |\n\n");
    if !s.observables.is_empty() {
        t += "## Observables\n\n| observable | value |\n|---|---:|\n";
        for (k, v) in &s.observables {
            t += &format!("| {k} | {v:.6e} |\n");
        }
        t += "\n";
    }
    t += "## Files\n\n";
    for (file, what) in FILES {
        if dir.join(file).exists() {
            t += &format!("- [`{file}`]({file}): {what}\n");
        }
    }
    t += &format!(
        "\n## Reproduce\n\n```sh\n{command}\nblockflow run {}   # the same run from the recorded configuration\n```\n",
        dir.join("effective.toml").display()
    );
    t
}
