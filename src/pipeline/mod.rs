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
//! The rigid-body phases of blocks with few contacts run one task per group of blocks (`graph`'s
//! `RbGroups`): a task per block and phase would cost more to schedule than the block's work.
//!
//! Every block's numbers depend only on its data, never on which thread runs it; the sweep statistics
//! are reduced in block order after the run, so results are bitwise identical for any P, T, pinning,
//! stealing and assignment.

//!
//! Under ranks that share no memory ([`World`] of several ranks) each rank runs its own blocks' tasks
//! and the graph's edges between ranks become messages (`ranked`).
//!
//! Files: [`kinds`] (task kinds and payloads), `graph` (building the graph), `skip` (the skip rules'
//! bookkeeping), `dispatch` (what each task does), `messages` (the cross-process message plan),
//! `ranked` (the graph and its messages on ranks), `migrate` (moving blocks between processes and
//! ranks), `accounting` (per-task times into totals and the record of the last run). The pipeline holds only working memory: the state is the [`Simulation`]
//! passed in, the decisions (when to balance, where blocks go) are the time loop's.

mod accounting;
mod dispatch;
mod graph;
pub mod kinds;
mod messages;
mod migrate;
mod ranked;
mod skip;

pub use accounting::{RunRecord, Totals};
pub use messages::MessageSizes;
pub use skip::SkipRule;

use crate::config::Config;
use crate::error::{Error, Instability};
use crate::physics::parts::{ByPart, Part};
use crate::physics::simulation::Simulation;
use crate::ranks::World;
use accounting::LastRun;
use blockflow_kernels::sweep::SweepStats;
use blockflow_kernels::{Pattern, Real};
use blockflow_scheduler::executor::Executor;
use blockflow_scheduler::trace::{TracePart, TraceWriter};
use blockflow_scheduler::{GraphBuilder, TaskGraph};
use dispatch::Dispatch;
use graph::{add_fluid_tasks, add_particle_tasks, add_static_map_tasks, rb_groups, rb_load, Grouping, RbGroups};
use kinds::Payload;
use messages::MessagePlan;
use ranked::{Driver, Outbox, RankGhosts, RankGraph};
use skip::{count_tasks, GraphCounts};
use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
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

/// A compiled graph: the tasks this process runs and, under ranks, the messages along the edges to
/// and from the other ranks' tasks.
struct Compiled {
    graph: Arc<TaskGraph>,
    messages: Option<RankGraph>,
    /// The blocks each `rb` task of a Jacobi sweep round runs (none under ranks or `run.no_skip`).
    groups: RbGroups,
}

/// What a rank's pipeline keeps besides the shared-memory one: the ghost regions between ranks, the
/// block flags the graph's shape comes from (gathered at the start of every run) and the tasks' outbox.
struct RankState {
    ghosts: RankGhosts,
    flags: Option<ShapeFlags>,
    outbox: Outbox,
}

/// Per block, what the step graph's shape depends on besides its static structure and the active
/// blocks: whether the block has a particle overlay, and whether the overlay has links.
#[derive(Clone, Debug, PartialEq, Eq)]
struct ShapeFlags {
    overlay: Vec<bool>,
    links: Vec<bool>,
}

impl ShapeFlags {
    /// The flags of the blocks this process holds (false for the others).
    fn of<T: Real>(sim: &Simulation<T>) -> Self {
        ShapeFlags {
            overlay: sim.blocks.iter().map(|b| b.particle_cells().is_some()).collect(),
            links: sim
                .blocks
                .iter()
                .map(|b| b.particle_cells().is_some_and(|p| !p.link_cells.is_empty()))
                .collect(),
        }
    }
}

/// The step graph of `k` steps for `owners` (block id → process or rank), with the cross-process ghost
/// messages `outgoing` and the blocks' shape `flags`: the whole graph, or under ranks (`me`) rank `me`'s
/// share of it; and its task counts.
fn compile<T: Real>(
    sim: &Simulation<T>,
    owners: &[u32],
    outgoing: &[Vec<messages::Outgoing>],
    flags: &ShapeFlags,
    k: usize,
    no_skip: bool,
    me: Option<u32>,
) -> (Compiled, GraphCounts) {
    let mut g = GraphBuilder::new();
    let coupled = sim.particles.is_some() && flags.overlay.iter().any(|&o| o);
    let moving = sim.particles.as_ref().is_some_and(|p| p.has_moving());
    // Blocks whose fluid touches particles always get a boundary task.
    let force_boundary: Vec<bool> = sim
        .blocks
        .iter()
        .map(|b| {
            b.fluid_cells > 0
                && flags.overlay[b.id]
                && (moving && sim.particles.as_ref().is_some_and(|p| p.active[b.id]) || flags.links[b.id])
        })
        .collect();
    let fluid = add_fluid_tasks(&mut g, &sim.blocks, owners, outgoing, k, &force_boundary, no_skip);
    let mut groups = RbGroups::default();
    if let (Some(parts), true) = (&sim.particles, moving) {
        let grouping = grouping(no_skip, me);
        groups = add_particle_tasks(
            &mut g,
            parts,
            &sim.blocks,
            owners,
            k,
            &fluid,
            coupled,
            no_skip,
            grouping,
        );
    }
    if no_skip {
        add_static_map_tasks(&mut g, &sim.blocks, owners, k, &fluid);
    }
    let global = g.build().expect("the step graph is acyclic");
    let compiled = match me {
        None => Compiled {
            graph: Arc::new(global),
            messages: None,
            groups,
        },
        Some(me) => {
            let (graph, messages) = RankGraph::project(&global, me);
            Compiled {
                graph: Arc::new(graph),
                messages: Some(messages),
                groups,
            }
        }
    };
    let counts = count_tasks(sim, &compiled.graph, &compiled.groups, &force_boundary, no_skip);
    (compiled, counts)
}

/// How the rigid-body phases are grouped: not with `run.no_skip` (each task counts under its own
/// block's skip rule), else per process, or under ranks among rank `me`'s inner blocks.
fn grouping(no_skip: bool, me: Option<u32>) -> Grouping {
    match me {
        _ if no_skip => Grouping::Off,
        None => Grouping::Processes,
        Some(me) => Grouping::Rank(me),
    }
}

/// Compiles the step graph of `k` steps for the assignment `owners` of `sim`'s blocks as a pipeline of
/// virtual processes would after moving its blocks there (the cross-process message plan, the graph
/// compiled and its tasks counted), and drops it: the recompile a counterfactual balancing step is charged.
pub fn compile_for<T: Real>(sim: &Simulation<T>, owners: &[u32], k: usize, no_skip: bool) {
    let plan = MessagePlan::new(sim, owners);
    let compiled = compile(sim, owners, &plan.outgoing, &ShapeFlags::of(sim), k, no_skip, None);
    drop(std::hint::black_box(compiled));
}

/// Runs a [`Simulation`] through the task graph: the executor, the owners, the compiled graphs, the
/// message plan and the task accounting (working memory only).
pub struct Pipeline<T: Real> {
    exec: Executor,
    owners: Vec<u32>,
    settings: PipelineConfig,
    graphs: HashMap<usize, Compiled>,
    counts: HashMap<usize, GraphCounts>,
    plan: MessagePlan<T>,
    sizes: Arc<MessageSizes>,
    stats: Vec<Mutex<SweepStats>>,
    /// Monotonic nanoseconds each member of a grouped rigid-body phase spent, summed per (step in the
    /// run, block): how a group's CPU time is shared among its members.
    member_ns: Vec<AtomicU64>,
    totals: Totals,
    last: LastRun,
    trace: Option<Trace>,
    world: Arc<World>,
    ranks: Option<RankState>,
}

impl<T: Real> Pipeline<T> {
    /// A pipeline for `sim`'s blocks with the given owners: block id → process of `exec` in a world of one
    /// rank; block id → rank in a world of several, where `exec` runs this rank's blocks in its one
    /// process and `sim` holds only those blocks.
    pub fn new(
        sim: &Simulation<T>,
        exec: Executor,
        owners: Vec<u32>,
        settings: PipelineConfig,
        world: Arc<World>,
    ) -> Self {
        assert_eq!(owners.len(), sim.blocks.len());
        let settings = PipelineConfig {
            steps_per_graph: settings.steps_per_graph.max(1),
            ..settings
        };
        let plan = MessagePlan::new(sim, &owners);
        let ranks = (!world.is_single()).then(|| {
            assert_eq!(exec.processes(), 1, "a rank runs its blocks in one process");
            RankState {
                ghosts: RankGhosts::new(sim, &owners, world.rank() as u32, settings.steps_per_graph),
                flags: None,
                outbox: Mutex::new(Vec::new()),
            }
        });
        Pipeline {
            exec,
            owners,
            settings,
            graphs: HashMap::new(),
            counts: HashMap::new(),
            plan,
            sizes: Arc::new(MessageSizes::of(sim)),
            stats: Vec::new(),
            member_ns: Vec::new(),
            totals: Totals::default(),
            last: LastRun::default(),
            trace: None,
            world,
            ranks,
        }
    }

    /// The ranks the run is spread over.
    pub fn world(&self) -> &Arc<World> {
        &self.world
    }

    /// Processes the blocks are distributed over: the executor's virtual processes, or the ranks.
    pub fn processes(&self) -> usize {
        if self.ranks.is_some() {
            self.world.ranks()
        } else {
            self.exec.processes()
        }
    }

    /// The process of this executor that runs block `b`'s tasks (`None`: another rank's block).
    pub fn local_process(&self, b: usize) -> Option<u32> {
        match self.ranks {
            None => Some(self.owners[b]),
            Some(_) => (self.owners[b] == self.world.rank() as u32).then_some(0),
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

    /// Number of tasks of the one-step graph (this rank's under ranks).
    pub fn tasks_per_step(&mut self, sim: &Simulation<T>) -> usize {
        self.graph(sim, 1).graph.len()
    }

    /// Writes the initial state's pages from a thread of each block's owner (first touch: on a NUMA
    /// machine the memory then lives next to the cores that use it). Call before the first step.
    pub fn first_touch(&self, sim: &Simulation<T>) {
        self.exec.on_each_process(|p| {
            for b in sim.blocks.iter().filter(|b| self.local_process(b.id) == Some(p)) {
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

    /// The compiled graph of `k` steps for the current owners and active blocks (compiled on first use):
    /// the whole step graph, or under ranks this rank's share of it.
    fn graph(&mut self, sim: &Simulation<T>, k: usize) -> &Compiled {
        if !self.graphs.contains_key(&k) {
            let flags = match &self.ranks {
                Some(r) => r.flags.clone().expect("the flags are gathered before a graph run"),
                None => ShapeFlags::of(sim),
            };
            let me = self.ranks.as_ref().map(|_| self.world.rank() as u32);
            let (compiled, counts) = compile(
                sim,
                &self.owners,
                &self.plan.outgoing,
                &flags,
                k,
                self.settings.no_skip,
                me,
            );
            self.counts.insert(k, counts);
            self.graphs.insert(k, compiled);
        }
        &self.graphs[&k]
    }

    /// Advances `sim` by one graph run of `k` steps (at most [`PipelineConfig::steps_per_graph`]): the
    /// blocks with rigid-body tasks follow the bodies (the graphs are rebuilt when they move), every task
    /// runs on its owner's threads, its times go into the totals and [`Pipeline::last_run`]. On
    /// instability the simulation stops at the end of the run; the report names the first step (and
    /// lowest block) whose sweep saw it, and the cell as found in the state after the run. Under ranks
    /// every rank calls this at once and they all return the same result.
    pub fn run(&mut self, sim: &mut Simulation<T>, k: usize) -> Result<(), Error> {
        assert!(k >= 1 && k <= self.settings.steps_per_graph, "graph run of {k} steps");
        if self.ranks.is_some() {
            return self.run_ranked(sim, k);
        }
        if let Some(parts) = sim.particles.as_mut() {
            let bodies = parts.bodies(sim.step);
            if parts.update_active(k as u64, &bodies) || self.groups_outdated(sim) {
                self.graphs.clear();
                self.counts.clear();
            }
        }
        let base = sim.step;
        if let Some((kk, b)) = self.run_graph(sim, k)? {
            sim.step = base + k as u64;
            return Err(Error::Unstable(sim.instability(b, base + kk as u64 + 1)));
        }
        sim.step = base + k as u64;
        if let Some(parts) = sim.particles.as_mut() {
            parts.collect_stats((k * parts.subcycles) as u64);
            if let Some(e) = parts.take_error() {
                return Err(Error::ParticlesUnstable(e));
            }
        }
        Ok(())
    }

    /// Whether a compiled graph's rigid-body groups no longer fit the blocks' loads
    /// ([`RbGroups::outdated`]); under ranks this rank's view (its own inner blocks).
    fn groups_outdated(&self, sim: &Simulation<T>) -> bool {
        let Some(parts) = sim.particles.as_ref() else {
            return false;
        };
        let me = self.ranks.as_ref().map(|_| self.world.rank() as u32);
        let grouping = grouping(self.settings.no_skip, me);
        if self.graphs.is_empty() || grouping == Grouping::Off || !parts.has_moving() {
            return false;
        }
        let active: Vec<usize> = (0..sim.blocks.len()).filter(|&b| parts.active[b]).collect();
        let fresh = rb_groups(parts, &self.owners, &active, grouping);
        self.graphs
            .values()
            .any(|c| c.groups.outdated(&fresh, |b| rb_load(parts, b)))
    }

    /// Under ranks: the blocks with rigid-body tasks for the next `k` steps (the union of every rank's
    /// bodies' reach) and the shape flags of every block, agreed on by all ranks (a collective); the
    /// compiled graphs are dropped when either changed. Nothing under virtual processes.
    pub fn agree(&mut self, sim: &mut Simulation<T>, k: usize) -> Result<(), Error> {
        if self.ranks.is_none() {
            return Ok(());
        }
        let nb = sim.blocks.len();
        let words = nb.div_ceil(64);
        // Three block sets (active, overlay, links) and one word: whether this rank's groups are outdated.
        let mut bits = vec![0u64; 3 * words + 1];
        bits[3 * words] = self.groups_outdated(sim) as u64;
        let set = |bits: &mut [u64], at: usize, b: usize| bits[at * words + b / 64] |= 1 << (b % 64);
        let mine = ShapeFlags::of(sim);
        for b in 0..nb {
            if mine.overlay[b] {
                set(&mut bits, 1, b);
            }
            if mine.links[b] {
                set(&mut bits, 2, b);
            }
        }
        if let Some(parts) = sim.particles.as_ref() {
            for (b, &a) in parts.reach(k as u64, &parts.bodies(sim.step)).iter().enumerate() {
                if a {
                    set(&mut bits, 0, b);
                }
            }
        }
        self.world.or(&mut bits)?;
        let get = |at: usize, b: usize| bits[at * words + b / 64] >> (b % 64) & 1 != 0;
        let flags = ShapeFlags {
            overlay: (0..nb).map(|b| get(1, b)).collect(),
            links: (0..nb).map(|b| get(2, b)).collect(),
        };
        let state = self.ranks.as_mut().expect("ranked");
        let mut changed = state.flags.as_ref() != Some(&flags) || bits[3 * words] != 0;
        state.flags = Some(flags);
        if let Some(parts) = sim.particles.as_mut() {
            changed |= parts.set_active((0..nb).map(|b| get(0, b)).collect());
        }
        if changed {
            self.graphs.clear();
            self.counts.clear();
        }
        Ok(())
    }

    /// [`Pipeline::run`] on ranks: the active blocks and the graph's shape flags agreed on, the copies of
    /// the neighbours' particle state refreshed, this rank's graph run with its messages; then the first
    /// instability or particle failure over all ranks (reported by the rank that found it) and the
    /// particle statistics summed over them.
    fn run_ranked(&mut self, sim: &mut Simulation<T>, k: usize) -> Result<(), Error> {
        let world = self.world.clone();
        let nb = sim.blocks.len();
        self.agree(sim, k)?;
        for (to, bytes) in ranked::halo(sim, &self.owners, &world)? {
            self.totals.count_message("halo", to as usize, world.ranks(), bytes);
        }
        let base = sim.step;
        let bad = self.run_graph(sim, k)?;
        // The first failure over all ranks by (step, block) and (phase, block), the particle statistics.
        let key = |x: Option<(u64, usize)>| x.map_or(u64::MAX, |(s, b)| s * nb as u64 + b as u64);
        let (mut perr, mut stats) = (None, (0u64, 0.0f64));
        if let Some(parts) = sim.particles.as_mut() {
            perr = parts.take_error_keyed();
            stats = parts.take_stats();
        }
        let mine = [
            key(bad.map(|(kk, b)| (kk as u64, b))),
            key(perr.as_ref().map(|e| (e.0, e.1))),
            stats.0,
            stats.1.to_bits(),
        ];
        let all: Vec<[u64; 4]> = world
            .allgather(&mine.iter().flat_map(|v| v.to_le_bytes()).collect::<Vec<u8>>())?
            .iter()
            .map(|r| std::array::from_fn(|i| u64::from_le_bytes(r[8 * i..8 * i + 8].try_into().expect("8 bytes"))))
            .collect();
        let first_bad = all.iter().map(|r| r[0]).min().unwrap_or(u64::MAX);
        let first_err = all.iter().map(|r| r[1]).min().unwrap_or(u64::MAX);
        sim.step = base + k as u64;
        if first_bad != u64::MAX {
            let (kk, b) = (first_bad / nb as u64, (first_bad % nb as u64) as usize);
            let report = (self.owners[b] == world.rank() as u32).then(|| sim.instability(b, base + kk + 1));
            let text = self.owners_bytes(b, report.map(|i| encode_instability(&i)))?;
            return Err(Error::Unstable(decode_instability(&text)));
        }
        if let Some(parts) = sim.particles.as_mut() {
            let contacts = all.iter().fold(0u64, |a, r| a.wrapping_add(r[2]));
            let pen = all.iter().map(|r| f64::from_bits(r[3])).fold(0.0, f64::max);
            parts.add_stats((k * parts.subcycles) as u64, contacts, pen);
        }
        if first_err != u64::MAX {
            let b = (first_err % nb as u64) as usize;
            let text = self.owners_bytes(b, perr.map(|e| e.2.into_bytes()))?;
            return Err(Error::ParticlesUnstable(String::from_utf8_lossy(&text).into_owned()));
        }
        Ok(())
    }

    /// The bytes the owner of block `b` has (`mine` there, `None` elsewhere), on every rank.
    fn owners_bytes(&self, b: usize, mine: Option<Vec<u8>>) -> Result<Vec<u8>, Error> {
        let mut bytes = mine.unwrap_or_default();
        self.world.broadcast(self.owners[b] as usize, &mut bytes)?;
        Ok(bytes)
    }

    /// The record of the last graph run (`None` before the first).
    pub fn last_run(&self) -> Option<RunRecord<'_>> {
        let graph = &self.graphs.get(&self.last.steps)?.graph;
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

    /// One graph run of `k` steps (the simulation's step is left at the run's first): returns the first
    /// (step in the run, block) whose sweep found the fluid unstable, among the blocks this process
    /// holds; an error only when the ranks could not finish the run together.
    fn run_graph(&mut self, sim: &Simulation<T>, k: usize) -> Result<Option<(usize, usize)>, Error> {
        let nb = sim.blocks.len();
        if self.stats.len() < k * nb {
            self.stats.resize_with(k * nb, || Mutex::new(SweepStats::default()));
        }
        if self.member_ns.len() < k * nb {
            self.member_ns.resize_with(k * nb, || AtomicU64::new(0));
        }
        for x in &self.member_ns {
            x.store(0, Ordering::Relaxed);
        }
        self.graph(sim, k);
        let compiled = self.graphs.remove(&k).expect("graph built above");
        let base = sim.step;
        let t0 = Instant::now();
        let dispatch = Dispatch {
            sim,
            plan: &self.plan,
            stats: &self.stats,
            no_skip: self.settings.no_skip,
            ghosts: self.ranks.as_ref().map(|r| &r.ghosts),
            groups: &compiled.groups,
            member_ns: &self.member_ns,
        };
        let (run, failure) = match (&self.ranks, &compiled.messages) {
            (Some(state), Some(messages)) => {
                let driver_thread = std::thread::current();
                let sent: ranked::SentLog = Mutex::new(Vec::new());
                self.world.transport().set_waker(driver_thread.clone());
                let mut driver = Driver {
                    sim,
                    world: &self.world,
                    ghosts: &state.ghosts,
                    graph: messages,
                    outbox: &state.outbox,
                    base,
                    error: None,
                    sent: &sent,
                };
                let run = self.exec.run_with_progress(
                    &compiled.graph,
                    |t, spec, _| {
                        // SAFETY: the graph carries the edges of the module docs (on this rank) and the
                        // messages stand for the edges between ranks (`ranked`).
                        unsafe {
                            dispatch.run(spec);
                            let dests = &messages.post[t as usize];
                            if !dests.is_empty() {
                                let log = (&*self.world, &sent);
                                if ranked::post(sim, &state.ghosts, dests, spec, base, &state.outbox, log) {
                                    driver_thread.unpark();
                                }
                            }
                        }
                    },
                    |rel| driver.progress(rel),
                );
                let error = driver.error;
                for &(to, kind, bytes) in sent.lock().expect("sent log").iter() {
                    self.totals
                        .count_message(kind.name(), to as usize, self.world.ranks(), bytes);
                }
                (run, error)
            }
            _ => {
                // SAFETY: the graph carries the edges of the module docs (and those of the particle and
                // coupling tasks), so no two conflicting accesses run concurrently.
                let run = self
                    .exec
                    .run(&compiled.graph, |_, spec, _| unsafe { dispatch.run(spec) });
                (run, None)
            }
        };
        if let Some(e) = failure {
            self.graphs.insert(k, compiled);
            return Err(e);
        }
        let wall = t0.elapsed().as_secs_f64();
        let member_ns = std::mem::take(&mut self.member_ns);
        self.account(&compiled, &run.records, wall, sim, k, &member_ns);
        self.member_ns = member_ns;
        if let Some(tr) = self.trace.as_mut() {
            tr.bases.lock().expect("trace bases").push(base);
            tr.writer.add_run(&compiled.graph, &run.records, tr.offset_ns);
            tr.offset_ns += run.wall_ns;
        }
        self.graphs.insert(k, compiled);
        // The first instability in step order, then block order.
        for kk in 0..k {
            for (b, blk) in sim.blocks.iter().enumerate() {
                if blk.is_held() && sim.is_unstable(&self.stats[kk * nb + b].lock().expect("stats")) {
                    return Ok(Some((kk, b)));
                }
            }
        }
        Ok(None)
    }
}

/// An instability report as bytes (to send it to the other ranks).
fn encode_instability(i: &Instability) -> Vec<u8> {
    let mut v = Vec::new();
    for x in [i.step, i.block as u64] {
        v.extend_from_slice(&x.to_le_bytes());
    }
    for x in i.block_coords.iter().chain(&i.cell) {
        v.extend_from_slice(&(*x as u64).to_le_bytes());
    }
    for x in [i.density, i.velocity[0], i.velocity[1], i.velocity[2], i.limit] {
        v.extend_from_slice(&x.to_bits().to_le_bytes());
    }
    v
}

/// The report of [`encode_instability`].
fn decode_instability(b: &[u8]) -> Instability {
    let u = |k: usize| u64::from_le_bytes(b[8 * k..8 * k + 8].try_into().expect("8 bytes"));
    let f = |k: usize| f64::from_bits(u(k));
    Instability {
        step: u(0),
        block: u(1) as usize,
        block_coords: [u(2) as usize, u(3) as usize, u(4) as usize],
        cell: [u(5) as usize, u(6) as usize, u(7) as usize],
        density: f(8),
        velocity: [f(9), f(10), f(11)],
        limit: f(12),
    }
}

/// Per-part CPU nanoseconds of one (step, block) of a graph run.
pub type BlockPartNs = ByPart<u64>;
