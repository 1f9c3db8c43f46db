//! The step graph on ranks that share no memory: each rank runs the tasks of the blocks it owns, and
//! every edge of the step graph between two ranks becomes a message.
//!
//! Every rank builds the same global graph (from the same block structure, owners, active blocks and
//! shape flags) and keeps its own tasks ([`RankGraph`]). An edge from a task of another rank becomes an
//! *external dependency* of the local task (the driver releases it when the producer's message has
//! arrived and been put in place); an edge to a task of another rank makes the local task send a message
//! to that rank when it finishes (one per producer and destination rank, whatever the number of tasks it
//! releases there). What the message carries is what the consumer reads of the producer's block, as
//! bytes of its exact bits, and the receiver puts it where the shared-memory code reads it, so every task
//! computes from the same bits in either mode:
//!
//! | producer → consumer | message | put where |
//! |---|---|---|
//! | `send(n, s)` → `comm(b, s)` | the ghost regions of the destination's blocks, packed | a buffer per (sender, step of the run), read by `comm` |
//! | `rb_sync(n, g)` → `rb(b, g + 1)`, `map(b, t)` | n's published list of parity g | the copy of n's list |
//! | `forces(n, t)` → `rb(b, first phase)` | n's published list, forces set | the copy of n's list |
//! | `rb(n, g)` → `rb_sync(b, g)` | n's velocity changes | the copy of n's `work` |
//! | `rb(n, g)` → `rb(b, g + 1)`, `map(b, t)` (Jacobi: no `rb_sync`) | n's published list of parity g | the copy of n's list |
//! | `boundary(n, t)` or `map(n, t)` → `forces(b, t)` | n's body forces | [`crate::physics::block::Block::set_remote_forces`] |
//!
//! The slot-reuse edges `comm(b, s) → send(n, s + 1)` carry nothing between ranks: a received region has
//! a buffer per step of the run, so there is no slot to reuse, and they are dropped.
//!
//! A copy is overwritten only when the message that replaces it arrives, which is after the producer
//! ran; in the global graph the producer comes after every task that read the old contents (the edges
//! that order those accesses in shared memory), and every path between ranks is a chain of messages, so
//! the old contents are no longer read when the new ones arrive. Messages carry their producer and the
//! first step of their graph run in a header.
//!
//! Before each graph run, with particles, every rank sends the particle state of each of its blocks
//! (published list, velocity changes, body forces) to the ranks that own one of its neighbours
//! ([`halo`]): the copies then hold what the owners hold at the start of the run, whatever the
//! migrations or the graph runs before.

use super::kinds::{Payload, TaskKind};
use crate::error::{Error, Result};
use crate::physics::block::Block;
use crate::physics::fluid;
use crate::physics::particles::Particles;
use crate::physics::simulation::Simulation;
use crate::ranks::{class, World};
use crate::serialise::halo::{
    decode_deltas, decode_forces, decode_published, encode_deltas, encode_forces, encode_published,
};
use crate::util::bytes::Reader;
use blockflow_kernels::Real;
use blockflow_scheduler::executor::Releaser;
use blockflow_scheduler::transport::Tag;
use blockflow_scheduler::{GraphBuilder, TaskGraph, TaskId, TaskSpec};
use std::collections::HashMap;
use std::sync::Mutex;

/// The task whose completion sends a message: its kind, block, step in the graph run and phase.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub(super) struct Producer {
    kind: TaskKind,
    block: u32,
    step: u32,
    sub: u32,
}

impl Producer {
    fn of(spec: &TaskSpec) -> Self {
        let p = Payload::of(spec);
        Producer {
            kind: p.kind,
            block: spec.block,
            step: p.step as u32,
            sub: p.sub as u32,
        }
    }
}

/// Bytes of a graph message's header: producer kind, block, step, phase, and the first step of the run.
const HEADER: usize = 1 + 4 + 4 + 4 + 8;

fn header(p: Producer, base: u64) -> Vec<u8> {
    let mut v = Vec::with_capacity(HEADER + 256);
    v.push(p.kind as u8);
    v.extend_from_slice(&p.block.to_le_bytes());
    v.extend_from_slice(&p.step.to_le_bytes());
    v.extend_from_slice(&p.sub.to_le_bytes());
    v.extend_from_slice(&base.to_le_bytes());
    v
}

fn read_header(b: &[u8]) -> Option<(Producer, u64)> {
    let kind = *TaskKind::ALL.get(*b.first()? as usize)?;
    let u32_at = |at: usize| Some(u32::from_le_bytes(b.get(at..at + 4)?.try_into().ok()?));
    let base = u64::from_le_bytes(b.get(13..21)?.try_into().ok()?);
    Some((
        Producer {
            kind,
            block: u32_at(1)?,
            step: u32_at(5)?,
            sub: u32_at(9)?,
        },
        base,
    ))
}

/// The edges between ranks that carry nothing (see the module docs).
fn carries_nothing(from: TaskKind, to: TaskKind) -> bool {
    from == TaskKind::Comm && to == TaskKind::Send
}

/// The messages of one rank's share of a step graph.
pub(super) struct RankGraph {
    /// Per local task: the ranks its completion sends its message to, ascending.
    pub(super) post: Vec<Vec<u32>>,
    /// Per message this rank waits for: the local tasks it releases.
    pub(super) expect: HashMap<Producer, Vec<TaskId>>,
}

impl RankGraph {
    /// The share of rank `me` of `global` (whose task owners are ranks): its tasks (all owned by its
    /// executor's one process) with their external dependencies, and their messages.
    pub(super) fn project(global: &TaskGraph, me: u32) -> (TaskGraph, Self) {
        let n = global.len();
        let mut local: Vec<Option<TaskId>> = vec![None; n];
        let mut g = GraphBuilder::new();
        for (t, spec) in global.specs().iter().enumerate() {
            if spec.owner == me {
                local[t] = Some(g.add(TaskSpec { owner: 0, ..*spec }));
            }
        }
        let mut post: Vec<Vec<u32>> = vec![Vec::new(); g.len()];
        let mut expect: HashMap<Producer, Vec<TaskId>> = HashMap::new();
        for (t, spec) in global.specs().iter().enumerate() {
            for &s in global.successors(t as TaskId) {
                let to = global.spec(s);
                let (from_kind, to_kind) = (Payload::of(spec).kind, Payload::of(to).kind);
                match (local[t], local[s as usize]) {
                    (Some(a), Some(b)) => g.edge(a, b),
                    (None, Some(b)) if !carries_nothing(from_kind, to_kind) => {
                        g.external(b, 1);
                        expect.entry(Producer::of(spec)).or_default().push(b);
                    }
                    (Some(a), None) if !carries_nothing(from_kind, to_kind) => {
                        let list = &mut post[a as usize];
                        if !list.contains(&to.owner) {
                            list.push(to.owner);
                        }
                    }
                    _ => {}
                }
            }
        }
        for list in &mut post {
            list.sort_unstable();
        }
        (
            g.build().expect("a part of an acyclic graph is acyclic"),
            RankGraph { post, expect },
        )
    }
}

/// The regions a block sends to one rank, as (receiving block, index in its `recv`), in packing order.
pub(super) type RegionsTo = (u32, Vec<(usize, usize)>);

/// The ghost regions that cross ranks, seen from one rank: what each of its blocks sends to which rank,
/// and where each region it receives lies in which message.
pub(super) struct RankGhosts {
    /// Per block (this rank's; empty for the others): per destination rank, ascending, the regions it
    /// sends there as (receiving block, index in its `recv`), in the order they are packed.
    pub(super) outgoing: Vec<Vec<RegionsTo>>,
    /// Per (receiving block of this rank, index in its `recv`) with a sender on another rank: the sender's
    /// buffer slot and the byte range of the region in the sender's message (after the header).
    pub(super) incoming: Vec<Vec<Option<(usize, usize, usize)>>>,
    /// The buffer slot of each sending block of another rank.
    slot_of: HashMap<u32, usize>,
    /// Received ghost messages, per (sender slot, step of the run): `slot * steps + step`.
    buffers: Vec<Mutex<Vec<u8>>>,
    /// Steps per graph run at most.
    steps: usize,
}

impl RankGhosts {
    /// The ghost plan of rank `me` under `owners` (block → rank), for graph runs of up to `steps` steps.
    pub(super) fn new<T: Real>(sim: &Simulation<T>, owners: &[u32], me: u32, steps: usize) -> Self {
        let nb = sim.blocks.len();
        let mut outgoing: Vec<Vec<RegionsTo>> = vec![Vec::new(); nb];
        // Regions in receiver order, then region order: the order a sender packs them in.
        for b in &sim.blocks {
            for (r, g) in b.recv.iter().enumerate() {
                let (from, to) = (owners[g.from], owners[b.id]);
                if from == to || from != me {
                    continue;
                }
                let list = &mut outgoing[g.from];
                match list.iter_mut().find(|(d, _)| *d == to) {
                    Some((_, v)) => v.push((b.id, r)),
                    None => list.push((to, vec![(b.id, r)])),
                }
            }
        }
        for list in &mut outgoing {
            list.sort_by_key(|(d, _)| *d);
        }
        let mut slot_of = HashMap::new();
        let mut offsets: HashMap<u32, usize> = HashMap::new();
        let mut incoming = Vec::with_capacity(nb);
        for b in &sim.blocks {
            let mut v = Vec::with_capacity(b.recv.len());
            for g in &b.recv {
                if owners[b.id] != me || owners[g.from] == me {
                    v.push(None);
                    continue;
                }
                let next = slot_of.len();
                let slot = *slot_of.entry(g.from as u32).or_insert(next);
                let at = offsets.entry(g.from as u32).or_insert(0);
                let len = fluid::region_values(&b.layout, g.offset, &g.directions) * T::BYTES;
                v.push(Some((slot, *at, len)));
                *at += len;
            }
            incoming.push(v);
        }
        let buffers = (0..slot_of.len() * steps).map(|_| Mutex::new(Vec::new())).collect();
        RankGhosts {
            outgoing,
            incoming,
            slot_of,
            buffers,
            steps,
        }
    }

    /// Unpacks region `r` of block `b` (from another rank) at step `step` of the run into the state of
    /// parity `p`.
    pub(super) fn unpack<T: Real>(&self, b: &Block<T>, r: usize, step: usize, p: usize) {
        let (slot, at, len) = self.incoming[b.id][r].expect("a region from another rank");
        let g = &b.recv[r];
        let msg = self.buffers[slot * self.steps + step].lock().expect("ghost buffer");
        fluid::unpack_bytes(b, p, g.offset, &g.directions, &msg[HEADER + at..HEADER + at + len]);
    }
}

/// What a rank's tasks queue for the driver to send: (destination rank, bytes).
pub(super) type Outbox = Mutex<Vec<(u32, Vec<u8>)>>;

/// Whether a task of kind `kind` ends a rigid-body phase by publishing its block's list: `rb_sync`, or
/// `rb` under a solver without sync tasks (Jacobi). Its message is that list.
fn publishes(kind: TaskKind, parts: &Particles) -> bool {
    kind == TaskKind::RbSync || (kind == TaskKind::Rb && !parts.has_sync_tasks())
}

/// The messages of one finished local task (see the module table): sent at once when the transport lets
/// any thread send, else (or when the send fails) queued in `outbox` for the driver; each sent one is
/// logged in `log`. Returns whether the outbox was empty before something was queued (then the driver
/// may be parked and should be woken).
///
/// # Safety
/// Called by the task that just ran `spec`, before its successors start: it reads what that task wrote.
pub(super) unsafe fn post<T: Real>(
    sim: &Simulation<T>,
    ghosts: &RankGhosts,
    dests: &[u32],
    spec: &TaskSpec,
    base: u64,
    outbox: &Outbox,
    (world, log): (&World, &SentLog),
) -> bool {
    if dests.is_empty() {
        return false;
    }
    let producer = Producer::of(spec);
    let b = spec.block as usize;
    let step = base + producer.step as u64;
    let mut out = Vec::with_capacity(dests.len());
    if producer.kind == TaskKind::Send {
        let blk = &sim.blocks[b];
        let p = (step % 2) as usize;
        for (dest, regions) in &ghosts.outgoing[b] {
            let mut bytes = header(producer, base);
            for &(rb, r) in regions {
                let g = &sim.blocks[rb].recv[r];
                fluid::pack_bytes(blk, p, g.offset, &g.directions, &mut bytes);
            }
            out.push((*dest, bytes));
        }
    } else {
        let mut bytes = header(producer, base);
        let parts = || sim.particles.as_ref().expect("particle tasks only with particles");
        match producer.kind {
            k if publishes(k, parts()) => {
                let g = step * parts().phases() + producer.sub as u64 + 1;
                encode_published(parts().blocks[b].published((g % 2) as usize), &mut bytes)
            }
            TaskKind::Forces => encode_published(parts().blocks[b].published(parts().parity(step)), &mut bytes),
            TaskKind::Rb => encode_deltas(&parts().blocks[b].work().deltas, &mut bytes),
            TaskKind::Boundary | TaskKind::Map => encode_forces(sim.blocks[b].body_forces(), &mut bytes),
            k => unreachable!("a {} task has no message between ranks", k.name()),
        }
        for &d in dests {
            out.push((d, bytes.clone()));
        }
    }
    if world.transport().sends_from_any_thread() {
        let t = world.transport();
        let mut left = Vec::new();
        for (to, bytes) in out {
            let n = bytes.len();
            match t.send(to as usize, Tag::new(class::GRAPH, 0), bytes.clone()) {
                Ok(()) => log.lock().expect("sent log").push((to, producer.kind, n)),
                Err(_) => left.push((to, bytes)),
            }
        }
        out = left;
        if out.is_empty() {
            return false;
        }
    }
    let mut queue = outbox.lock().expect("outbox");
    let was_empty = queue.is_empty();
    queue.extend(out);
    was_empty
}

/// The messages a rank sent in a graph run: (destination rank, kind of the task that sent it, bytes).
pub(super) type SentLog = Mutex<Vec<(u32, TaskKind, usize)>>;

/// The driver's side of a graph run on ranks: sends what the tasks queued, receives the messages of
/// other ranks, puts them in place and releases the tasks waiting for them.
pub(super) struct Driver<'a, T: Real> {
    pub(super) sim: &'a Simulation<T>,
    pub(super) world: &'a World,
    pub(super) ghosts: &'a RankGhosts,
    pub(super) graph: &'a RankGraph,
    pub(super) outbox: &'a Outbox,
    /// The first step of the run.
    pub(super) base: u64,
    /// A failure met while driving (a message that does not fit, another rank's abort).
    pub(super) error: Option<Error>,
    /// The messages sent.
    pub(super) sent: &'a SentLog,
}

impl<T: Real> Driver<'_, T> {
    /// One round of progress (see `Executor::run_with_progress`).
    pub(super) fn progress(&mut self, rel: &mut Releaser<'_>) -> bool {
        match self.round(rel) {
            Ok(did) => did,
            Err(e) => {
                self.error.get_or_insert(e);
                rel.cancel();
                false
            }
        }
    }

    fn round(&mut self, rel: &mut Releaser<'_>) -> Result<bool> {
        let t = self.world.transport();
        let queued = std::mem::take(&mut *self.outbox.lock().expect("outbox"));
        let mut did = !queued.is_empty();
        for (to, bytes) in queued {
            let kind = TaskKind::ALL[bytes[0] as usize];
            self.sent.lock().expect("sent log").push((to, kind, bytes.len()));
            t.send(to as usize, Tag::new(class::GRAPH, 0), bytes)
                .map_err(|e| self.world.error(e))?;
        }
        t.poll().map_err(|e| self.world.error(e))?;
        while let Some((from, _, bytes)) = t.try_recv_any(class::GRAPH).map_err(|e| self.world.error(e))? {
            did = true;
            self.arrived(from, bytes, rel)?;
        }
        Ok(did)
    }

    fn arrived(&mut self, from: usize, bytes: Vec<u8>, rel: &mut Releaser<'_>) -> Result<()> {
        let bad = |m: String| Error::Aborted {
            rank: self.world.rank(),
            code: 70,
            message: format!("a message from rank {from} {m}; this is a bug, please report it"),
        };
        let (p, base) = read_header(&bytes).ok_or_else(|| bad("has no valid header".into()))?;
        if base != self.base {
            return Err(bad(format!(
                "belongs to the graph run from step {base}, this rank runs the one from step {}",
                self.base
            )));
        }
        let consumers = self
            .graph
            .expect
            .get(&p)
            .ok_or_else(|| bad(format!("from {p:?} was not expected")))?;
        let b = p.block as usize;
        let step = self.base + p.step as u64;
        let fail = |e: crate::serialise::FormatError| bad(format!("from {p:?} does not decode: {e}"));
        if p.kind == TaskKind::Send {
            let slot = self.ghosts.slot_of[&p.block];
            *self.ghosts.buffers[slot * self.ghosts.steps + p.step as usize]
                .lock()
                .expect("ghost buffer") = bytes;
        } else {
            let parts = self
                .sim
                .particles
                .as_ref()
                .expect("particle messages only with particles");
            let mut r = Reader::new(&bytes[HEADER..], "graph message");
            // SAFETY: the tasks that read the copies replaced here have finished, and those that read
            // the new contents wait for the release below (module docs).
            unsafe {
                match p.kind {
                    _ if publishes(p.kind, parts) => {
                        let g = step * parts.phases() + p.sub as u64 + 1;
                        let list = decode_published(&mut r, parts.blocks.len()).map_err(fail)?;
                        parts.blocks[b].replace_published((g % 2) as usize, list);
                    }
                    TaskKind::Forces => {
                        let list = decode_published(&mut r, parts.blocks.len()).map_err(fail)?;
                        parts.blocks[b].replace_published(parts.parity(step), list);
                    }
                    TaskKind::Rb => parts.blocks[b].set_deltas(decode_deltas(&mut r).map_err(fail)?),
                    TaskKind::Boundary | TaskKind::Map => {
                        self.sim.blocks[b].set_remote_forces(decode_forces(&mut r).map_err(fail)?)
                    }
                    k => return Err(bad(format!("names a {} task", k.name()))),
                }
            }
        }
        for &c in consumers {
            rel.release(c);
        }
        Ok(())
    }
}

/// The blocks of other ranks among the neighbours of this rank's blocks (whose particle state this rank
/// keeps copies of), ascending.
pub(super) fn halo_blocks(parts: &Particles, owners: &[u32], me: u32) -> Vec<usize> {
    let mut v: Vec<usize> = (0..owners.len())
        .filter(|&b| owners[b] == me)
        .flat_map(|b| parts.blocks[b].near.iter().copied())
        .filter(|&n| owners[n] != me)
        .collect();
    v.sort_unstable();
    v.dedup();
    v
}

/// Sends the particle state of every block of this rank to the ranks that own one of its neighbours
/// (published list of the current parity, velocity changes, body forces) and puts the copies other ranks
/// send into place (see the module docs). Call between graph runs, on every rank at once. Returns the
/// messages sent as (destination rank, bytes).
pub(super) fn halo<T: Real>(sim: &Simulation<T>, owners: &[u32], world: &World) -> Result<Vec<(u32, usize)>> {
    let mut sent = Vec::new();
    let Some(parts) = sim.particles.as_ref() else {
        return Ok(sent);
    };
    let me = world.rank() as u32;
    let t = world.transport();
    let tag = Tag::new(class::HALO, 0);
    let par = parts.parity(sim.step);
    for b in (0..owners.len()).filter(|&b| owners[b] == me) {
        let mut dests: Vec<u32> = parts.blocks[b]
            .near
            .iter()
            .map(|&n| owners[n])
            .filter(|&o| o != me)
            .collect();
        dests.sort_unstable();
        dests.dedup();
        if dests.is_empty() {
            continue;
        }
        let mut bytes = (b as u32).to_le_bytes().to_vec();
        // SAFETY: between graph runs.
        unsafe {
            encode_published(parts.blocks[b].published(par), &mut bytes);
            encode_deltas(&parts.blocks[b].work().deltas, &mut bytes);
        }
        encode_forces(sim.blocks[b].body_forces(), &mut bytes);
        for d in dests {
            sent.push((d, bytes.len()));
            t.send(d as usize, tag, bytes.clone()).map_err(|e| world.error(e))?;
        }
    }
    let want = halo_blocks(parts, owners, me);
    let mut got = 0;
    while got < want.len() {
        t.poll().map_err(|e| world.error(e))?;
        let Some((from, _, bytes)) = t.try_recv_any(class::HALO).map_err(|e| world.error(e))? else {
            std::thread::yield_now();
            continue;
        };
        let bad = |m: String| Error::Aborted {
            rank: world.rank(),
            code: 70,
            message: format!("a particle halo from rank {from} {m}; this is a bug, please report it"),
        };
        let b = u32::from_le_bytes(bytes[..4].try_into().map_err(|_| bad("is empty".into()))?) as usize;
        if want.binary_search(&b).is_err() {
            return Err(bad(format!("names block {b}, which this rank does not keep a copy of")));
        }
        let mut r = Reader::new(&bytes[4..], "particle halo");
        let fail = |e: crate::serialise::FormatError| bad(format!("of block {b} does not decode: {e}"));
        let list = decode_published(&mut r, parts.blocks.len()).map_err(fail)?;
        let deltas = decode_deltas(&mut r).map_err(fail)?;
        let forces = decode_forces(&mut r).map_err(fail)?;
        // SAFETY: between graph runs.
        unsafe {
            parts.blocks[b].replace_published(par, list);
            parts.blocks[b].set_deltas(deltas);
            sim.blocks[b].set_remote_forces(forces);
        }
        got += 1;
    }
    Ok(sent)
}
