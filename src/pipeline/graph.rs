//! Building the step graph of `k` consecutive steps: the fluid tasks (`send`, `comm`, `boundary`,
//! `sweep`) and the particle tasks (`map`, `reconstruct`, `forces`, `rb`, `rb_sync`) with the edges the
//! module docs of [`super`] list.

use super::kinds::{spec, Payload, TaskKind};
use super::messages::Outgoing;
use crate::physics::block::Block;
use crate::physics::particles::Particles;
use blockflow_kernels::Real;
use blockflow_scheduler::{GraphBuilder, TaskId};

/// Adds the particle tasks of `k` consecutive steps for every active block: with the fluid (`coupled`),
/// `map` and `reconstruct` before the block's fluid tasks and `forces` after the boundary passes around
/// it; then `rb(b, s)` and `rb_sync(b, s)` for the S sub-steps (only `rb` under Jacobi). Edges as
/// documented in [`crate::physics::particles::tasks`] and [`crate::physics::coupling::tasks`]. With `no_skip` every block counts as
/// active and gets `map`/`reconstruct` even without fluid.
#[allow(clippy::too_many_arguments)] // the graph under construction and the state it is built from
pub(super) fn add_particle_tasks<T: Real>(
    g: &mut GraphBuilder,
    parts: &Particles,
    blocks: &[Block<T>],
    owners: &[u32],
    k: usize,
    fluid: &[Ids],
    coupled: bool,
    no_skip: bool,
) {
    let nb = parts.blocks.len();
    let s = parts.phases() as usize;
    let active: Vec<usize> = (0..nb).filter(|&b| no_skip || parts.active[b]).collect();
    let task = |b: usize, payload: Payload| spec(owners[b], b, payload);
    // Receivers of each block's interior layers inside the same process (their comm reads it directly).
    let mut local_receivers: Vec<Vec<usize>> = vec![Vec::new(); nb];
    for blk in blocks {
        for r in &blk.recv {
            if owners[r.from] == owners[blk.id] && r.from != blk.id {
                local_receivers[r.from].push(blk.id);
            }
        }
    }
    let mut sync: Vec<Option<TaskId>> = vec![None; nb];
    for kk in 0..k {
        let mut forces: Vec<Option<TaskId>> = vec![None; nb];
        if coupled {
            let mut maps: Vec<Option<TaskId>> = vec![None; nb];
            for &b in active.iter().filter(|&&b| no_skip || blocks[b].fluid_cells > 0) {
                let m = g.add(task(b, Payload::new(TaskKind::Map, kk)));
                let r = g.add(task(b, Payload::new(TaskKind::Reconstruct, kk)));
                g.edge(m, r);
                for &n in &parts.blocks[b].near {
                    if let Some(sp) = sync[n] {
                        g.edge(sp, m);
                    }
                }
                if kk > 0 {
                    if let Some(sw) = fluid[(kk - 1) * nb + b].sweep {
                        g.edge(sw, m);
                    }
                }
                let f = &fluid[kk * nb + b];
                if let Some(first) = f.comm.or(f.boundary).or(f.sweep) {
                    g.edge(r, first);
                }
                if let Some(sd) = f.send {
                    g.edge(r, sd);
                }
                for &n in &local_receivers[b] {
                    if let Some(c) = fluid[kk * nb + n].comm {
                        g.edge(r, c);
                    }
                }
                maps[b] = Some(m);
            }
            for &b in &active {
                let fo = g.add(task(b, Payload::new(TaskKind::Forces, kk)));
                for &n in &parts.blocks[b].near {
                    if let Some(x) = fluid[kk * nb + n].boundary.or(maps[n]) {
                        g.edge(x, fo);
                    }
                }
                if let Some(sp) = sync[b] {
                    g.edge(sp, fo);
                }
                forces[b] = Some(fo);
            }
        }
        for sub in 0..s {
            let mut new_rb: Vec<Option<TaskId>> = vec![None; nb];
            let mut new_sync: Vec<Option<TaskId>> = vec![None; nb];
            for &b in &active {
                new_rb[b] = Some(g.add(task(b, Payload::sub_step(TaskKind::Rb, kk, sub))));
            }
            // Without sync tasks (Jacobi) `rb` publishes, and it is what the next phase waits for.
            let with_sync = parts.has_sync_tasks();
            if with_sync {
                for &b in &active {
                    new_sync[b] = Some(g.add(task(b, Payload::sub_step(TaskKind::RbSync, kk, sub))));
                }
            }
            for &b in &active {
                let me_rb = new_rb[b].expect("active");
                for &n in &parts.blocks[b].near {
                    let before = if sub == 0 && coupled { forces[n] } else { sync[n] };
                    if let Some(prev) = before {
                        g.edge(prev, me_rb);
                    }
                    if let (Some(r), Some(me_sync)) = (new_rb[n], new_sync[b]) {
                        g.edge(r, me_sync);
                    }
                }
            }
            sync = if with_sync { new_sync } else { new_rb };
        }
    }
}

/// Task ids of one block and step.
#[derive(Clone, Copy, Default)]
pub(super) struct Ids {
    pub(super) send: Option<TaskId>,
    pub(super) comm: Option<TaskId>,
    pub(super) boundary: Option<TaskId>,
    pub(super) sweep: Option<TaskId>,
}

/// Adds the fluid tasks of `k` consecutive steps (see the module docs for tasks and edges). With
/// `no_skip` every block gets `comm`, `boundary` and `sweep` tasks, with or without fluid, ghost regions
/// or links (`send` stays where a message crosses processes: without one there is nothing to send).
pub(super) fn add_fluid_tasks<T: Real>(
    g: &mut GraphBuilder,
    blocks: &[Block<T>],
    owners: &[u32],
    outgoing: &[Vec<Outgoing>],
    k: usize,
    force_boundary: &[bool],
    no_skip: bool,
) -> Vec<Ids> {
    let nb = blocks.len();
    let mut ids = vec![Ids::default(); nb * k];
    // Within a step the send tasks get the lowest ids: a worker that finishes a task continues with its
    // lowest-id ready successor, so a block's sweep is followed at once by the message another process
    // is waiting for, and run roots are queued sends first.
    for s in 0..k {
        for b in blocks
            .iter()
            .filter(|b| (no_skip || b.fluid_cells > 0) && !outgoing[b.id].is_empty())
        {
            ids[s * nb + b.id].send = Some(g.add(spec(owners[b.id], b.id, Payload::new(TaskKind::Send, s))));
        }
        for b in blocks.iter().filter(|b| no_skip || b.fluid_cells > 0) {
            let owner = owners[b.id];
            let mk = |g: &mut GraphBuilder, kind: TaskKind| g.add(spec(owner, b.id, Payload::new(kind, s)));
            let id = &mut ids[s * nb + b.id];
            if no_skip || !b.recv.is_empty() {
                id.comm = Some(mk(g, TaskKind::Comm));
            }
            if no_skip || !b.links.is_empty() || force_boundary[b.id] {
                id.boundary = Some(mk(g, TaskKind::Boundary));
            }
            id.sweep = Some(mk(g, TaskKind::Sweep));
        }
    }
    let compute = |i: &Ids| i.boundary.or(i.sweep).expect("fluid block has a sweep");
    let first = |i: &Ids| i.comm.or(i.boundary).or(i.sweep).expect("fluid block has a sweep");
    for s in 0..k {
        for b in blocks.iter().filter(|b| no_skip || b.fluid_cells > 0) {
            let me = ids[s * nb + b.id];
            let sweep = me.sweep.expect("sweep");
            // own chain
            if let Some(c) = me.comm {
                g.edge(c, compute(&me));
            }
            if let Some(bd) = me.boundary {
                g.edge(bd, sweep);
            }
            if let Some(sd) = me.send {
                g.edge(sd, compute(&me));
            }
            if s + 1 < k {
                let next = ids[(s + 1) * nb + b.id];
                g.edge(sweep, first(&next));
                if let Some(sd) = next.send {
                    g.edge(sweep, sd);
                }
            }
            // neighbours
            if let Some(c) = me.comm {
                for r in &b.recv {
                    let n = ids[s * nb + r.from];
                    if owners[r.from] == owners[b.id] {
                        if r.from != b.id {
                            if s > 0 {
                                g.edge(ids[(s - 1) * nb + r.from].sweep.expect("sweep"), c);
                            }
                            g.edge(c, compute(&n));
                        }
                    } else {
                        g.edge(n.send.expect("remote sender has a send task"), c);
                        if s + 1 < k {
                            g.edge(c, ids[(s + 1) * nb + r.from].send.expect("send"));
                        }
                    }
                }
            }
        }
    }
    ids
}

/// `run.no_skip` only: a `static_map(b, s)` task per block and step that re-derives the block's static
/// geometry (flags, runs, links) and checks it against the one mapped at set-up. It reads only data no
/// task writes, so it needs no edge for safety; it is placed inside its step (after the block's sweep of
/// step s-1, before its first fluid task of step s) so that it is timed where a re-mapping would run.
pub(super) fn add_static_map_tasks<T: Real>(
    g: &mut GraphBuilder,
    blocks: &[Block<T>],
    owners: &[u32],
    k: usize,
    fluid: &[Ids],
) {
    let nb = blocks.len();
    for s in 0..k {
        for b in blocks {
            let t = g.add(spec(owners[b.id], b.id, Payload::new(TaskKind::StaticMap, s)));
            let f = &fluid[s * nb + b.id];
            if let Some(first) = f.comm.or(f.boundary).or(f.sweep) {
                g.edge(t, first);
            }
            if s > 0 {
                if let Some(sw) = fluid[(s - 1) * nb + b.id].sweep {
                    g.edge(sw, t);
                }
            }
        }
    }
}
