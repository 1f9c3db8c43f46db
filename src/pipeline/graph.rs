//! Building the step graph of `k` consecutive steps: the fluid tasks (`send`, `comm`, `boundary`,
//! `sweep`) and the particle tasks (`map`, `reconstruct`, `forces`, `rb`, `rb_sync`) with the edges the
//! module docs of [`super`] list.

use super::kinds::{spec, Payload, TaskKind};
use super::messages::Outgoing;
use crate::physics::block::Block;
use crate::physics::particles::Particles;
use blockflow_kernels::Real;
use blockflow_scheduler::{GraphBuilder, TaskId};

/// Which blocks' Jacobi sweep rounds may share an `rb` task ([`SweepGroups`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Grouping {
    /// One task per block and round: `run.no_skip` counts every task under its own block's skip rule.
    Off,
    /// Every process's active blocks (a world of one rank).
    Processes,
    /// Rank `me`'s blocks whose neighbours are all its own. A block next to another rank's keeps a task
    /// per round, which posts its velocities to that rank; another rank's block is never grouped here,
    /// so every rank's graph has the same tasks wherever an edge crosses ranks.
    Rank(u32),
}

/// Adds the particle tasks of `k` consecutive steps for every active block: with the fluid (`coupled`),
/// `map` and `reconstruct` before the block's fluid tasks and `forces` after the boundary passes around
/// it; then `rb(b, s)` and `rb_sync(b, s)` for the S sub-steps (only `rb` under Jacobi). Edges as
/// documented in [`crate::physics::particles::tasks`] and [`crate::physics::coupling::tasks`]. With `no_skip` every block counts as
/// active and gets `map`/`reconstruct` even without fluid. Under Jacobi with `grouping` other than
/// [`Grouping::Off`], the sweep rounds run one task per [`SweepGroups`] group (returned; empty
/// otherwise), after every task of the round before that covers a neighbour of a member.
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
    grouping: Grouping,
) -> SweepGroups {
    let nb = parts.blocks.len();
    let s = parts.phases() as usize;
    let active: Vec<usize> = (0..nb).filter(|&b| no_skip || parts.active[b]).collect();
    let groups = sweep_groups(parts, owners, &active, grouping);
    let task = |b: usize, payload: Payload| spec(owners[b], b, payload);
    let mut sync: Vec<Option<TaskId>> = vec![None; nb];
    for kk in 0..k {
        let forces = if coupled {
            add_coupling_tasks(g, parts, blocks, owners, kk, fluid, &active, &sync, no_skip)
        } else {
            vec![None; nb]
        };
        for sub in 0..s {
            if groups.runs_round(sub % parts.rounds) {
                sync = add_grouped_round(g, parts, owners, &groups, kk, sub, &sync);
                continue;
            }
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
    groups
}

/// The [`SweepGroups`] of the `active` blocks under `grouping` (none under block Gauss–Seidel, whose
/// rounds have sync tasks).
fn sweep_groups(parts: &Particles, owners: &[u32], active: &[usize], grouping: Grouping) -> SweepGroups {
    if grouping == Grouping::Off || parts.has_sync_tasks() {
        return SweepGroups::default();
    }
    // SAFETY: the graph is built between runs; no `rb` task runs.
    let contacts = |b: usize| unsafe { parts.blocks[b].work().contact_list.len() };
    let alone = |b: usize| match grouping {
        Grouping::Rank(me) => owners[b] != me || parts.blocks[b].near.iter().any(|&n| owners[n] != me),
        _ => false,
    };
    SweepGroups::new(parts.blocks.len(), owners, active, contacts, alone)
}

/// Adds `map`, `reconstruct` and `forces` of step `kk` for the `active` blocks (`map` and `reconstruct`
/// only where the block has fluid, or everywhere with `no_skip`), after the last rigid-body tasks `sync`
/// of the step before; returns each block's `forces` task.
#[allow(clippy::too_many_arguments)] // the graph under construction and the state it is built from
fn add_coupling_tasks<T: Real>(
    g: &mut GraphBuilder,
    parts: &Particles,
    blocks: &[Block<T>],
    owners: &[u32],
    kk: usize,
    fluid: &[Ids],
    active: &[usize],
    sync: &[Option<TaskId>],
    no_skip: bool,
) -> Vec<Option<TaskId>> {
    let nb = parts.blocks.len();
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
    let mut forces: Vec<Option<TaskId>> = vec![None; nb];
    for &b in active {
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
    forces
}

/// Adds sweep round `sub` of step `kk` as one `rb` task per group of `groups`, after every task of the
/// round before (`sync`) that covers a neighbour of a member (the graph's build drops the repeated
/// edges); returns each member's task.
fn add_grouped_round(
    g: &mut GraphBuilder,
    parts: &Particles,
    owners: &[u32],
    groups: &SweepGroups,
    kk: usize,
    sub: usize,
    sync: &[Option<TaskId>],
) -> Vec<Option<TaskId>> {
    let mut new_rb: Vec<Option<TaskId>> = vec![None; parts.blocks.len()];
    for (first, members) in groups.iter() {
        let t = g.add(spec(owners[first], first, Payload::sub_step(TaskKind::Rb, kk, sub)));
        for &m in members {
            new_rb[m] = Some(t);
            for &n in &parts.blocks[m].near {
                if let Some(prev) = sync[n] {
                    g.edge(prev, t);
                }
            }
        }
    }
    new_rb
}

/// Contacts per `rb` task of a Jacobi sweep round at most, unless one block has more: a sweep costs
/// tens of nanoseconds per contact and a task about half a microsecond to schedule and release.
const GROUP_CONTACTS: usize = 32;

/// Under the Jacobi solver, the blocks whose sweep rounds (rounds 1 … I of a sub-step) one `rb` task
/// runs: every process's active blocks in id order, cut into runs whose blocks solved at most
/// [`GROUP_CONTACTS`] contacts in their last sub-step together (a block with more is a run of its own).
/// Most blocks have few contacts or none and a sweep round only publishes their velocities, so one task
/// per block and round (S × I per block and step, each with an edge from every neighbour) costs more in
/// scheduling than in work; blocks with many contacts keep a task each, so their sweeps run in
/// parallel. A block's round reads only the lists of the round before and writes only its own, so it
/// computes the same bits in any task; the set-up round (gather, detection) stays one task per block.
#[derive(Clone, Debug, Default)]
pub(super) struct SweepGroups {
    /// (first block, members in id order) of every group.
    groups: Vec<(usize, Vec<usize>)>,
    /// Index into `groups` of the group a block starts (`u32::MAX`: none).
    starts: Vec<u32>,
}

impl SweepGroups {
    /// The groups of `active` (ascending block ids) under `owners`, for `nb` blocks, from each block's
    /// contacts in its last sub-step (`contacts`); a block for which `alone` holds is a group of its own.
    fn new(
        nb: usize,
        owners: &[u32],
        active: &[usize],
        contacts: impl Fn(usize) -> usize,
        alone: impl Fn(usize) -> bool,
    ) -> Self {
        let mut by_owner: std::collections::BTreeMap<u32, Vec<usize>> = Default::default();
        for &b in active {
            by_owner.entry(owners[b]).or_default().push(b);
        }
        let mut out = SweepGroups {
            groups: Vec::new(),
            starts: vec![u32::MAX; nb],
        };
        for blocks in by_owner.values() {
            let mut run: Vec<usize> = Vec::new();
            let mut load = 0;
            for &b in blocks {
                if alone(b) {
                    if !run.is_empty() {
                        out.push(std::mem::take(&mut run));
                        load = 0;
                    }
                    out.push(vec![b]);
                    continue;
                }
                let c = contacts(b);
                if !run.is_empty() && load + c > GROUP_CONTACTS {
                    out.push(std::mem::take(&mut run));
                    load = 0;
                }
                run.push(b);
                load += c;
            }
            if !run.is_empty() {
                out.push(run);
            }
        }
        out
    }

    /// Adds the group `members` (ascending ids).
    fn push(&mut self, members: Vec<usize>) {
        self.starts[members[0]] = self.groups.len() as u32;
        self.groups.push((members[0], members));
    }

    /// Whether round `round` of a sub-step runs as one task per group (a sweep round of a grouped graph).
    pub(super) fn runs_round(&self, round: usize) -> bool {
        round > 0 && !self.groups.is_empty()
    }

    /// The groups as (first block, members).
    fn iter(&self) -> impl Iterator<Item = (usize, &[usize])> {
        self.groups.iter().map(|(f, m)| (*f, m.as_slice()))
    }

    /// The blocks the `rb` task of block `b` in round `round` runs: the group b starts in a grouped sweep
    /// round, else `None` (b alone).
    pub(super) fn members(&self, b: usize, round: usize) -> Option<&[usize]> {
        if !self.runs_round(round) {
            return None;
        }
        let i = *self.starts.get(b)?;
        (i != u32::MAX).then(|| self.groups[i as usize].1.as_slice())
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Groups hold one process's blocks in id order, at most `GROUP_CONTACTS` contacts together, a block
    /// with more on its own; sweep rounds run grouped, the set-up round (0) block by block.
    #[test]
    fn sweep_groups_cut_by_process_and_contacts() {
        let owners = [0, 0, 1, 0, 1, 0, 0, 0];
        let active = [0, 1, 2, 3, 4, 5, 7];
        let contacts = [10, 20, 0, 5, 0, GROUP_CONTACTS + 1, 0, 3];
        let g = SweepGroups::new(owners.len(), &owners, &active, |b| contacts[b], |_| false);
        let got: Vec<(usize, Vec<usize>)> = g.iter().map(|(f, m)| (f, m.to_vec())).collect();
        assert_eq!(
            got,
            vec![
                (0, vec![0, 1]),
                (3, vec![3]),
                (5, vec![5]),
                (7, vec![7]),
                (2, vec![2, 4])
            ]
        );
        assert_eq!(g.members(0, 1), Some(&[0, 1][..]));
        assert_eq!(g.members(0, 0), None, "the set-up round is one task per block");
        assert_eq!(g.members(1, 3), None, "block 1 starts no group");
        assert_eq!(g.members(6, 1), None, "an inactive block is in no group");
        // A block that must stay alone (under ranks: one next to another rank's) cuts the run around it.
        let g = SweepGroups::new(owners.len(), &owners, &active, |_| 0, |b| b == 3);
        let got: Vec<(usize, Vec<usize>)> = g.iter().map(|(f, m)| (f, m.to_vec())).collect();
        assert_eq!(
            got,
            vec![(0, vec![0, 1]), (3, vec![3]), (5, vec![5, 7]), (2, vec![2, 4])]
        );
        let none = SweepGroups::default();
        assert!(!none.runs_round(1) && none.members(0, 1).is_none());
    }
}
