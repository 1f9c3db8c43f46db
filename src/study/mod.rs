//! The load-balancing study of section 4.3 by counterfactual replay (`blockflow study`).
//!
//! The scene runs once. After every graph run, the measured duration of every task is replayed under
//! every candidate strategy's current assignment ([`crate::metrics::cost_model`]: the `graph` and `bsp`
//! models, messages between processes at α + bytes/β); at the end of every interval each candidate weighs
//! the blocks from the same per-block measurements and quantities, actually runs its partitioner
//! (timed), and moves its blocks on paper: the bytes are those of the block serialisation
//! ([`crate::serialise`]) and are priced like messages. The physics is bitwise identical under every
//! assignment, so every candidate sees exactly the same workload: the comparison is free of machine
//! noise, and a 32-process study costs one run on any machine.
//!
//! The [`Counterfactual`] is an observer of the run's time loop, and each candidate keeps its intervals
//! with the same [`IntervalLog`] as the live run, so a candidate of the live strategy reproduces the live
//! run's load-imbalance series exactly. [`report`] turns the candidates into Table 3.

pub mod report;

use crate::balance::weights::BlockState;
use crate::balance::Balancer;
use crate::error::Result;
use crate::metrics::cost_model::Machine;
use crate::metrics::interval::{IntervalLog, IntervalStats};
use crate::metrics::load::predicted_imbalance;
use crate::timeloop::{Observer, RunContext};
use blockflow_kernels::Real;

/// One counterfactual strategy followed through the run.
pub struct Candidate {
    /// Name in the tables (`none`, `hilbert`, ..., `steal-global`, optionally with `@weights`).
    pub name: String,
    /// The balancer (absent: the assignment never changes).
    pub balancer: Option<Balancer>,
    /// Its assignment and intervals.
    pub log: IntervalLog,
}

impl Candidate {
    /// A candidate starting from `owners` on `machine`, which `initial_weights` predict (for the first
    /// interval's predicted imbalance).
    pub fn new(
        name: &str,
        balancer: Option<Balancer>,
        owners: Vec<u32>,
        initial_weights: &[f64],
        machine: Machine,
    ) -> Self {
        let predicted = predicted_imbalance(initial_weights, &owners, machine.processes);
        Candidate {
            name: name.to_string(),
            balancer,
            log: IntervalLog::new(owners, machine, predicted),
        }
    }

    /// The finished intervals.
    pub fn intervals(&self) -> &[IntervalStats] {
        self.log.intervals()
    }

    /// The balancing step at the end of an interval: weights from the interval's loads and the
    /// partitioner, timed together by the thread's CPU clock (the recording's task times are CPU times
    /// too, and a wall clock on a loaded machine would charge other programs to the partitioner), the
    /// migration priced from the serialised bytes of the moved blocks, and the step graph of
    /// `steps_per_graph` steps recompiled for the new assignment when blocks moved, timed by the same clock.
    fn balance<T: Real>(&mut self, cx: &RunContext<'_, T>, block_load: &[f64], steps_per_graph: usize, no_skip: bool) {
        let m = *self.log.machine();
        let p = m.processes;
        let Some(bal) = self.balancer.as_mut() else {
            let owners = self.log.owners().to_vec();
            self.log.reassign(owners, f64::NAN);
            return;
        };
        let t0 = blockflow_scheduler::executor::thread_cpu_ns();
        let state = state_for(bal, cx);
        let dist = bal.rebalance(&state, block_load, self.log.owners());
        let partition = (blockflow_scheduler::executor::thread_cpu_ns() - t0) as f64 * 1e-9;
        let predicted = predicted_imbalance(bal.last_weights(), &dist.owners, p);
        let mut sent = vec![(0u64, 0u64); p];
        let mut received = vec![(0u64, 0u64); p];
        let mut moved = 0;
        let mut bytes = 0;
        for (b, (&old, &new)) in self.log.owners().iter().zip(&dist.owners).enumerate() {
            if old != new {
                let n = crate::serialise::encoded_len(cx.sim, b) as u64;
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
                let (k, n) = (sent[q].0 + received[q].0, sent[q].1 + received[q].1);
                k as f64 * m.comm.latency + n as f64 / m.comm.bandwidth
            })
            .fold(0.0, f64::max);
        let recompile = if moved > 0 {
            let t0 = blockflow_scheduler::executor::thread_cpu_ns();
            crate::pipeline::compile_for(cx.sim, &dist.owners, steps_per_graph, no_skip);
            (blockflow_scheduler::executor::thread_cpu_ns() - t0) as f64 * 1e-9
        } else {
            0.0
        };
        if let Some(iv) = self.log.last_mut() {
            iv.migrated_blocks = moved;
            iv.migrated_bytes = bytes;
            iv.migrated_unrelabelled = dist.migrated_unrelabelled.map(|m| m as u64);
            iv.partition_seconds = partition;
            iv.migration_seconds = migration;
            iv.recompile_seconds = recompile;
            iv.balance_seconds = partition + recompile + migration;
        }
        self.log.reassign(dist.owners, predicted);
    }
}

/// Every counterfactual of a run: an observer that replays each graph run under every candidate's
/// assignment and lets every candidate balance at the end of every interval.
pub struct Counterfactual {
    /// The candidates, in table order.
    pub candidates: Vec<Candidate>,
    /// Steps per graph run of the recording: the graph a candidate recompiles after moving blocks.
    pub steps_per_graph: usize,
    /// Whether the recording runs every task on every block (`run.no_skip`).
    pub no_skip: bool,
}

impl Counterfactual {
    /// The counterfactuals `candidates` of a recording of `cfg` (its graph runs and skip rule are what a
    /// candidate recompiles after moving blocks).
    pub fn new(candidates: Vec<Candidate>, cfg: &crate::config::Config) -> Self {
        Counterfactual {
            candidates,
            steps_per_graph: cfg.processes.steps_per_graph.max(1),
            no_skip: cfg.run.no_skip,
        }
    }
}

impl<T: Real> Observer<T> for Counterfactual {
    fn after_run(&mut self, cx: &RunContext<'_, T>) -> Result<()> {
        let Some(run) = cx.run else { return Ok(()) };
        let recorded = run.recorded();
        for c in &mut self.candidates {
            c.log.add_run(&recorded);
            if let Some(b) = c.balancer.as_mut().filter(|b| b.needs_state_after_runs()) {
                b.after_run(&BlockState::of(cx.sim), run.steps);
            }
        }
        Ok(())
    }

    fn interval_closed(&mut self, cx: &RunContext<'_, T>, interval: &IntervalStats, balanced: bool) -> Result<()> {
        let (k, no_skip) = (self.steps_per_graph, self.no_skip);
        for c in &mut self.candidates {
            if c.log.close(cx.sim.step, &interval.block_load, &cx.sim.domain).is_some() && balanced {
                c.balance(cx, &interval.block_load, k, no_skip);
            }
        }
        Ok(())
    }
}

/// The blocks' state a balancer's weights are computed from (empty when they need none).
fn state_for<T: Real>(bal: &Balancer, cx: &RunContext<'_, T>) -> BlockState {
    if bal.needs_state() {
        // The state the live balancer saw, before its migration, where it balanced this interval.
        cx.balance_state.cloned().unwrap_or_else(|| BlockState::of(cx.sim))
    } else {
        BlockState {
            quantities: Vec::new(),
            dry: false,
        }
    }
}
