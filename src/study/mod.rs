//! The load-balancing study of section 4.3 by counterfactual replay (`blockflow study`, issue #8 point 5).
//!
//! The scene runs once. After every graph run, the measured duration of every task is replayed under
//! every strategy's current assignment ([`model::model_run`]: the `graph` and `bsp` models, messages
//! between processes at α + bytes/β); at the end of every interval each strategy weighs the blocks from
//! the same per-block measurements and quantities, actually runs its partitioner (timed), and moves its
//! blocks on paper: the bytes are those of the block serialisation ([`crate::serialise`]) and are priced
//! like messages. The physics is bitwise identical under every assignment, so every strategy sees
//! exactly the same workload: the comparison is free of machine noise, and a 32-process study costs one
//! run on any machine.
//!
//! The live run's own balancer computes its interval metrics with the same functions
//! ([`process_loads`], [`predicted_imbalance`], [`model::model_run`]), so a counterfactual of the live
//! strategy reproduces the live run's load-imbalance series exactly.

pub mod model;
pub mod report;
pub mod run;

use crate::balance::dynamic::Balancer;
use crate::sim::Simulation;
use blockflow_kernels::Real;
use blockflow_scheduler::replay::load_imbalance;
use blockflow_scheduler::TaskGraph;
use model::{CommModel, TaskKinds};
use serde::Serialize;
use std::time::Instant;

/// Per-process load: `block_load` summed by owner in block-id order (the reduction order that makes a
/// counterfactual reproduce the live run exactly).
pub fn process_loads(block_load: &[f64], owners: &[u32], processes: usize) -> Vec<f64> {
    let p = processes.max(1);
    let mut load = vec![0.0; p];
    for (b, &l) in block_load.iter().enumerate() {
        load[owners[b] as usize % p] += l;
    }
    load
}

/// The load imbalance eq. (18) that block `weights` predict for `owners`.
pub fn predicted_imbalance(weights: &[f64], owners: &[u32], processes: usize) -> f64 {
    if weights.len() != owners.len() {
        return f64::NAN;
    }
    load_imbalance(&process_loads(weights, owners, processes))
}

/// One interval of one strategy.
#[derive(Clone, Debug, Default, Serialize)]
pub struct StrategyInterval {
    /// First step (exclusive).
    pub start: u64,
    /// Last step.
    pub end: u64,
    /// Modeled seconds, `graph` model (balancing at the interval's end not included).
    pub graph_seconds: f64,
    /// Modeled seconds, `bsp` model.
    pub bsp_seconds: f64,
    /// m_tot per process (eq. 16).
    pub process_load: Vec<f64>,
    /// Measured load imbalance eq. (18).
    pub imbalance: f64,
    /// Load imbalance the weights predicted for this interval's assignment (NaN: not made from weights).
    pub predicted_imbalance: f64,
    /// Edge cut eq. (17) per process.
    pub edge_cut_mean: f64,
    /// Blocks moved at the end of the interval.
    pub migrated_blocks: u64,
    /// Of which would have moved without METIS relabelling (METIS only).
    pub migrated_unrelabelled: Option<u64>,
    /// Serialised bytes of the moved blocks.
    pub migrated_bytes: u64,
    /// Measured seconds of the weights and the partitioner at the end of the interval.
    pub partition_seconds: f64,
    /// Modeled seconds of the migration: the slowest process's sent and received blocks as messages.
    pub migration_seconds: f64,
}

impl StrategyInterval {
    /// Seconds of the balancing step at the interval's end (partition measured, migration modeled).
    pub fn balance_seconds(&self) -> f64 {
        self.partition_seconds + self.migration_seconds
    }
}

/// One counterfactual assignment followed through the run.
pub struct Strategy {
    /// Name in the tables (`none`, `hilbert`, ..., `steal-global`).
    pub name: String,
    /// The balancer (absent: the assignment never changes).
    pub balancer: Option<Balancer>,
    /// Any idle thread takes any ready task (the replay's global pool).
    pub global: bool,
    /// Current owners.
    pub owners: Vec<u32>,
    /// Finished intervals.
    pub intervals: Vec<StrategyInterval>,
    current: StrategyInterval,
}

impl Strategy {
    /// A counterfactual starting from `owners`, which `initial_weights` predict (for the first
    /// interval's predicted imbalance).
    pub fn new(
        name: &str,
        balancer: Option<Balancer>,
        global: bool,
        owners: Vec<u32>,
        initial_weights: &[f64],
        processes: usize,
    ) -> Self {
        let current = StrategyInterval {
            predicted_imbalance: predicted_imbalance(initial_weights, &owners, processes),
            ..Default::default()
        };
        Strategy {
            name: name.to_string(),
            balancer,
            global,
            owners,
            intervals: Vec::new(),
            current,
        }
    }
}

/// Every counterfactual of a run.
pub struct Counterfactual {
    /// The strategies, in table order.
    pub strategies: Vec<Strategy>,
    /// Processes of the counterfactual assignments.
    pub processes: usize,
    /// Threads per process.
    pub threads: usize,
    /// Price of a message.
    pub comm: CommModel,
}

impl Counterfactual {
    /// Replays a finished graph run (its tasks' measured nanoseconds) under every strategy's owners.
    pub fn after_run(
        &mut self,
        graph: &TaskGraph,
        durations_ns: &[u64],
        k: usize,
        kinds: &TaskKinds,
        step_of: fn(u32) -> usize,
    ) {
        for s in &mut self.strategies {
            let t = model::model_run(
                graph,
                durations_ns,
                &s.owners,
                self.processes,
                self.threads,
                s.global,
                &self.comm,
                kinds,
                k,
                step_of,
            );
            s.current.graph_seconds += t.graph_ns as f64 * 1e-9;
            s.current.bsp_seconds += t.bsp_ns as f64 * 1e-9;
        }
    }

    /// Bookkeeping of the weights after `k` steps (the corrector's prediction).
    pub fn after_steps<T: Real>(&mut self, sim: &Simulation<T>, k: usize) {
        for s in &mut self.strategies {
            if let Some(b) = s.balancer.as_mut() {
                b.after_run(sim, k);
            }
        }
    }

    /// Closes every strategy's interval at `sim.step` with the interval's per-block loads.
    pub fn close_interval<T: Real>(&mut self, sim: &Simulation<T>, block_load: &[f64]) {
        let p = self.processes;
        for s in &mut self.strategies {
            let mut c = std::mem::take(&mut s.current);
            c.end = sim.step;
            c.process_load = process_loads(block_load, &s.owners, p);
            c.imbalance = load_imbalance(&c.process_load);
            c.edge_cut_mean = crate::balance::edge_cut_mean(&sim.domain, &s.owners, p);
            s.intervals.push(c);
            s.current.start = sim.step;
            s.current.predicted_imbalance = f64::NAN;
        }
    }

    /// The balancing step of every strategy with a balancer: weights from the last interval's loads,
    /// its partitioner (timed), the migration priced from the serialised bytes of the moved blocks.
    pub fn balance<T: Real>(&mut self, sim: &Simulation<T>, block_load: &[f64]) {
        let p = self.processes;
        for s in &mut self.strategies {
            let Some(bal) = s.balancer.as_mut() else {
                s.current.predicted_imbalance = predicted_imbalance(&[], &s.owners, p);
                continue;
            };
            let t0 = Instant::now();
            let dist = bal.rebalance(sim, block_load, &s.owners);
            let partition = t0.elapsed().as_secs_f64();
            let predicted = predicted_imbalance(bal.last_weights(), &dist.owners, p);
            let mut sent = vec![(0u64, 0u64); p];
            let mut received = vec![(0u64, 0u64); p];
            let mut moved = 0;
            let mut bytes = 0;
            for (b, (&old, &new)) in s.owners.iter().zip(&dist.owners).enumerate() {
                if old != new {
                    let n = crate::serialise::encoded_len(sim, b) as u64;
                    moved += 1;
                    bytes += n;
                    sent[old as usize % p].0 += 1;
                    sent[old as usize % p].1 += n;
                    received[new as usize % p].0 += 1;
                    received[new as usize % p].1 += n;
                }
            }
            let migration = (0..p)
                .map(|q| {
                    let (m, n) = (sent[q].0 + received[q].0, sent[q].1 + received[q].1);
                    m as f64 * self.comm.latency + n as f64 / self.comm.bandwidth
                })
                .fold(0.0, f64::max);
            if let Some(iv) = s.intervals.last_mut() {
                iv.migrated_blocks = moved;
                iv.migrated_bytes = bytes;
                iv.migrated_unrelabelled = dist.migrated_unrelabelled.map(|m| m as u64);
                iv.partition_seconds = partition;
                iv.migration_seconds = migration;
            }
            s.owners = dist.owners;
            s.current.predicted_imbalance = predicted;
        }
    }
}
