//! The fluid time step as a task graph run by the scheduler's virtual processes (DESIGN.md, "One time step
//! as a task graph"). The graph covers `k` consecutive steps, is compiled once per block layout and
//! assignment, and re-armed for every run; inside a run, a block may start step t+1 while a distant block
//! still works on step t.
//!
//! Tasks per block `b` with fluid and step `s` (parity `p = s % 2`: the state is read from field `p`, the
//! new state written to field `1 - p`):
//!
//! | task | reads | writes |
//! |---|---|---|
//! | `send(b,s)` (only if a receiver lives in another process) | b.field[p] interior layers | message slots |
//! | `comm(b,s)` | senders' field[p] layers (same process) or slots (other process) | b.field[p] ghost cells |
//! | `boundary(b,s)` (only with links) | b.field[p] fluid cells | b.field[p] wall cells |
//! | `sweep(b,s)` | b.field[p] | b.field[1-p] fluid cells |
//! | `static_map(b,s)` (only with `run.no_skip`) | the scene geometry, b's flags and links | nothing |
//!
//! Skip rules (DESIGN.md principle 2) and what `run.no_skip` (measurement only; the results stay bitwise
//! the same) does instead, by [`SKIP_RULES`] name:
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

use crate::block::Block;
mod graph;
mod skip;
use crate::config::KernelChoice;
use crate::coupling::{self, SurfaceBoundary};
use crate::error::{Error, Instability};
use crate::fluid;
use crate::particles::Particles;
use crate::sim::Simulation;
use blockflow_kernels::sweep::SweepStats;
use blockflow_kernels::Real;
use blockflow_scheduler::executor::Executor;
use blockflow_scheduler::replay::load_imbalance;
use blockflow_scheduler::trace::TraceWriter;
use blockflow_scheduler::{GraphBuilder, TaskGraph, TaskId, TaskRecord, TaskSpec};
use graph::{add_fluid_tasks, add_particle_tasks, add_static_map_tasks};
pub use skip::SKIP_RULES;
use skip::{count_tasks, GraphCounts, NO_RULE};
use std::collections::HashMap;
use std::sync::Mutex;
use std::time::Instant;

/// Part labels of the tasks (index = `TaskSpec::part`): the parts of Algorithm 1 (LBM, boundary
/// handling, mapping = Coup1, reconstruction = Coup2, rigid body) plus communication.
pub const PARTS: [&str; 6] = ["lbm", "boundary", "exchange", "rigid_body", "map", "reconstruct"];
const PART_LBM: u8 = 0;
const PART_BOUNDARY: u8 = 1;
const PART_EXCHANGE: u8 = 2;
const PART_RB: u8 = 3;
const PART_MAP: u8 = 4;
const PART_RECON: u8 = 5;

const KIND_SEND: u32 = 0;
const KIND_COMM: u32 = 1;
const KIND_BOUNDARY: u32 = 2;
const KIND_SWEEP: u32 = 3;
const KIND_RB: u32 = 4;
const KIND_RB_SYNC: u32 = 5;
const KIND_MAP: u32 = 6;
const KIND_RECON: u32 = 7;
const KIND_FORCES: u32 = 8;
const KIND_STATIC: u32 = 9;

/// Task kind names, indexed by the kind bits of a task's payload.
pub const TASK_KINDS: [&str; 10] = [
    "send",
    "comm",
    "boundary",
    "sweep",
    "rb",
    "rb_sync",
    "map",
    "reconstruct",
    "forces",
    "static_map",
];

/// Task payload: bits 0–3 the kind, 4–11 the rigid-body sub-step inside the step, 12– the step inside
/// the graph run.
fn payload(k: usize, kind: u32) -> u32 {
    ((k as u32) << 12) | kind
}

fn payload_sub(k: usize, sub: usize, kind: u32) -> u32 {
    ((k as u32) << 12) | ((sub as u32) << 4) | kind
}

/// Step of a task inside its graph run.
fn step_of(payload: u32) -> usize {
    (payload >> 12) as usize
}

/// A remote message: which receiver and ghost region a slot feeds.
#[derive(Clone, Copy, Debug)]
struct Outgoing {
    receiver: usize,
    recv: usize,
    slot: usize,
}

/// Measurements of one interval of steps (`balance.interval`).
#[derive(Clone, Debug, Default)]
pub struct IntervalStats {
    /// First step of the interval (exclusive start: steps `start + 1 ..= end`).
    pub start: u64,
    /// Last step.
    pub end: u64,
    /// Wall-clock seconds of the graph runs.
    pub wall_seconds: f64,
    /// Modeled seconds (`graph` model of [`crate::study::model`]): the recorded graphs replayed with
    /// measured CPU durations on P×T dedicated cores, messages between processes priced at α + bytes/β.
    pub modeled_seconds: f64,
    /// Modeled seconds of the `bsp` model (sum over steps of the slowest process, messages included).
    pub bsp_seconds: f64,
    /// Workload (CPU seconds of every task but communication, eq. 16) per owner process, summed from
    /// `block_load` in block-id order.
    pub process_load: Vec<f64>,
    /// The same per block (m_tot of each block summed over the interval, in block-id order): the
    /// `measured` block weight and the corrector's measurement.
    pub block_load: Vec<f64>,
    /// Load imbalance eq. (18) of `process_load`.
    pub imbalance: f64,
    /// Bytes packed into cross-process messages.
    pub message_bytes: u64,
    /// Edge cut eq. (17) per process of the assignment used during the interval.
    pub edge_cut_mean: f64,
    /// Blocks moved by the balancing step at the end of the interval.
    pub migrated_blocks: u64,
    /// Bytes of the serialised blocks moved at the end of the interval.
    pub migrated_bytes: u64,
    /// The load imbalance eq. (18) the block weights predicted for this interval's assignment (NaN
    /// when the assignment was not made from weights).
    pub predicted_imbalance: f64,
    /// Seconds of the balancing step at the end of the interval (weights, partition, migration, re-arm).
    pub balance_seconds: f64,
}

/// Totals over a run.
#[derive(Clone, Debug, Default)]
pub struct PipelineTotals {
    /// CPU seconds per part (index as [`PARTS`]).
    pub part_cpu: [f64; 6],
    /// Tasks executed.
    pub tasks: u64,
    /// Cross-process message bytes.
    pub message_bytes: u64,
    /// Cross-process messages.
    pub remote_messages: u64,
    /// Ghost regions copied directly inside a process.
    pub local_copies: u64,
    /// Tasks executed per kind (index as [`TASK_KINDS`]).
    pub tasks_by_kind: [u64; 10],
    /// With `run.no_skip`: the work done only because a skip rule was off, per rule (index as
    /// [`SKIP_RULES`]): tasks that would not exist (`outside`, `no_boundary`, `no_particles`,
    /// `static_map`) and sweeps that took the general path instead of the fused kernel (`fused_kernel`).
    /// Zero without `run.no_skip`.
    pub unskipped: [u64; 5],
    /// CPU seconds per task kind (index as [`TASK_KINDS`]).
    pub cpu_by_kind: [f64; 10],
    /// With `run.no_skip`: CPU seconds of the work counted in `unskipped`, per rule (for `fused_kernel`
    /// the whole general-path sweeps of the fluid blocks, to be compared with the fused sweeps' time).
    pub unskipped_cpu: [f64; 5],
}

/// Runs a [`Simulation`] through the task graph.
pub struct Pipeline<T: Real> {
    exec: Executor,
    owners: Vec<u32>,
    steal_global: bool,
    max_k: usize,
    graphs: HashMap<usize, TaskGraph>,
    counts: HashMap<usize, GraphCounts>,
    /// Run every task on every block (`run.no_skip`, for measurement only): see the module docs. Set
    /// before the first step.
    pub no_skip: bool,
    outgoing: Vec<Vec<Outgoing>>,
    /// Slot index per (block, recv index) when the sender is remote.
    slot_of: Vec<Vec<Option<usize>>>,
    slots: Vec<Mutex<Vec<T>>>,
    stats: Vec<Mutex<SweepStats>>,
    interval: u64,
    current: IntervalStats,
    /// Finished intervals.
    pub intervals: Vec<IntervalStats>,
    /// Totals.
    pub totals: PipelineTotals,
    trace: Option<TraceWriter>,
    trace_offset_ns: u64,
    /// First step of every traced run, so trace events carry absolute step numbers.
    trace_bases: std::sync::Arc<Mutex<Vec<u64>>>,
    /// Boundary condition at particle surfaces.
    pub surface: SurfaceBoundary,
    /// Average the hydrodynamic force over two steps.
    pub force_averaging: bool,
    /// Dynamic load balancing at the end of every interval (absent: the assignment never changes).
    pub balancer: Option<crate::balance::dynamic::Balancer>,
    /// Price of a message between processes in the modeled times.
    pub comm: crate::study::model::CommModel,
    kinds: crate::study::model::TaskKinds,
    /// Counterfactual assignments replayed alongside the run (`blockflow study`).
    pub study: Option<crate::study::Counterfactual>,
    /// When set, the thread CPU nanoseconds of the last graph run per (step in the run, block) and part
    /// (index as [`PARTS`]): the per-block part timings m_X of section 3 (set it to `Some(Vec::new())`).
    pub block_times: Option<Vec<[u64; 6]>>,
    _marker: std::marker::PhantomData<T>,
}

impl<T: Real> Pipeline<T> {
    /// A pipeline for `sim`'s blocks with the given owners (block id → process), running at most `max_k`
    /// steps per graph and measuring intervals of `interval` steps.
    pub fn new(sim: &Simulation<T>, exec: Executor, owners: Vec<u32>, max_k: usize, interval: u64) -> Self {
        assert_eq!(owners.len(), sim.blocks.len());
        let steal_global = exec.steal() == blockflow_scheduler::executor::Steal::Global;
        let (outgoing, slot_of, nslots) = message_plan(sim, &owners);
        Pipeline {
            exec,
            owners,
            steal_global,
            max_k: max_k.max(1),
            graphs: HashMap::new(),
            counts: HashMap::new(),
            no_skip: false,
            outgoing,
            slot_of,
            slots: (0..nslots).map(|_| Mutex::new(Vec::new())).collect(),
            stats: Vec::new(),
            interval,
            current: IntervalStats::default(),
            intervals: Vec::new(),
            totals: PipelineTotals::default(),
            trace: None,
            trace_offset_ns: 0,
            trace_bases: Default::default(),
            surface: SurfaceBoundary::Cli,
            force_averaging: true,
            block_times: None,
            balancer: None,
            comm: Default::default(),
            kinds: task_kinds(sim),
            study: None,
            _marker: std::marker::PhantomData,
        }
    }

    /// Moves blocks to new owners: every block whose owner changes is serialised ([`crate::serialise`])
    /// by a thread of its old owner and rebuilt from the bytes by a thread of its new owner, which
    /// first-touches its new fields; then the ghost-region message plan is recomputed and the compiled
    /// graphs are dropped (the next run compiles for the new owners). Ghost layers are refilled by the
    /// next step's exchange. The numerics never see an owner. Returns the blocks moved and their bytes.
    pub fn set_owners(&mut self, sim: &Simulation<T>, owners: Vec<u32>) -> (usize, u64) {
        assert_eq!(owners.len(), sim.blocks.len());
        let moved: Vec<usize> = (0..owners.len()).filter(|&b| owners[b] != self.owners[b]).collect();
        if moved.is_empty() {
            return (0, 0);
        }
        let bufs: Vec<Mutex<Vec<u8>>> = moved.iter().map(|_| Mutex::new(Vec::new())).collect();
        let old = &self.owners;
        self.exec.on_each_process(|p| {
            for (i, &b) in moved.iter().enumerate() {
                if old[b] == p {
                    crate::serialise::encode_block(sim, b, &mut bufs[i].lock().expect("migration buffer"));
                }
            }
        });
        let new = &owners;
        self.exec.on_each_process(|p| {
            for (i, &b) in moved.iter().enumerate() {
                if new[b] == p {
                    let bytes = bufs[i].lock().expect("migration buffer");
                    // SAFETY: no task runs; each moved block is rebuilt by exactly one thread.
                    if let Err(e) = unsafe { crate::serialise::decode_block(sim, b, &bytes) } {
                        panic!("block {b} does not rebuild from its own bytes: {e}");
                    }
                }
            }
        });
        let bytes: u64 = bufs
            .iter()
            .map(|b| b.lock().expect("migration buffer").len() as u64)
            .sum();
        let (outgoing, slot_of, nslots) = message_plan(sim, &owners);
        self.outgoing = outgoing;
        self.slot_of = slot_of;
        self.slots = (0..nslots).map(|_| Mutex::new(Vec::new())).collect();
        self.owners = owners;
        self.graphs.clear();
        self.counts.clear();
        (moved.len(), bytes)
    }

    /// Records a Chrome trace of every run from now on; events carry the absolute step of their task.
    pub fn enable_trace(&mut self) {
        let cores = self.exec.cores().to_vec();
        let bases = self.trace_bases.clone();
        self.trace = Some(
            TraceWriter::new(
                PARTS.iter().map(|s| s.to_string()).collect(),
                cores,
                self.exec.threads_per_process(),
            )
            .with_step(move |run, spec| bases.lock().expect("trace bases")[run] + step_of(spec.payload) as u64 + 1),
        );
    }

    /// Writes the trace recorded so far.
    pub fn write_trace(&self, path: &std::path::Path) -> std::io::Result<()> {
        match &self.trace {
            Some(t) => t.write(path),
            None => Ok(()),
        }
    }

    /// The executor (processes, threads, cores).
    pub fn executor(&self) -> &Executor {
        &self.exec
    }

    /// Block owners.
    pub fn owners(&self) -> &[u32] {
        &self.owners
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
        });
    }

    fn graph(&mut self, sim: &Simulation<T>, k: usize) -> &TaskGraph {
        let owners = &self.owners;
        let outgoing = &self.outgoing;
        let no_skip = self.no_skip;
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
                            || b.particle_cells().is_some_and(|pc| !pc.links.is_empty()))
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

    /// Advances `sim` by `steps` steps through the task graph. On instability the simulation stops at the
    /// end of the graph run in which it was detected; the report names the first step (and lowest block)
    /// whose sweep saw it, and the cell as found in the state after that run.
    pub fn advance(&mut self, sim: &mut Simulation<T>, steps: u64) -> Result<(), Error> {
        let mut left = steps;
        while left > 0 {
            let to_interval = self.interval - sim.step % self.interval;
            let k = (self.max_k as u64).min(left).min(to_interval) as usize;
            let step = sim.step;
            if let Some(parts) = sim.particles.as_mut() {
                // The blocks with rigid-body tasks follow the bodies; the graphs are rebuilt when they move.
                let bodies = parts.bodies(step);
                if parts.update_active(k as u64, &bodies) {
                    self.graphs.clear();
                    self.counts.clear();
                }
            }
            self.run_graph(sim, k).map_err(Error::Unstable)?;
            if let Some(bal) = self.balancer.as_mut() {
                bal.after_run(sim, k);
            }
            if let Some(cf) = self.study.as_mut() {
                cf.after_steps(sim, k);
            }
            if let Some(parts) = sim.particles.as_mut() {
                parts.collect_stats((k * parts.subcycles) as u64);
                if let Some(e) = parts.take_error() {
                    return Err(Error::ParticlesUnstable(e));
                }
            }
            left -= k as u64;
            if sim.step.is_multiple_of(self.interval) {
                self.close_interval(sim);
                self.balance(sim);
            }
        }
        Ok(())
    }

    /// The balancing step at the end of an interval: weights, a new assignment, migration, re-arm (the
    /// graphs are recompiled at the next run); then the counterfactual assignments take theirs.
    fn balance(&mut self, sim: &Simulation<T>) {
        let load = self.intervals.last().map(|i| i.block_load.clone()).unwrap_or_default();
        if let Some(mut bal) = self.balancer.take() {
            let t0 = Instant::now();
            let dist = bal.rebalance(sim, &load, &self.owners);
            let predicted = crate::study::predicted_imbalance(bal.last_weights(), &dist.owners, self.exec.processes());
            let (moved, bytes) = self.set_owners(sim, dist.owners);
            let secs = t0.elapsed().as_secs_f64();
            bal.migrated += moved as u64;
            bal.seconds += secs;
            if let Some(iv) = self.intervals.last_mut() {
                iv.migrated_blocks = moved as u64;
                iv.migrated_bytes = bytes;
                iv.balance_seconds = secs;
            }
            self.current.predicted_imbalance = predicted;
            self.balancer = Some(bal);
        }
        if let Some(cf) = self.study.as_mut() {
            cf.balance(sim, &load);
        }
    }

    /// Closes the current measurement interval at `sim.step` (also called at the end of a run for a
    /// partial interval): per-process loads from the per-block loads in block-id order, the imbalance
    /// and the edge cut of the interval's assignment; the counterfactual assignments close theirs.
    pub fn close_interval(&mut self, sim: &Simulation<T>) {
        let step = sim.step;
        if step <= self.current.start {
            return;
        }
        let procs = self.exec.processes();
        let mut c = std::mem::take(&mut self.current);
        c.end = step;
        c.block_load.resize(sim.blocks.len(), 0.0);
        c.process_load = crate::study::process_loads(&c.block_load, &self.owners, procs);
        c.imbalance = load_imbalance(&c.process_load);
        c.edge_cut_mean = crate::balance::edge_cut_mean(&sim.domain, &self.owners, procs);
        if let Some(cf) = self.study.as_mut() {
            cf.close_interval(sim, &c.block_load);
        }
        self.intervals.push(c);
        self.current.start = step;
        self.current.predicted_imbalance = f64::NAN;
    }

    /// Sets the load imbalance the initial assignment's weights predict for the first interval.
    pub fn set_predicted_imbalance(&mut self, weights: &[f64]) {
        self.current.predicted_imbalance =
            crate::study::predicted_imbalance(weights, &self.owners, self.exec.processes());
    }

    /// Starts the measurement of the current interval at `step` (a run restarted from a checkpoint of
    /// that step: its first interval covers `step + 1 ..` up to the next multiple of `balance.interval`).
    pub fn resume_at(&mut self, step: u64) {
        self.current.start = step;
    }

    fn run_graph(&mut self, sim: &mut Simulation<T>, k: usize) -> Result<(), Instability> {
        let nb = sim.blocks.len();
        if self.stats.len() < k * nb {
            self.stats.resize_with(k * nb, || Mutex::new(SweepStats::default()));
        }
        self.graph(sim, k);
        let graph = self.graphs.remove(&k).expect("graph built above");
        let base = sim.step;
        let params = sim.params;
        let kernel: KernelChoice = sim.kernel;
        let blocks = &sim.blocks;
        let slots = &self.slots;
        let slot_of = &self.slot_of;
        let outgoing = &self.outgoing;
        let stats = &self.stats;
        let parts = sim.particles.as_ref();
        let surface = self.surface;
        let force_averaging = self.force_averaging;
        let domain = sim.domain;
        let sim_geometry = &sim.geometry;
        let no_skip = self.no_skip;
        let t0 = Instant::now();
        let run = self.exec.run(&graph, |_t: TaskId, spec: &TaskSpec, _w| {
            let b = &blocks[spec.block as usize];
            let kk = step_of(spec.payload);
            let p = ((base + kk as u64) % 2) as usize;
            match spec.payload & 15 {
                KIND_RB | KIND_RB_SYNC => {
                    let parts = parts.expect("rigid-body tasks only exist with particles");
                    let s = parts.subcycles as u64;
                    let g = (base + kk as u64) * s + ((spec.payload >> 4) & 0xff) as u64 + 1;
                    // SAFETY: the graph carries the edges of `particles::tasks`.
                    unsafe {
                        if spec.payload & 15 == KIND_RB {
                            parts.rb(b.id, g)
                        } else {
                            parts.rb_sync(b.id, g)
                        }
                    }
                }
                KIND_MAP => {
                    let parts = parts.expect("map tasks only exist with particles");
                    if b.fluid_cells == 0 {
                        // `run.no_skip` only: a block without fluid never gets an overlay.
                        coupling::tasks::map_scratch(parts, b, base + kk as u64, surface)
                    } else {
                        // SAFETY: the graph carries the edges of `coupling::tasks`.
                        unsafe { coupling::tasks::map_task(parts, b, base + kk as u64, surface, no_skip) }
                    }
                }
                KIND_RECON => {
                    // SAFETY: as above; reconstruct writes b's field p before anyone reads it this step.
                    unsafe {
                        if b.particle_cells().is_some() {
                            coupling::reconstruct(&domain, b, b.particle_cells_mut(), p, &params)
                        }
                    }
                }
                KIND_FORCES => {
                    let parts = parts.expect("forces tasks only exist with particles");
                    // SAFETY: as above.
                    unsafe { coupling::tasks::forces_task(parts, blocks, b.id, base + kk as u64, force_averaging) }
                }
                KIND_SEND => {
                    for o in &outgoing[b.id] {
                        let g = &blocks[o.receiver].recv[o.recv];
                        let mut buf = slots[o.slot].lock().expect("slot");
                        fluid::pack(b, p, g.offset, &g.directions, &mut buf);
                    }
                }
                KIND_COMM => {
                    for (r, g) in b.recv.iter().enumerate() {
                        match slot_of[b.id][r] {
                            Some(s) => fluid::unpack(b, p, g.offset, &g.directions, &slots[s].lock().expect("slot")),
                            None => fluid::copy_ghost(&blocks[g.from], b, p, g.offset, &g.directions),
                        }
                    }
                }
                KIND_STATIC => b.check_static_geometry(&domain, sim_geometry),
                KIND_BOUNDARY => {
                    if no_skip {
                        fluid::boundary_general(b, p);
                    } else {
                        fluid::boundary(b, p);
                    }
                    if b.particle_cells().is_some() {
                        // SAFETY: the boundary task is the only user of b's overlay and particle cells now.
                        unsafe { coupling::boundary(b, b.particle_cells_mut(), p) }
                    }
                }
                _ => {
                    // SAFETY: the graph orders every task touching field 1 - p of this block or writing
                    // field p around this sweep (module docs).
                    let st = unsafe {
                        if no_skip {
                            fluid::stream_collide_general(b, p, &params)
                        } else {
                            fluid::stream_collide(b, p, &params, kernel)
                        }
                    };
                    *stats[kk * blocks.len() + b.id].lock().expect("stats") = st;
                }
            }
        });
        let wall = t0.elapsed().as_secs_f64();
        self.account(&graph, &run.records, wall, sim, k);
        if let Some(tr) = self.trace.as_mut() {
            self.trace_bases.lock().expect("trace bases").push(base);
            tr.add_run(&graph, &run.records, self.trace_offset_ns);
            self.trace_offset_ns += run.wall_ns;
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

    fn account(&mut self, graph: &TaskGraph, records: &[TaskRecord], wall: f64, sim: &Simulation<T>, k: usize) {
        let procs = self.exec.processes();
        if self.current.block_load.len() != sim.blocks.len() {
            self.current.block_load = vec![0.0; sim.blocks.len()];
        }
        let mut durations = Vec::with_capacity(records.len());
        if let Some(bt) = self.block_times.as_mut() {
            let nb = sim.blocks.len();
            bt.clear();
            bt.resize(k * nb, [0; 6]);
        }
        let rule_of = self.counts.get(&k).map(|c| c.rule_of.as_slice()).unwrap_or(&[]);
        for (i, (spec, r)) in graph.specs().iter().zip(records).enumerate() {
            let cpu = r.cpu_ns as f64 * 1e-9;
            self.totals.part_cpu[spec.part as usize] += cpu;
            self.totals.cpu_by_kind[(spec.payload & 15) as usize] += cpu;
            if let Some(&rule) = rule_of.get(i).filter(|&&x| x != NO_RULE) {
                self.totals.unskipped_cpu[rule as usize] += cpu;
            }
            if let Some(bt) = self.block_times.as_mut() {
                let nb = sim.blocks.len();
                bt[step_of(spec.payload) * nb + spec.block as usize][spec.part as usize] += r.cpu_ns;
            }
            if spec.part != PART_EXCHANGE {
                self.current.block_load[spec.block as usize] += cpu;
            }
            durations.push(r.cpu_ns);
        }
        self.totals.tasks += records.len() as u64;
        if let Some(c) = self.counts.get(&k) {
            for (t, n) in self.totals.tasks_by_kind.iter_mut().zip(c.by_kind) {
                *t += n;
            }
            for (t, n) in self.totals.unskipped.iter_mut().zip(c.by_rule) {
                *t += n;
            }
        }
        let times = crate::study::model::model_run(
            graph,
            &durations,
            &self.owners,
            procs,
            self.exec.threads_per_process(),
            self.steal_global,
            &self.comm,
            &self.kinds,
            k,
            step_of,
        );
        self.current.modeled_seconds += times.graph_ns as f64 * 1e-9;
        self.current.bsp_seconds += times.bsp_ns as f64 * 1e-9;
        self.current.wall_seconds += wall;
        if let Some(cf) = self.study.as_mut() {
            cf.after_run(graph, &durations, k, &self.kinds, step_of);
        }
        let mut bytes = 0u64;
        let mut remote = 0u64;
        for o in self.outgoing.iter().flatten() {
            let g = &sim.blocks[o.receiver].recv[o.recv];
            bytes += (region_cells(&sim.blocks[o.receiver], g.offset) * g.directions.len() * T::BYTES) as u64;
            remote += 1;
        }
        let local: u64 = sim.blocks.iter().map(|b| b.recv.len() as u64).sum::<u64>() - remote;
        self.totals.message_bytes += bytes * k as u64;
        self.totals.remote_messages += remote * k as u64;
        self.totals.local_copies += local * k as u64;
        self.current.message_bytes += bytes * k as u64;
    }
}

/// The task kinds the modeled times need: which tasks receive ghost regions and the bytes of every
/// (sender block, receiver block) region (summed over the regions a pair shares across periodic wraps).
pub fn task_kinds<T: Real>(sim: &Simulation<T>) -> crate::study::model::TaskKinds {
    let mut region_bytes = HashMap::new();
    for b in &sim.blocks {
        for g in &b.recv {
            let bytes = (region_cells(b, g.offset) * g.directions.len() * T::BYTES) as u64;
            *region_bytes.entry((g.from as u32, b.id as u32)).or_insert(0) += bytes;
        }
    }
    crate::study::model::TaskKinds {
        exchange_part: PART_EXCHANGE,
        kind_mask: 15,
        comm_kind: KIND_COMM,
        region_bytes,
    }
}

/// Which ghost regions cross processes under `owners`: outgoing messages per sender, the slot of every
/// (receiver, region) that is remote, and the number of slots.
/// Outgoing messages per sender, the slot of every remote (receiver, region), and the slot count.
type MessagePlan = (Vec<Vec<Outgoing>>, Vec<Vec<Option<usize>>>, usize);

fn message_plan<T: Real>(sim: &Simulation<T>, owners: &[u32]) -> MessagePlan {
    let mut outgoing = vec![Vec::new(); sim.blocks.len()];
    let mut slot_of = Vec::with_capacity(sim.blocks.len());
    let mut nslots = 0;
    for b in &sim.blocks {
        let mut v = Vec::with_capacity(b.recv.len());
        for (r, g) in b.recv.iter().enumerate() {
            if owners[g.from] != owners[b.id] {
                outgoing[g.from].push(Outgoing {
                    receiver: b.id,
                    recv: r,
                    slot: nslots,
                });
                v.push(Some(nslots));
                nslots += 1;
            } else {
                v.push(None);
            }
        }
        slot_of.push(v);
    }
    (outgoing, slot_of, nslots)
}

fn region_cells<T: Real>(b: &Block<T>, off: [i32; 3]) -> usize {
    (0..3).map(|a| if off[a] == 0 { b.layout.size[a] } else { 1 }).product()
}
