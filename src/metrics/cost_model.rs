//! Modeled run time of a recorded graph run under an assignment (section 4 of the paper): two models,
//! both pricing every message between processes at `α + bytes/β`.
//!
//! - `graph`: the dependency-respecting list-scheduling replay of the scheduler on `P × T` dedicated
//!   cores, tasks on their owner's cores (any core with global stealing). An edge between tasks of two
//!   processes delays its successor by `α + bytes/β`: the bytes of the ghost region when the successor
//!   receives one, none (latency only) for the rigid-body and coupling edges. Edges of the recorded
//!   graph that order accesses inside one process (write-after-read on a neighbour's ghost layer) are
//!   kept when the counterfactual owners put their ends on two processes: a conservative model, slightly
//!   more synchronised than a distributed code would be.
//! - `bsp`: what a code that synchronises every step sees: per step, the slowest process's CPU seconds
//!   (its tasks' durations divided over its `T` threads) plus its incoming messages, one message per
//!   (sending process, receiving process, receiving task's payload), each `α + bytes/β`; summed over steps.
//!
//! The models know tasks only through [`TaskSemantics`] (which step a task belongs to, what an edge
//! carries), so they need nothing of the pipeline's task kinds. The defaults of α and β
//! (`balance.latency`, `balance.bandwidth`) are those of an InfiniBand FDR cluster like the paper's
//! SuperMUC: 2 µs and 5 GB/s.

use crate::config::{BalanceConfig, DEFAULT_BANDWIDTH, DEFAULT_LATENCY};
use blockflow_scheduler::replay::replay_mapped;
use blockflow_scheduler::{TaskGraph, TaskId, TaskSpec};
use std::collections::HashMap;
use std::sync::{mpsc, Arc};

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
    /// The price of `balance.latency` and `balance.bandwidth`.
    pub fn of(cfg: &BalanceConfig) -> Self {
        CommModel {
            latency: cfg.latency,
            bandwidth: cfg.bandwidth,
        }
    }

    /// Nanoseconds of one message of `bytes` bytes.
    pub fn message_ns(&self, bytes: u64) -> u64 {
        ((self.latency + bytes as f64 / self.bandwidth) * 1e9).round() as u64
    }
}

/// The machine a run is modeled on: `processes × threads` dedicated cores, whether any idle thread takes
/// any ready task (global stealing), and the price of a message.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Machine {
    /// Processes P.
    pub processes: usize,
    /// Threads per process T.
    pub threads: usize,
    /// Any idle thread takes any ready task.
    pub global: bool,
    /// Price of a message between processes.
    pub comm: CommModel,
}

/// What the models need to know about the tasks of a recorded graph.
pub trait TaskSemantics {
    /// Step of a task inside its graph run (0-based).
    fn step(&self, spec: &TaskSpec) -> usize;
    /// Bytes the edge from task `a` to task `b` carries when the two run in different processes (0: the
    /// edge is a latency-only synchronisation).
    fn edge_bytes(&self, a: &TaskSpec, b: &TaskSpec) -> u64;
}

/// A graph run as it was recorded: the graph, every task's measured nanoseconds (index = task id), the
/// steps it covered and the meaning of its tasks.
#[derive(Clone, Copy)]
pub struct RecordedRun<'a> {
    /// The graph.
    pub graph: &'a TaskGraph,
    /// Measured duration of every task (thread CPU nanoseconds).
    pub durations_ns: &'a [u64],
    /// Steps of the run.
    pub steps: usize,
    /// What the tasks are.
    pub tasks: &'a dyn TaskSemantics,
}

/// Modeled nanoseconds of one graph run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RunTimes {
    /// Dependency-respecting replay.
    pub graph_ns: u64,
    /// Bulk-synchronous: sum over steps of the slowest process.
    pub bsp_ns: u64,
}

/// Models one recorded graph run under `owners` (block → process) on machine `m`.
pub fn model_run(run: &RecordedRun, owners: &[u32], m: &Machine) -> RunTimes {
    let graph = run.graph;
    let durations_ns = run.durations_ns;
    let (processes, threads, global, comm) = (m.processes, m.threads, m.global, &m.comm);
    let owner = |t: TaskId| owners[graph.spec(t).block as usize];
    let delay = |a: TaskId, b: TaskId| {
        let (sa, sb) = (graph.spec(a), graph.spec(b));
        if owners[sa.block as usize] == owners[sb.block as usize] {
            return 0;
        }
        comm.message_ns(run.tasks.edge_bytes(sa, sb))
    };
    let graph_ns = replay_mapped(graph, durations_ns, owner, processes, threads, global, delay);
    let p = processes.max(1);
    let t = threads.max(1) as f64;
    let steps = run.steps.max(1);
    let mut cpu = vec![0u64; steps * p];
    for (i, s) in graph.specs().iter().enumerate() {
        let k = run.tasks.step(s).min(steps - 1);
        cpu[k * p + owners[s.block as usize] as usize % p] += durations_ns.get(i).copied().unwrap_or(0);
    }
    // Messages: one per (sender process, receiver process, receiving task's payload, step), with the
    // bytes of every edge it carries.
    let mut messages: HashMap<(usize, u32, u32, u32), u64> = HashMap::new();
    for a in 0..graph.len() as TaskId {
        let sa = graph.spec(a);
        let pa = owners[sa.block as usize];
        for &b in graph.successors(a) {
            let sb = graph.spec(b);
            let pb = owners[sb.block as usize];
            if pa != pb {
                let k = run.tasks.step(sb).min(steps - 1);
                *messages.entry((k, pa, pb, sb.payload)).or_insert(0) += run.tasks.edge_bytes(sa, sb);
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

/// A recorded graph run that owns what it refers to (to be modeled on another thread).
#[derive(Clone)]
pub struct OwnedRun {
    /// The graph.
    pub graph: Arc<TaskGraph>,
    /// Measured duration of every task.
    pub durations_ns: Vec<u64>,
    /// Steps of the run.
    pub steps: usize,
    /// What the tasks are.
    pub tasks: Arc<dyn TaskSemantics + Send + Sync>,
}

impl OwnedRun {
    /// The run as [`model_run`] takes it.
    pub fn recorded(&self) -> RecordedRun<'_> {
        RecordedRun {
            graph: &self.graph,
            durations_ns: &self.durations_ns,
            steps: self.steps,
            tasks: &*self.tasks,
        }
    }
}

/// Models graph runs on a thread of its own, while the next ones execute: [`Modeler::submit`] hands a run
/// over, [`Modeler::collect`] waits for every run handed over since the last call and returns their
/// times in submission order (the numbers [`model_run`] gives).
pub struct Modeler {
    jobs: Option<mpsc::Sender<(OwnedRun, Vec<u32>, Machine)>>,
    results: mpsc::Receiver<RunTimes>,
    outstanding: usize,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Default for Modeler {
    fn default() -> Self {
        Self::new()
    }
}

impl Modeler {
    /// A modeler with its thread.
    pub fn new() -> Self {
        let (jobs, rx) = mpsc::channel::<(OwnedRun, Vec<u32>, Machine)>();
        let (tx, results) = mpsc::channel();
        let thread = std::thread::Builder::new()
            .name("blockflow-model".into())
            .spawn(move || {
                for (run, owners, machine) in rx {
                    if tx.send(model_run(&run.recorded(), &owners, &machine)).is_err() {
                        return;
                    }
                }
            })
            .expect("spawn the modeling thread");
        Modeler {
            jobs: Some(jobs),
            results,
            outstanding: 0,
            thread: Some(thread),
        }
    }

    /// Hands over a run to model under `owners` on `machine`.
    pub fn submit(&mut self, run: OwnedRun, owners: Vec<u32>, machine: Machine) {
        self.jobs
            .as_ref()
            .expect("a live modeler")
            .send((run, owners, machine))
            .expect("the modeling thread is alive");
        self.outstanding += 1;
    }

    /// Waits for the runs handed over since the last call and returns their times, in submission order.
    pub fn collect(&mut self) -> Vec<RunTimes> {
        (0..std::mem::take(&mut self.outstanding))
            .map(|_| self.results.recv().expect("the modeling thread is alive"))
            .collect()
    }
}

impl Drop for Modeler {
    fn drop(&mut self) {
        self.jobs = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use blockflow_scheduler::GraphBuilder;

    fn spec(block: u32, part: u8, payload: u32) -> TaskSpec {
        TaskSpec {
            owner: 0,
            part,
            block,
            payload,
        }
    }

    /// Payload 1 receives a ghost region: its incoming edge carries the region's bytes; every task is in
    /// step 0.
    struct Regions(HashMap<(u32, u32), u64>);

    impl TaskSemantics for Regions {
        fn step(&self, _spec: &TaskSpec) -> usize {
            0
        }
        fn edge_bytes(&self, a: &TaskSpec, b: &TaskSpec) -> u64 {
            if b.payload == 1 {
                self.0.get(&(a.block, b.block)).copied().unwrap_or(0)
            } else {
                0
            }
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
        // Block 0's sweep feeds block 1's ghost exchange which feeds block 1's sweep.
        let mut g = GraphBuilder::new();
        let a = g.add(spec(0, 0, 3));
        let b = g.add(spec(1, 2, 1));
        let s = g.add(spec(1, 0, 3));
        g.edge(a, b);
        g.edge(b, s);
        let g = g.build().unwrap();
        let regions = Regions([((0, 1), 3000)].into_iter().collect());
        let d = [10_000, 1_000, 10_000];
        let run = RecordedRun {
            graph: &g,
            durations_ns: &d,
            steps: 1,
            tasks: &regions,
        };
        let m = Machine {
            processes: 2,
            threads: 1,
            global: false,
            comm: c,
        };
        let same = model_run(&run, &[0, 0], &m);
        assert_eq!(same.graph_ns, 21_000);
        // One process holds all the work: bsp = the sum, no messages.
        assert_eq!(same.bsp_ns, 21_000);
        let split = model_run(&run, &[0, 1], &m);
        // The exchange waits for the message: 1 µs + 3000 B / 1 GB/s = 4 µs.
        assert_eq!(split.graph_ns, 25_000);
        // bsp: process 1 has 11 µs of work and one 4 µs message; process 0 has 10 µs.
        assert_eq!(split.bsp_ns, 15_000);
    }
}
