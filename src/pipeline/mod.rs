//! The fluid time step as a task graph run by the scheduler's virtual processes (DESIGN.md, "One time step
//! as a task graph"). The graph covers `k` consecutive steps, is compiled once per block layout and
//! assignment, and re-armed for every run; inside a run, a block may start step t+1 while a distant block
//! still works on step t.
//!
//! Tasks per block `b` with fluid and step `s` (parity `p = s % 2`: the state of parity p is read; under
//! pull streaming it is field `p` and the new state goes to field `1 - p`, under AA the one field is
//! updated in place). "Cells" below are the cells whose post-collision populations are meant; where
//! they are stored is the pattern's slot map ([`blockflow_kernels::Slots`]), one element per (cell,
//! direction) in each state, so tasks on the same state conflict exactly as under pull. The one task on
//! two states is the sweep; the AA sweep writes state p + 1 into the elements that held the incoming
//! populations f*_q(x − c_q) of b's fluid cells in state p, which only b's own earlier tasks of step s
//! read (boundary passes, reconstruction, `send`), so the edges below serve both patterns:
//!
//! | task | reads | writes |
//! |---|---|---|
//! | `send(b,s)` (only if a receiver lives in another process) | state p of b's interior layers | message slots |
//! | `comm(b,s)` | senders' state p layers (same process) or slots (other process) | state p of b's ghost cells |
//! | `boundary(b,s)` (only with links) | state p of b's fluid cells | state p of b's wall cells |
//! | `sweep(b,s)` | state p of b | state p + 1 of b's fluid cells (pull: field `1 - p`; AA: in place) |
//! | `static_map(b,s)` (only with `run.no_skip`) | the scene geometry, b's flags and links | nothing |
//!
//! Skip rules (DESIGN.md principle 2) and what `run.no_skip` (measurement only; the results stay bitwise
//! the same) does instead, by [`SkipRule`] name:
//! - `outside`: a block without fluid gets no task, a block without a ghost region to receive no `comm`.
//!   No-skip: every block gets `comm`, `boundary` and `sweep` (and, with moving bodies, `map` and
//!   `reconstruct`); they visit the block's cells and find nothing to do cell by cell.
//! - `no_boundary`: a block without links (and without particle links) gets no `boundary` task.
//!   No-skip: every block gets one; it scans every interior cell for near-boundary cells, then applies
//!   the (possibly empty) links.
//! - `no_particles`: only blocks that a body can reach get `map`, `reconstruct`, `forces`, `rb` and
//!   `rb_sync` tasks, and `map` takes a fast path on a block with no body near. No-skip: every block gets
//!   all of them every step and `map` scans every block. (A scene without moving bodies has none: n/a.)
//! - `static_map`: walls and planes are classified into flags and links once, at set-up. No-skip: a
//!   `static_map` task re-derives them for every block every step and checks them against the stored ones.
//!   (Fixed bodies, mapped once at set-up, are not re-mapped.)
//! - `fused_kernel`: the sweep runs the configured kernel (`fluid.kernel`, fused by default: on every
//!   block, not only obstacle-free ones) over the fluid runs mapped once. No-skip: the general path,
//!   runs found by scanning every cell's flag and the split kernels (stream, then collide).
//!
//! Edges (every conflicting pair of accesses is ordered):
//! - chain `comm(b,s) → boundary(b,s) → sweep(b,s) → first(b,s+1)`, and `sweep(b,s-1) → send(b,s)`;
//! - local sender n of b: `sweep(n,s-1) → comm(b,s)` (read after write) and `comm(b,s) → compute(n,s)`,
//!   the first of boundary/sweep of n (n's boundary writes wall cells in the layer b reads; n's next
//!   sweep into field p comes after it on n's chain);
//! - remote sender n: `send(n,s) → comm(b,s)`, `comm(b,s) → send(n,s+1)` (slot reuse);
//! - `send(n,s) → compute(n,s)` (n's boundary writes wall cells in the layers being packed).
//!
//! Every block's numbers depend only on its data, never on which thread runs it; the sweep statistics
//! are reduced in block order after the run, so results are bitwise identical for any P, T, pinning,
//! stealing and assignment.

//!
//! Files: [`kinds`] (task kinds and payloads), `graph` (building the graph), `skip` (the skip rules'
//! bookkeeping), `dispatch` (what each task does), `messages` (the cross-process message plan),
//! `migrate` (moving blocks between processes), `accounting` (per-task times into totals and the
//! record of the last run). The pipeline holds only working memory: the state is the [`Simulation`]
//! passed in, the decisions (when to balance, where blocks go) are the time loop's.

mod accounting;
mod dispatch;
mod graph;
pub mod kinds;
mod messages;
mod migrate;
mod skip;

pub use accounting::{RunRecord, Totals};
pub use messages::MessageSizes;
pub use skip::SkipRule;

use crate::config::Config;
use crate::error::{Error, Instability};
use crate::physics::parts::{ByPart, Part};
use crate::physics::simulation::Simulation;
use accounting::LastRun;
use blockflow_kernels::sweep::SweepStats;
use blockflow_kernels::{Pattern, Real};
use blockflow_scheduler::executor::Executor;
use blockflow_scheduler::trace::{TracePart, TraceWriter};
use blockflow_scheduler::{GraphBuilder, TaskGraph};
use dispatch::Dispatch;
use graph::{add_fluid_tasks, add_particle_tasks, add_static_map_tasks};
use kinds::Payload;
use messages::MessagePlan;
use skip::{count_tasks, GraphCounts};
use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// How a pipeline runs its graphs: the longest graph run, the skip rules, what it records.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PipelineConfig {
    /// Steps per graph run at most (`processes.steps_per_graph`): consecutive steps overlap inside a run.
    pub steps_per_graph: usize,
    /// Run every task on every block (`run.no_skip`, for measurement only): see the module docs.
    pub no_skip: bool,
    /// Record the thread CPU time of every (step, block, part) of each graph run: the per-block part
    /// timings m_X of section 3 ([`RunRecord::block_part_ns`]).
    pub block_parts: bool,
}

impl PipelineConfig {
    /// The settings of a configuration (`processes.steps_per_graph`, `run.no_skip`); no per-block part
    /// timings.
    pub fn of(cfg: &Config) -> Self {
        PipelineConfig {
            steps_per_graph: cfg.processes.steps_per_graph,
            no_skip: cfg.run.no_skip,
            block_parts: false,
        }
    }
}

/// A Chrome trace under way: the writer, the time offset of the next run and the first step of every
/// traced run (so events carry absolute step numbers).
struct Trace {
    writer: TraceWriter,
    offset_ns: u64,
    bases: Arc<Mutex<Vec<u64>>>,
}

/// Runs a [`Simulation`] through the task graph: the executor, the owners, the compiled graphs, the
/// message plan and the task accounting (working memory only).
pub struct Pipeline<T: Real> {
    exec: Executor,
    owners: Vec<u32>,
    settings: PipelineConfig,
    graphs: HashMap<usize, TaskGraph>,
    counts: HashMap<usize, GraphCounts>,
    plan: MessagePlan<T>,
    sizes: MessageSizes,
    stats: Vec<Mutex<SweepStats>>,
    totals: Totals,
    last: LastRun,
    trace: Option<Trace>,
}

impl<T: Real> Pipeline<T> {
    /// A pipeline for `sim`'s blocks with the given owners (block id → process of `exec`).
    pub fn new(sim: &Simulation<T>, exec: Executor, owners: Vec<u32>, settings: PipelineConfig) -> Self {
        assert_eq!(owners.len(), sim.blocks.len());
        let plan = MessagePlan::new(sim, &owners);
        Pipeline {
            exec,
            owners,
            settings: PipelineConfig {
                steps_per_graph: settings.steps_per_graph.max(1),
                ..settings
            },
            graphs: HashMap::new(),
            counts: HashMap::new(),
            plan,
            sizes: MessageSizes::of(sim),
            stats: Vec::new(),
            totals: Totals::default(),
            last: LastRun::default(),
            trace: None,
        }
    }

    /// The settings.
    pub fn settings(&self) -> &PipelineConfig {
        &self.settings
    }

    /// The executor (processes, threads, cores).
    pub fn executor(&self) -> &Executor {
        &self.exec
    }

    /// Block owners.
    pub fn owners(&self) -> &[u32] {
        &self.owners
    }

    /// Totals over the graph runs so far.
    pub fn totals(&self) -> &Totals {
        &self.totals
    }

    /// What the ghost-region edges of the graph carry (for the cost model).
    pub fn message_sizes(&self) -> &MessageSizes {
        &self.sizes
    }

    /// Records a Chrome trace of every run from now on; events carry the absolute step of their task.
    pub fn enable_trace(&mut self) {
        let cores = self.exec.cores().to_vec();
        let bases: Arc<Mutex<Vec<u64>>> = Default::default();
        let b = bases.clone();
        let parts = Part::ALL
            .iter()
            .map(|p| TracePart {
                name: p.name().to_string(),
                colour: Some(p.trace_colour()),
            })
            .collect();
        let writer = TraceWriter::new(parts, cores, self.exec.threads_per_process())
            .with_step(move |run, spec| b.lock().expect("trace bases")[run] + Payload::of(spec).step as u64 + 1);
        self.trace = Some(Trace {
            writer,
            offset_ns: 0,
            bases,
        });
    }

    /// Writes the trace recorded so far (nothing without [`Pipeline::enable_trace`]).
    pub fn write_trace(&self, path: &std::path::Path) -> std::io::Result<()> {
        match &self.trace {
            Some(t) => t.writer.write(path),
            None => Ok(()),
        }
    }

    /// Number of tasks of the one-step graph.
    pub fn tasks_per_step(&mut self, sim: &Simulation<T>) -> usize {
        self.graph(sim, 1).len()
    }

    /// Writes the initial state's pages from a thread of each block's owner (first touch: on a NUMA
    /// machine the memory then lives next to the cores that use it). Call before the first step.
    pub fn first_touch(&self, sim: &Simulation<T>) {
        let owners = &self.owners;
        self.exec.on_each_process(|p| {
            for b in sim.blocks.iter().filter(|b| owners[b.id] == p) {
                match b.pattern {
                    Pattern::Pull => {
                        // SAFETY: each block is touched by exactly one process's thread, nothing else runs.
                        let f = unsafe { b.field_mut(1) };
                        let src = b.field(0);
                        for s in &b.segments {
                            for q in 0..blockflow_kernels::d3q19::Q {
                                for i in s.start..s.start + s.len {
                                    f.set(q, i, src.get(q, i));
                                }
                            }
                        }
                    }
                    // The one field was written by the initialisation; copying it into pages mapped here
                    // would need a second field for a moment, the memory AA saves.
                    Pattern::Aa => {}
                }
            }
        });
    }

    /// The compiled graph of `k` steps for the current owners and active blocks (compiled on first use).
    fn graph(&mut self, sim: &Simulation<T>, k: usize) -> &TaskGraph {
        let owners = &self.owners;
        let outgoing = &self.plan.outgoing;
        let no_skip = self.settings.no_skip;
        let counts = &mut self.counts;
        self.graphs.entry(k).or_insert_with(|| {
            let mut g = GraphBuilder::new();
            let coupled = sim.particles.is_some() && sim.blocks.iter().any(|b| b.particle_cells().is_some());
            let moving = sim.particles.as_ref().is_some_and(|p| p.has_moving());
            // Blocks whose fluid touches particles always get a boundary task.
            let force_boundary: Vec<bool> = sim
                .blocks
                .iter()
                .map(|b| {
                    b.fluid_cells > 0
                        && b.particle_cells().is_some()
                        && (moving && sim.particles.as_ref().is_some_and(|p| p.active[b.id])
                            || b.particle_cells().is_some_and(|pc| !pc.link_cells.is_empty()))
                })
                .collect();
            let fluid = add_fluid_tasks(&mut g, &sim.blocks, owners, outgoing, k, &force_boundary, no_skip);
            if let (Some(parts), true) = (&sim.particles, moving) {
                add_particle_tasks(&mut g, parts, &sim.blocks, owners, k, &fluid, coupled, no_skip);
            }
            if no_skip {
                add_static_map_tasks(&mut g, &sim.blocks, owners, k, &fluid);
            }
            let graph = g.build().expect("the step graph is acyclic");
            counts.insert(k, count_tasks(sim, &graph, &force_boundary, no_skip));
            graph
        })
    }

    /// Advances `sim` by one graph run of `k` steps (at most [`PipelineConfig::steps_per_graph`]): the
    /// blocks with rigid-body tasks follow the bodies (the graphs are rebuilt when they move), every task
    /// runs on its owner's threads, its times go into the totals and [`Pipeline::last_run`]. On
    /// instability the simulation stops at the end of the run; the report names the first step (and
    /// lowest block) whose sweep saw it, and the cell as found in the state after the run.
    pub fn run(&mut self, sim: &mut Simulation<T>, k: usize) -> Result<(), Error> {
        assert!(k >= 1 && k <= self.settings.steps_per_graph, "graph run of {k} steps");
        if let Some(parts) = sim.particles.as_mut() {
            let bodies = parts.bodies(sim.step);
            if parts.update_active(k as u64, &bodies) {
                self.graphs.clear();
                self.counts.clear();
            }
        }
        self.run_graph(sim, k).map_err(Error::Unstable)?;
        if let Some(parts) = sim.particles.as_mut() {
            parts.collect_stats((k * parts.subcycles) as u64);
            if let Some(e) = parts.take_error() {
                return Err(Error::ParticlesUnstable(e));
            }
        }
        Ok(())
    }

    /// The record of the last graph run (`None` before the first).
    pub fn last_run(&self) -> Option<RunRecord<'_>> {
        let graph = self.graphs.get(&self.last.steps)?;
        Some(RunRecord {
            graph,
            durations_ns: &self.last.durations_ns,
            steps: self.last.steps,
            wall_seconds: self.last.wall_seconds,
            block_load: &self.last.block_load,
            message_bytes: self.last.message_bytes,
            block_part_ns: self.settings.block_parts.then_some(self.last.block_part_ns.as_slice()),
            sizes: &self.sizes,
        })
    }

    fn run_graph(&mut self, sim: &mut Simulation<T>, k: usize) -> Result<(), Instability> {
        let nb = sim.blocks.len();
        if self.stats.len() < k * nb {
            self.stats.resize_with(k * nb, || Mutex::new(SweepStats::default()));
        }
        self.graph(sim, k);
        let graph = self.graphs.remove(&k).expect("graph built above");
        let base = sim.step;
        let t0 = Instant::now();
        let run = {
            let dispatch = Dispatch {
                sim: &*sim,
                plan: &self.plan,
                stats: &self.stats,
                no_skip: self.settings.no_skip,
            };
            // SAFETY: the graph carries the edges of the module docs (and those of the particle and
            // coupling tasks), so no two conflicting accesses run concurrently.
            self.exec.run(&graph, |_, spec, _| unsafe { dispatch.run(spec) })
        };
        let wall = t0.elapsed().as_secs_f64();
        self.account(&graph, &run.records, wall, sim, k);
        if let Some(tr) = self.trace.as_mut() {
            tr.bases.lock().expect("trace bases").push(base);
            tr.writer.add_run(&graph, &run.records, tr.offset_ns);
            tr.offset_ns += run.wall_ns;
        }
        self.graphs.insert(k, graph);
        // Instability check in step order, then block order.
        for kk in 0..k {
            let row: Vec<SweepStats> = (0..nb)
                .map(|b| *self.stats[kk * nb + b].lock().expect("stats"))
                .collect();
            let limit2 = sim.velocity_limit * sim.velocity_limit;
            if row
                .iter()
                .any(|st| st.nonfinite || st.max_u2.is_nan() || st.max_u2 > limit2)
            {
                sim.step = base + k as u64 - 1;
                let mut e = match sim.finish_step(&row) {
                    Err(e) => e,
                    Ok(()) => unreachable!("the row holds a bad statistic"),
                };
                e.step = base + kk as u64 + 1;
                return Err(e);
            }
        }
        sim.step = base + k as u64;
        Ok(())
    }
}

/// Per-part CPU nanoseconds of one (step, block) of a graph run.
pub type BlockPartNs = ByPart<u64>;
