//! The few lines `blockflow run` prints when it ends: what ran and how fast, the load imbalance per
//! interval and what rebalancing moved, where the time went, and which files to open.

use crate::config::{Config, Weights};
use crate::io::summary::Summary;
use std::path::Path;

/// Intervals listed one by one; longer runs show the first and last ones around an ellipsis.
const LISTED_INTERVALS: usize = 12;

/// The closing lines of a run: the headline (scene, steps, cells, threads, wall time, MLUPS), the load
/// imbalance eq. (18) per interval with its medians before and after the first rebalance, the migrated
/// blocks, each part's share of the task CPU time, the observables, the checksums and the files.
pub fn recap(s: &Summary, cfg: &Config, dir: &Path) -> String {
    let layout = if s.ranks > 1 {
        format!("{} ranks x {} threads", s.ranks, s.threads_per_process)
    } else {
        format!("{} x {} threads", s.processes, s.threads_per_process)
    };
    let mut text = format!(
        "{}: {} steps, {} fluid cells in {} blocks, {layout}, {:.2} s, {:.1} MLUPS ({}, {} streaming, \
         PDFs {:.1} MB)\n",
        s.scene,
        s.steps,
        s.fluid_cells,
        s.blocks,
        s.wall_seconds,
        s.mlups,
        s.precision,
        s.streaming,
        s.pdf_bytes as f64 / 1e6
    );
    if let Some(line) = imbalance_line(s, cfg) {
        text += &line;
    }
    if let Some(b) = s.balance.as_ref().filter(|b| b.migrated_blocks > 0) {
        text += &format!(
            "  migrated {} blocks ({:.1} MB) in {:.3} s of balancing steps ({:.2} % of the run)\n",
            b.migrated_blocks,
            b.migrated_bytes as f64 / 1e6,
            b.balance_seconds,
            100.0 * b.balance_seconds / s.wall_seconds.max(f64::MIN_POSITIVE)
        );
    }
    text += &parts_line(s);
    for (k, v) in &s.observables {
        text += &format!("  {k} = {v:.6e}\n");
    }
    let sum = match &s.checksum.particles {
        Some(p) => format!("checksums fluid {} particles {p}", s.checksum.fluid),
        None => format!("checksum {}", s.checksum.fluid),
    };
    text += &format!("  {sum}; results in {}\n", dir.display());
    let pictures: Vec<&str> = ["balance.png", "parts.png", "slices.gif"]
        .into_iter()
        .filter(|f| dir.join(f).exists())
        .collect();
    if dir.join("report.md").exists() || !pictures.is_empty() {
        let also = if pictures.is_empty() {
            String::new()
        } else {
            format!(", then {}", pictures.join(", "))
        };
        text += &format!("  open {} first{also}\n", dir.join("report.md").display());
    }
    text
}

/// "load imbalance per interval ...": only for runs of several processes and intervals.
fn imbalance_line(s: &Summary, cfg: &Config) -> Option<String> {
    let b = s.balance.as_ref()?;
    if s.processes < 2 || b.imbalance.len() < 2 {
        return None;
    }
    let pct = |v: f64| format!("{:.0} %", 100.0 * v);
    let n = b.imbalance.len();
    let listed: Vec<String> = if n <= LISTED_INTERVALS {
        b.imbalance.iter().map(|&v| pct(v)).collect()
    } else {
        let head = b.imbalance[..LISTED_INTERVALS - 3].iter().map(|&v| pct(v));
        let tail = b.imbalance[n - 2..].iter().map(|&v| pct(v));
        head.chain(std::iter::once("…".to_string())).chain(tail).collect()
    };
    let rebalancing = cfg.balance.strategy != crate::config::Strategy::None;
    let how = if rebalancing {
        format!(
            "{}, {} weights, every {} steps",
            strategy_name(cfg),
            weights_name(cfg.balance.weights),
            b.interval
        )
    } else {
        "static assignment".to_string()
    };
    let mut line = format!(
        "  load imbalance eq. (18) per interval ({how}): {}\n",
        listed.join(", ")
    );
    if rebalancing {
        let after = crate::util::stats::median(&b.imbalance[1..]);
        line += &format!(
            "    first interval {} (the initial assignment), median {} after the first rebalance\n",
            pct(b.imbalance[0]),
            pct(after)
        );
    }
    Some(line)
}

/// "time per part ...": each part's share of the task CPU time.
fn parts_line(s: &Summary) -> String {
    let parts = s.parts_seconds.labelled();
    let total: f64 = s.tasks_cpu_seconds_by_kind.values().sum();
    if total <= 0.0 {
        return String::new();
    }
    let shown: Vec<String> = parts
        .iter()
        .filter_map(|(name, v)| v.map(|v| format!("{name} {:.0} %", 100.0 * v / total)))
        .collect();
    format!("  task CPU time {:.2} s: {}\n", total, shown.join(", "))
}

/// The name of `balance.strategy` as the config file spells it.
fn strategy_name(cfg: &Config) -> String {
    format!("{:?}", cfg.balance.strategy).to_lowercase()
}

/// The name of `balance.weights` as the config file spells it.
fn weights_name(w: Weights) -> &'static str {
    match w {
        Weights::Cells => "cells",
        Weights::Estimator => "estimator",
        Weights::Measured => "measured",
        Weights::Corrected => "corrected",
        Weights::Uniform => "uniform",
    }
}
