//! `intervals.csv`: one row per balancing interval of a run (modeled and measured times, load imbalance
//! measured and predicted, messages, edge cut, migration, balancing time, each process's load).

use crate::error::Result;
use crate::metrics::interval::IntervalStats;
use crate::util::fs::write_atomic;
use std::path::Path;

/// The CSV text of `intervals`.
pub fn to_csv(intervals: &[IntervalStats]) -> String {
    let procs = intervals.first().map_or(0, |i| i.process_load.len());
    let mut text = String::from(
        "interval,start,end,wall_seconds,modeled_seconds,bsp_seconds,imbalance,predicted_imbalance,message_bytes,\
         edge_cut_mean,migrated_blocks,migrated_bytes,balance_seconds",
    );
    for p in 0..procs {
        text += &format!(",load_p{p}");
    }
    text.push('\n');
    for (i, iv) in intervals.iter().enumerate() {
        text += &format!(
            "{i},{},{},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{},{:.6e},{},{},{:.6e}",
            iv.start,
            iv.end,
            iv.wall_seconds,
            iv.modeled_seconds,
            iv.bsp_seconds,
            iv.imbalance,
            iv.predicted_imbalance,
            iv.message_bytes,
            iv.edge_cut_mean,
            iv.migrated_blocks,
            iv.migrated_bytes,
            iv.balance_seconds
        );
        for l in &iv.process_load {
            text += &format!(",{l:.6e}");
        }
        text.push('\n');
    }
    text
}

/// Writes `intervals.csv` atomically.
pub fn write(path: &Path, intervals: &[IntervalStats]) -> Result<()> {
    write_atomic(path, to_csv(intervals).as_bytes())
}
