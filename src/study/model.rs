//! Modeled run time of a recorded graph run under an assignment (section 4 of the paper, issue #8
//! point 4): two models, both pricing every message between processes at `α + bytes/β`.
//!
//! - `graph`: the dependency-respecting list-scheduling replay of the scheduler (#3) on `P × T` dedicated
//!   cores, tasks on their owner's cores (any core with global stealing). An edge between tasks of two
//!   processes delays its successor by `α + bytes/β`: the bytes of the ghost region when the successor is
//!   a ghost exchange (`comm`), none (latency only) for the rigid-body and coupling edges. Edges of the
//!   recorded graph that order accesses inside one process (write-after-read on a neighbour's ghost
//!   layer) are kept when the counterfactual owners put their ends on two processes: a conservative
//!   model, slightly more synchronised than a distributed code would be.
//! - `bsp`: what a code that synchronises every step sees: per step, the slowest process's CPU seconds
//!   (its tasks' durations divided over its `T` threads) plus its incoming messages, one message per
//!   (sending process, receiving process, task kind and sub-step), each `α + bytes/β`; summed over steps.
//!
//! The defaults of α and β (`balance.latency`, `balance.bandwidth`) are those of an InfiniBand FDR
//! cluster like the paper's SuperMUC: 2 µs and 5 GB/s.

use blockflow_scheduler::replay::replay_mapped;
use blockflow_scheduler::{TaskGraph, TaskId};
use std::collections::HashMap;

/// Default message latency α in seconds.
pub const DEFAULT_LATENCY: f64 = 2e-6;
/// Default bandwidth β in bytes per second.
pub const DEFAULT_BANDWIDTH: f64 = 5e9;

/// Price of a message: `α + bytes/β`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CommModel {
    /// Latency α (seconds).
    pub latency: f64,
    /// Bandwidth β (bytes per second).
    pub bandwidth: f64,
}

impl Default for CommModel {
    fn default() -> Self {
        CommModel {
            latency: DEFAULT_LATENCY,
            bandwidth: DEFAULT_BANDWIDTH,
        }
    }
}

impl CommModel {
    /// Nanoseconds of one message of `bytes` bytes.
    pub fn message_ns(&self, bytes: u64) -> u64 {
        ((self.latency + bytes as f64 / self.bandwidth) * 1e9).round() as u64
    }
}

/// What the models need to know about the tasks: which part is the ghost exchange, the step and
/// sub-step of a task, and the bytes of the ghost region block `from` sends to block `to`.
pub struct TaskKinds {
    /// Part index of the ghost exchange.
    pub exchange_part: u8,
    /// Payload bits identifying the receiving (`comm`) kind: `payload & kind_mask == comm_kind`.
    pub kind_mask: u32,
    /// Kind of the receiving exchange task.
    pub comm_kind: u32,
    /// Bytes per (sender block, receiver block) ghost region.
    pub region_bytes: HashMap<(u32, u32), u64>,
}

/// Modeled nanoseconds of one graph run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RunTimes {
    /// Dependency-respecting replay.
    pub graph_ns: u64,
    /// Bulk-synchronous: sum over steps of the slowest process.
    pub bsp_ns: u64,
}

/// Models one recorded graph run under `owners` (block → process): `durations_ns[t]` is task `t`'s
/// measured time, `step_of` the step of a payload inside the run (`steps` steps).
#[allow(clippy::too_many_arguments)]
pub fn model_run(
    graph: &TaskGraph,
    durations_ns: &[u64],
    owners: &[u32],
    processes: usize,
    threads: usize,
    global: bool,
    comm: &CommModel,
    kinds: &TaskKinds,
    steps: usize,
    step_of: impl Fn(u32) -> usize,
) -> RunTimes {
    let owner = |t: TaskId| owners[graph.spec(t).block as usize];
    let delay = |a: TaskId, b: TaskId| {
        let (sa, sb) = (graph.spec(a), graph.spec(b));
        if owners[sa.block as usize] == owners[sb.block as usize] {
            return 0;
        }
        comm.message_ns(edge_bytes(kinds, sa, sb))
    };
    let graph_ns = replay_mapped(graph, durations_ns, owner, processes, threads, global, delay);
    let p = processes.max(1);
    let t = threads.max(1) as f64;
    let steps = steps.max(1);
    let mut cpu = vec![0u64; steps * p];
    for (i, s) in graph.specs().iter().enumerate() {
        let k = step_of(s.payload).min(steps - 1);
        cpu[k * p + owners[s.block as usize] as usize % p] += durations_ns.get(i).copied().unwrap_or(0);
    }
    // Messages: one per (sender process, receiver process, receiving kind and sub-step, step), with the
    // bytes of every edge it carries.
    let mut messages: HashMap<(usize, u32, u32, u32), u64> = HashMap::new();
    for a in 0..graph.len() as TaskId {
        let sa = graph.spec(a);
        let pa = owners[sa.block as usize];
        for &b in graph.successors(a) {
            let sb = graph.spec(b);
            let pb = owners[sb.block as usize];
            if pa != pb {
                let k = step_of(sb.payload).min(steps - 1);
                *messages.entry((k, pa, pb, sb.payload)).or_insert(0) += edge_bytes(kinds, sa, sb);
            }
        }
    }
    let mut incoming = vec![0u64; steps * p];
    for (&(k, _, pb, _), &bytes) in &messages {
        incoming[k * p + pb as usize % p] += comm.message_ns(bytes);
    }
    let mut bsp_ns = 0u64;
    for k in 0..steps {
        let mut slowest = 0u64;
        for q in 0..p {
            let x = if global {
                // Any thread takes any task: the step's work over all P × T cores.
                (cpu[k * p..(k + 1) * p].iter().sum::<u64>() as f64 / (p as f64 * t)) as u64
            } else {
                (cpu[k * p + q] as f64 / t) as u64
            } + incoming[k * p + q];
            slowest = slowest.max(x);
        }
        bsp_ns += slowest;
    }
    RunTimes { graph_ns, bsp_ns }
}

fn edge_bytes(kinds: &TaskKinds, a: &blockflow_scheduler::TaskSpec, b: &blockflow_scheduler::TaskSpec) -> u64 {
    if b.part == kinds.exchange_part && b.payload & kinds.kind_mask == kinds.comm_kind {
        kinds.region_bytes.get(&(a.block, b.block)).copied().unwrap_or(0)
    } else {
        0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use blockflow_scheduler::{GraphBuilder, TaskSpec};

    fn spec(block: u32, part: u8, payload: u32) -> TaskSpec {
        TaskSpec {
            owner: 0,
            part,
            block,
            payload,
        }
    }

    #[test]
    fn message_price_and_split_graph() {
        let c = CommModel {
            latency: 1e-6,
            bandwidth: 1e9,
        };
        assert_eq!(c.message_ns(0), 1000);
        assert_eq!(c.message_ns(1000), 2000);
        // Block 0's sweep (part 0) feeds block 1's comm (part 2, kind 1) which feeds block 1's sweep.
        let mut g = GraphBuilder::new();
        let a = g.add(spec(0, 0, 3));
        let b = g.add(spec(1, 2, 1));
        let s = g.add(spec(1, 0, 3));
        g.edge(a, b);
        g.edge(b, s);
        let g = g.build().unwrap();
        let kinds = TaskKinds {
            exchange_part: 2,
            kind_mask: 15,
            comm_kind: 1,
            region_bytes: [((0, 1), 3000)].into_iter().collect(),
        };
        let d = [10_000, 1_000, 10_000];
        let same = model_run(&g, &d, &[0, 0], 2, 1, false, &c, &kinds, 1, |_| 0);
        assert_eq!(same.graph_ns, 21_000);
        // One process holds all the work: bsp = the sum, no messages.
        assert_eq!(same.bsp_ns, 21_000);
        let split = model_run(&g, &d, &[0, 1], 2, 1, false, &c, &kinds, 1, |_| 0);
        // The comm waits for the message: 1 µs + 3000 B / 1 GB/s = 4 µs.
        assert_eq!(split.graph_ns, 25_000);
        // bsp: process 1 has 11 µs of work and one 4 µs message; process 0 has 10 µs.
        assert_eq!(split.bsp_ns, 15_000);
    }
}
