//! The per-interval record of one assignment (`balance.interval` steps each): modeled time, per-process
//! load, load imbalance eq. (18), edge cut eq. (17) and what the balancing step at the interval's end
//! moved. The live run and every counterfactual assignment of the study keep theirs with this one
//! [`IntervalLog`], so a counterfactual of the live strategy reproduces the live run's series bit for bit.

use super::cost_model::{model_run, Machine, RecordedRun};
use super::edge_cut::edge_cut_mean;
use super::load::{load_imbalance, process_loads};
use crate::physics::domain::DomainSpec;
use crate::physics::parts::ByPart;
use serde::Serialize;

/// Measurements of one interval of steps. `study.json` writes the fields the study models (the measured
/// ones are skipped there).
#[derive(Clone, Debug, Default, Serialize)]
pub struct IntervalStats {
    /// First step of the interval (exclusive start: steps `start + 1 ..= end`).
    pub start: u64,
    /// Last step.
    pub end: u64,
    /// Modeled seconds of the `graph` model ([`crate::metrics::cost_model`]): the recorded graphs replayed
    /// with measured CPU durations on P×T dedicated cores, messages between processes priced at
    /// α + bytes/β.
    #[serde(rename = "graph_seconds")]
    pub modeled_seconds: f64,
    /// Modeled seconds of the `bsp` model (sum over steps of the slowest process, messages included).
    pub bsp_seconds: f64,
    /// Workload (eq. 16) per process, summed from the per-block loads in block-id order.
    pub process_load: Vec<f64>,
    /// Load imbalance eq. (18) of `process_load`.
    pub imbalance: f64,
    /// The load imbalance eq. (18) the block weights predicted for this interval's assignment (NaN when
    /// the assignment was not made from weights).
    pub predicted_imbalance: f64,
    /// Edge cut eq. (17) per process of the interval's assignment.
    pub edge_cut_mean: f64,
    /// Blocks moved by the balancing step at the end of the interval.
    pub migrated_blocks: u64,
    /// Of which would have moved without METIS relabelling (METIS only).
    pub migrated_unrelabelled: Option<u64>,
    /// Bytes of the serialised blocks moved at the end of the interval.
    pub migrated_bytes: u64,
    /// Measured seconds of the weights and the partitioner at the end of the interval (a counterfactual).
    pub partition_seconds: f64,
    /// Modeled seconds of the migration: the slowest process's sent and received blocks as messages (a
    /// counterfactual).
    pub migration_seconds: f64,
    /// Measured seconds of recompiling the step graph for the new assignment (message plan, graph compiled,
    /// tasks counted) at the end of the interval, when blocks moved (a counterfactual).
    pub recompile_seconds: f64,
    /// Wall-clock seconds of the graph runs (the live run).
    #[serde(skip)]
    pub wall_seconds: f64,
    /// The workload m_tot of each block summed over the interval, in block-id order: the `measured` block
    /// weight and the corrector's measurement.
    #[serde(skip)]
    pub block_load: Vec<f64>,
    /// Bytes packed into cross-process messages (the live run).
    #[serde(skip)]
    pub message_bytes: u64,
    /// Task CPU seconds per part over the interval (the live run).
    #[serde(skip)]
    pub part_seconds: ByPart<f64>,
    /// Seconds of the balancing step at the end of the interval: measured for the live run (weights,
    /// partition, migration, graph recompiled); partition and recompile measured plus migration modeled for a counterfactual.
    #[serde(skip)]
    pub balance_seconds: f64,
}

/// The intervals of one assignment followed through a run.
#[derive(Clone, Debug)]
pub struct IntervalLog {
    machine: Machine,
    owners: Vec<u32>,
    current: IntervalStats,
    finished: Vec<IntervalStats>,
}

impl IntervalLog {
    /// A log of the assignment `owners` on `machine`, whose first interval the block weights predict
    /// `predicted_imbalance` for.
    pub fn new(owners: Vec<u32>, machine: Machine, predicted_imbalance: f64) -> Self {
        IntervalLog {
            machine,
            owners,
            current: IntervalStats {
                predicted_imbalance,
                ..Default::default()
            },
            finished: Vec::new(),
        }
    }

    /// The machine the assignment is modeled on.
    pub fn machine(&self) -> &Machine {
        &self.machine
    }

    /// The assignment of the current interval (block id → process).
    pub fn owners(&self) -> &[u32] {
        &self.owners
    }

    /// The finished intervals.
    pub fn intervals(&self) -> &[IntervalStats] {
        &self.finished
    }

    /// The last finished interval.
    pub fn last_mut(&mut self) -> Option<&mut IntervalStats> {
        self.finished.last_mut()
    }

    /// The interval under way.
    pub fn current_mut(&mut self) -> &mut IntervalStats {
        &mut self.current
    }

    /// Starts the interval under way at `step` (a run restarted from a checkpoint of that step: its first
    /// interval covers `step + 1 ..` up to the next multiple of `balance.interval`).
    pub fn resume_at(&mut self, step: u64) {
        self.current.start = step;
    }

    /// Adds the modeled times of a recorded graph run under this log's assignment.
    pub fn add_run(&mut self, run: &RecordedRun) {
        self.add_times(model_run(run, &self.owners, &self.machine));
    }

    /// Adds modeled times (of runs under this log's assignment modeled elsewhere: [`super::cost_model::Modeler`]).
    pub fn add_times(&mut self, t: super::cost_model::RunTimes) {
        self.current.modeled_seconds += t.graph_ns as f64 * 1e-9;
        self.current.bsp_seconds += t.bsp_ns as f64 * 1e-9;
    }

    /// Closes the interval under way at `step` with the interval's per-block loads: per-process loads in
    /// block-id order, the imbalance, the edge cut of the assignment. Returns the closed interval, or
    /// `None` if no step was taken since the last one closed.
    pub fn close(&mut self, step: u64, block_load: &[f64], domain: &DomainSpec) -> Option<&mut IntervalStats> {
        if step <= self.current.start {
            return None;
        }
        let p = self.machine.processes;
        let mut c = std::mem::take(&mut self.current);
        c.end = step;
        c.block_load = block_load.to_vec();
        c.process_load = process_loads(&c.block_load, &self.owners, p);
        c.imbalance = load_imbalance(&c.process_load);
        c.edge_cut_mean = edge_cut_mean(domain, &self.owners, p);
        self.finished.push(c);
        self.current.start = step;
        self.current.predicted_imbalance = f64::NAN;
        self.finished.last_mut()
    }

    /// Takes a new assignment for the interval under way, predicted by the weights it was made from to
    /// have `predicted_imbalance` (NaN: not made from weights).
    pub fn reassign(&mut self, owners: Vec<u32>, predicted_imbalance: f64) {
        self.owners = owners;
        self.current.predicted_imbalance = predicted_imbalance;
    }

    /// Sets the imbalance the weights predict for the interval under way.
    pub fn set_predicted_imbalance(&mut self, predicted_imbalance: f64) {
        self.current.predicted_imbalance = predicted_imbalance;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::cost_model::CommModel;

    #[test]
    fn closing_an_interval_sums_block_loads_by_owner() {
        let d = DomainSpec {
            blocks: [2, 1, 1],
            block_size: [4, 4, 4],
            periodic: [false; 3],
        };
        let m = Machine {
            processes: 2,
            threads: 1,
            global: false,
            comm: CommModel::default(),
        };
        let mut log = IntervalLog::new(vec![0, 1], m, 0.25);
        assert!(log.close(0, &[1.0, 3.0], &d).is_none(), "no step taken");
        let iv = log.close(10, &[1.0, 3.0], &d).unwrap();
        assert_eq!((iv.start, iv.end), (0, 10));
        assert_eq!(iv.process_load, vec![1.0, 3.0]);
        assert_eq!(iv.imbalance, 0.5);
        assert_eq!(iv.predicted_imbalance, 0.25);
        assert_eq!(iv.edge_cut_mean, 8.0);
        log.reassign(vec![0, 0], 1.0);
        let iv = log.close(20, &[1.0, 3.0], &d).unwrap();
        assert_eq!(
            (iv.start, iv.process_load.clone(), iv.edge_cut_mean),
            (10, vec![4.0, 0.0], 0.0)
        );
        assert_eq!(log.intervals().len(), 2);
    }
}
