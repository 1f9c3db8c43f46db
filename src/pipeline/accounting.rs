//! Task accounting: every task's measured thread CPU time into the run's totals (per part, per kind, per
//! skip rule) and the record of the last graph run ([`RunRecord`]) that the time loop and its observers
//! read.

use super::kinds::{ByKind, Payload, TaskKind};
use super::messages::MessageSizes;
use super::skip::ByRule;
use super::{BlockPartNs, Compiled, Pipeline};
use crate::metrics::cost_model::{OwnedRun, RecordedRun};
use crate::physics::parts::{ByPart, Part};
use crate::physics::simulation::Simulation;
use blockflow_kernels::Real;
use blockflow_scheduler::{TaskGraph, TaskRecord};
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

/// Messages and bytes by what the messages carry.
pub type MessageCounts = BTreeMap<String, (u64, u64)>;

/// Totals over a run.
#[derive(Clone, Debug, Default)]
pub struct Totals {
    /// CPU seconds per part.
    pub part_cpu: ByPart<f64>,
    /// Tasks executed.
    pub tasks: u64,
    /// Cross-process message bytes.
    pub message_bytes: u64,
    /// Cross-process messages.
    pub remote_messages: u64,
    /// Ghost regions copied directly inside a process.
    pub local_copies: u64,
    /// Tasks executed per kind (index: [`super::kinds::TaskKind::index`]).
    pub tasks_by_kind: ByKind<u64>,
    /// CPU seconds per task kind.
    pub cpu_by_kind: ByKind<f64>,
    /// With `run.no_skip`: the work done only because a skip rule was off, per rule (index:
    /// [`super::SkipRule`] as `usize`): tasks that would not exist (`outside`, `no_boundary`,
    /// `no_particles`, `static_map`) and sweeps that took the general path instead of the fused kernel
    /// (`fused_kernel`). Zero without `run.no_skip`.
    pub unskipped: ByRule<u64>,
    /// With `run.no_skip`: CPU seconds of the work counted in `unskipped`, per rule (for `fused_kernel`
    /// the whole general-path sweeps of the fluid blocks, to be compared with the fused sweeps' time).
    pub unskipped_cpu: ByRule<f64>,
    /// Under ranks: the messages sent to other ranks, by what they carry — the kind of the task that
    /// sent them (`send`: ghost regions; `rb_sync`, `forces`: published bodies; `rb`: velocity changes;
    /// `boundary`, `map`: body forces), `halo` for the copies of the neighbours' particle state before
    /// each graph run, `migrate` for moved blocks — as (messages, bytes with their headers).
    pub rank_messages: MessageCounts,
    /// Under ranks: the bytes of those messages by destination rank (this rank's row; after
    /// [`Totals::summed`], one row per sending rank).
    pub rank_bytes: Vec<Vec<u64>>,
}

impl Totals {
    /// Counts one message of `bytes` bytes that this rank sent to rank `to` (of `ranks`), carrying `what`.
    pub fn count_message(&mut self, what: &str, to: usize, ranks: usize, bytes: usize) {
        let e = self.rank_messages.entry(what.to_string()).or_default();
        e.0 += 1;
        e.1 += bytes as u64;
        if self.rank_bytes.is_empty() {
            self.rank_bytes = vec![vec![0; ranks]];
        }
        self.rank_bytes[0][to] += bytes as u64;
    }

    /// The totals of every rank of `world` added up (rank order), on every rank.
    pub fn summed(&self, world: &crate::ranks::World) -> crate::error::Result<Totals> {
        if world.is_single() {
            return Ok(self.clone());
        }
        let mut words: Vec<u64> = vec![self.tasks, self.message_bytes, self.remote_messages, self.local_copies];
        words.extend(self.tasks_by_kind);
        words.extend(self.unskipped);
        let mut floats: Vec<f64> = Part::ALL.iter().map(|&p| self.part_cpu[p]).collect();
        floats.extend(self.cpu_by_kind);
        floats.extend(self.unskipped_cpu);
        let bytes: Vec<u8> = words
            .iter()
            .copied()
            .chain(floats.iter().map(|f| f.to_bits()))
            .flat_map(|w| w.to_le_bytes())
            .collect();
        let mut out = Totals::default();
        for r in world.allgather(&bytes)? {
            let w: Vec<u64> = r
                .chunks_exact(8)
                .map(|c| u64::from_le_bytes(c.try_into().expect("8")))
                .collect();
            let (ints, fl) = w.split_at(words.len());
            let fl: Vec<f64> = fl.iter().map(|&b| f64::from_bits(b)).collect();
            out.tasks += ints[0];
            out.message_bytes += ints[1];
            out.remote_messages += ints[2];
            out.local_copies += ints[3];
            let (k, rest) = ints[4..].split_at(out.tasks_by_kind.len());
            out.tasks_by_kind.iter_mut().zip(k).for_each(|(a, b)| *a += b);
            out.unskipped.iter_mut().zip(rest).for_each(|(a, b)| *a += b);
            let (p, rest) = fl.split_at(Part::ALL.len());
            for (i, &part) in Part::ALL.iter().enumerate() {
                out.part_cpu[part] += p[i];
            }
            let (k, rest) = rest.split_at(out.cpu_by_kind.len());
            out.cpu_by_kind.iter_mut().zip(k).for_each(|(a, b)| *a += b);
            out.unskipped_cpu.iter_mut().zip(rest).for_each(|(a, b)| *a += b);
        }
        let mine = serde_json::to_vec(&(&self.rank_messages, self.rank_bytes.first())).expect("serialises");
        for r in world.allgather(&mine)? {
            let (m, row): (MessageCounts, Option<Vec<u64>>) =
                serde_json::from_slice(&r).expect("counts from a rank of this run");
            for (k, (n, b)) in m {
                let e = out.rank_messages.entry(k).or_default();
                e.0 += n;
                e.1 += b;
            }
            out.rank_bytes.push(row.unwrap_or_else(|| vec![0; world.ranks()]));
        }
        Ok(out)
    }
}

/// What the last graph run recorded (owned by the pipeline, lent out as a [`RunRecord`]).
#[derive(Clone, Debug, Default)]
pub(super) struct LastRun {
    pub(super) steps: usize,
    pub(super) durations_ns: Vec<u64>,
    pub(super) wall_seconds: f64,
    pub(super) block_load: Vec<f64>,
    pub(super) message_bytes: u64,
    pub(super) block_part_ns: Vec<BlockPartNs>,
}

/// The record of one graph run.
#[derive(Clone, Copy)]
pub struct RunRecord<'a> {
    /// The graph that ran.
    pub graph: &'a Arc<TaskGraph>,
    /// Thread CPU nanoseconds of every task (index = task id).
    pub durations_ns: &'a [u64],
    /// Steps of the run.
    pub steps: usize,
    /// Wall-clock seconds of the run.
    pub wall_seconds: f64,
    /// Workload m_tot (eq. 16: CPU seconds of every task but the exchange) per block, in block-id order.
    pub block_load: &'a [f64],
    /// Bytes of the cross-process messages of the run.
    pub message_bytes: u64,
    /// With [`super::PipelineConfig::block_parts`]: CPU nanoseconds per part of every (step in the run,
    /// block), index `step * blocks + block`: the m_X of section 3.
    pub block_part_ns: Option<&'a [BlockPartNs]>,
    /// What the ghost-region edges carry.
    pub sizes: &'a Arc<MessageSizes>,
}

impl<'a> RunRecord<'a> {
    /// The run as the cost model sees it.
    pub fn recorded(&self) -> RecordedRun<'a> {
        RecordedRun {
            graph: self.graph,
            durations_ns: self.durations_ns,
            steps: self.steps,
            tasks: &**self.sizes,
        }
    }

    /// The run with copies of what it refers to, to be modeled elsewhere.
    pub fn owned(&self) -> OwnedRun {
        OwnedRun {
            graph: self.graph.clone(),
            durations_ns: self.durations_ns.to_vec(),
            steps: self.steps,
            tasks: self.sizes.clone(),
        }
    }
}

impl<T: Real> Pipeline<T> {
    /// Adds one graph run's task times to the totals and keeps them as the last run; a grouped round's
    /// time goes to its members by their times `member_ns` (per step in the run and block).
    pub(super) fn account(
        &mut self,
        compiled: &Compiled,
        records: &[TaskRecord],
        wall: f64,
        sim: &Simulation<T>,
        k: usize,
        member_ns: &[AtomicU64],
    ) {
        let graph = &*compiled.graph;
        let rounds = sim.particles.as_ref().map_or(1, |p| p.rounds);
        let nb = sim.blocks.len();
        let held: Vec<bool> = (0..nb).map(|b| self.local_process(b).is_some()).collect();
        let last = &mut self.last;
        last.steps = k;
        last.wall_seconds = wall;
        last.durations_ns.clear();
        last.block_load.clear();
        last.block_load.resize(nb, 0.0);
        let record_parts = self.settings.block_parts;
        if record_parts {
            last.block_part_ns.clear();
            last.block_part_ns.resize(k * nb, ByPart::default());
        }
        let rule_of = self.counts.get(&k).map(|c| c.rule_of.as_slice()).unwrap_or(&[]);
        let t = &mut self.totals;
        for (i, (spec, r)) in graph.specs().iter().zip(records).enumerate() {
            let cpu = r.cpu_ns as f64 * 1e-9;
            let part = Part::from_index(spec.part);
            let payload = Payload::of(spec);
            t.part_cpu[part] += cpu;
            t.cpu_by_kind[payload.kind.index()] += cpu;
            if let Some(Some(rule)) = rule_of.get(i) {
                t.unskipped_cpu[*rule as usize] += cpu;
            }
            // A group's task time is shared among its members by their monotonic time in the step's
            // grouped rounds (equally where none was measured).
            let one = [spec.block as usize];
            let blocks = match payload.kind {
                TaskKind::Rb | TaskKind::RbSync => {
                    compiled.groups.members(one[0], payload.sub % rounds).unwrap_or(&one)
                }
                _ => &one,
            };
            let ns = |b: usize| {
                member_ns
                    .get(payload.step * nb + b)
                    .map_or(0, |x| x.load(Ordering::Relaxed))
            };
            let measured: u64 = if blocks.len() > 1 {
                blocks.iter().map(|&b| ns(b)).sum()
            } else {
                0
            };
            for &b in blocks {
                let share = if measured > 0 {
                    ns(b) as f64 / measured as f64
                } else {
                    1.0 / blocks.len() as f64
                };
                if record_parts {
                    last.block_part_ns[payload.step * nb + b][part] += (r.cpu_ns as f64 * share).round() as u64;
                }
                if part.is_workload() {
                    last.block_load[b] += cpu * share;
                }
            }
            last.durations_ns.push(r.cpu_ns);
        }
        t.tasks += records.len() as u64;
        if let Some(c) = self.counts.get(&k) {
            for (x, n) in t.tasks_by_kind.iter_mut().zip(c.by_kind) {
                *x += n;
            }
            for (x, n) in t.unskipped.iter_mut().zip(c.by_rule) {
                *x += n;
            }
        }
        // Under ranks each rank counts what its own blocks send and receive.
        let mine = |b: usize| held[b];
        let (bytes, remote) = self.plan.remote_per_step(sim, mine);
        let regions: u64 = sim
            .blocks
            .iter()
            .filter(|b| mine(b.id))
            .map(|b| b.recv.len() as u64)
            .sum();
        let received: u64 = sim
            .blocks
            .iter()
            .filter(|b| mine(b.id))
            .map(|b| self.plan.slot_of[b.id].iter().filter(|s| s.is_some()).count() as u64)
            .sum();
        let local = regions - received;
        t.message_bytes += bytes * k as u64;
        t.remote_messages += remote * k as u64;
        t.local_copies += local * k as u64;
        last.message_bytes = bytes * k as u64;
    }
}
