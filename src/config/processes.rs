//! `[processes]`: virtual processes (thread groups standing in for MPI ranks), pinning and stealing.

use crate::error::{config_err, Result};
use serde::{Deserialize, Serialize};

/// `processes.pin`: a policy name or an explicit core list.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq, Eq)]
#[serde(untagged)]
pub enum PinConfig {
    /// `"compact"`, `"scatter"` or `"none"` (or a list written as a string, `"0,2,4-7"`).
    Name(String),
    /// Explicit cores, one per worker thread in process-major order.
    Cores(Vec<usize>),
}

impl Default for PinConfig {
    fn default() -> Self {
        PinConfig::Name("none".into())
    }
}

/// `processes.steal`: where idle threads may take ready tasks from.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum StealConfig {
    /// Only inside their own virtual process (MPI-faithful; default).
    #[default]
    Process,
    /// From any process: a shared-memory experiment MPI cannot run.
    Global,
}

/// `[processes]`: virtual processes (thread groups standing in for MPI ranks).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ProcessesConfig {
    /// Number of virtual processes P (with `ranks` > 1: the ranks, each one process).
    #[serde(default = "one")]
    pub count: usize,
    /// Ranks that share no memory (`blockflow run --ranks R`): R rank drivers in this OS process, each
    /// holding only its own blocks and exchanging everything else as messages, the in-process stand-in for
    /// MPI ranks. 1 (the default): every block in shared memory, split over `count` virtual processes.
    #[serde(default = "one")]
    pub ranks: usize,
    /// Threads per process T.
    #[serde(default = "one")]
    pub threads_per_process: usize,
    /// Pinning policy.
    #[serde(default)]
    pub pin: PinConfig,
    /// Stealing policy.
    #[serde(default)]
    pub steal: StealConfig,
    /// Steps per task-graph run: consecutive steps overlap inside a run (no barrier between them); the
    /// instability detector and the time series look at the state between runs.
    #[serde(default = "d_graph_steps")]
    pub steps_per_graph: usize,
}

fn one() -> usize {
    1
}
fn d_graph_steps() -> usize {
    4
}

impl Default for ProcessesConfig {
    fn default() -> Self {
        ProcessesConfig {
            count: 1,
            ranks: 1,
            threads_per_process: 1,
            pin: PinConfig::default(),
            steal: StealConfig::Process,
            steps_per_graph: d_graph_steps(),
        }
    }
}

/// The largest value of each `[processes]` count (processes, ranks, threads per process, steps per graph run).
pub const MAX_PROCESS_COUNT: usize = 4096;

impl ProcessesConfig {
    /// Checks the keys' ranges; the message names the key.
    pub fn validate(&self) -> Result<()> {
        for (name, v) in [
            ("processes.count", self.count),
            ("processes.ranks", self.ranks),
            ("processes.threads_per_process", self.threads_per_process),
            ("processes.steps_per_graph", self.steps_per_graph),
        ] {
            if v == 0 || v > MAX_PROCESS_COUNT {
                return config_err(format!("{name} = {v}: must be between 1 and {MAX_PROCESS_COUNT}"));
            }
        }
        if self.ranks > 1 && self.steal == StealConfig::Global {
            return config_err(format!(
                "processes.steal = \"global\" with processes.ranks = {}: ranks share no memory, so idle threads \
                 cannot take another rank's tasks; use \"process\" or one rank",
                self.ranks
            ));
        }
        Ok(())
    }
}
