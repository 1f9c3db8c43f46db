//! Building the step graph of `k` consecutive steps: the fluid tasks (`send`, `comm`, `boundary`,
//! `sweep`) and the particle tasks (`map`, `reconstruct`, `forces`, `rb`, `rb_sync`) with the edges the
//! module docs of [`super`] list.

use super::kinds::{spec, Payload, TaskKind};
use super::messages::Outgoing;
use crate::physics::block::Block;
use crate::physics::particles::Particles;
use blockflow_kernels::Real;
use blockflow_scheduler::{GraphBuilder, TaskId};

/// Which blocks' rigid-body phases may share a task ([`RbGroups`]).
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
/// active and gets `map`/`reconstruct` even without fluid. With `grouping` other than [`Grouping::Off`],
/// the grouped phases (every phase under block Gauss–Seidel, the sweep rounds under Jacobi) run one task
/// per [`RbGroups`] group and kind (returned; empty otherwise), after every task of the phase before that
/// covers a neighbour of a member.
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
) -> RbGroups {
    let nb = parts.blocks.len();
    let s = parts.phases() as usize;
    let active: Vec<usize> = (0..nb).filter(|&b| no_skip || parts.active[b]).collect();
    let groups = rb_groups(parts, owners, &active, grouping);
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
                let before = if sub == 0 && coupled { &forces } else { &sync };
                sync = add_grouped_phase(g, parts, owners, &groups, kk, sub, before);
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

/// The [`RbGroups`] of the `active` blocks under `grouping`, cut by [`rb_load`].
pub(super) fn rb_groups(parts: &Particles, owners: &[u32], active: &[usize], grouping: Grouping) -> RbGroups {
    if grouping == Grouping::Off {
        return RbGroups::default();
    }
    let alone = |b: usize| match grouping {
        Grouping::Rank(me) => owners[b] != me || parts.blocks[b].near.iter().any(|&n| owners[n] != me),
        _ => false,
    };
    let (first_round, limit) = match parts.has_sync_tasks() {
        true => (0, GROUP_LOAD_GS),
        false => (1, GROUP_LOAD_JACOBI),
    };
    RbGroups::new(
        parts.blocks.len(),
        owners,
        active,
        |b| rb_load(parts, b),
        alone,
        (first_round, limit),
    )
}

/// The work of block `b`'s grouped rigid-body phase in contacts: under Jacobi (its sweep rounds) the
/// contacts it solved in its last sub-step; under block Gauss–Seidel (every phase) the contacts it saw
/// per sub-step in its last step plus the bodies it gathered, since a phase gathers, pushes, detects and
/// integrates every body it sees, each at a cost of the order of a contact's.
pub(super) fn rb_load(parts: &Particles, b: usize) -> usize {
    let subcycles = parts.subcycles.max(1) as u64;
    // SAFETY: called between graph runs; no rigid-body task runs.
    let w = unsafe { parts.blocks[b].work() };
    match parts.has_sync_tasks() {
        true => w.seen_step.div_ceil(subcycles) as usize + w.bodies.len(),
        false => w.contact_list.len(),
    }
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

/// Adds phase `sub` of step `kk` as one `rb` task per group of `groups`, after every task of the phase
/// before (`before`: its `rb_sync`, its `rb` under Jacobi, or at a step's first phase the `forces`)
/// that covers a neighbour of a member, and under block Gauss–Seidel one `rb_sync` task per group after
/// every new `rb` task that covers a neighbour of a member; returns each member's last task of the phase.
fn add_grouped_phase(
    g: &mut GraphBuilder,
    parts: &Particles,
    owners: &[u32],
    groups: &RbGroups,
    kk: usize,
    sub: usize,
    before: &[Option<TaskId>],
) -> Vec<Option<TaskId>> {
    let mut add = |kind: TaskKind, before: &[Option<TaskId>]| {
        let mut new: Vec<Option<TaskId>> = vec![None; parts.blocks.len()];
        for (first, members) in groups.iter() {
            let t = g.add(spec(owners[first], first, Payload::sub_step(kind, kk, sub)));
            for &m in members {
                new[m] = Some(t);
                // The graph's build drops the repeated edges.
                for prev in parts.blocks[m].near.iter().filter_map(|&n| before[n]) {
                    g.edge(prev, t);
                }
            }
        }
        new
    };
    let new_rb = add(TaskKind::Rb, before);
    if !parts.has_sync_tasks() {
        return new_rb;
    }
    add(TaskKind::RbSync, &new_rb)
}

/// [`rb_load`] per task of a grouped Jacobi sweep round at most, unless one block has more: a sweep
/// costs tens of nanoseconds per contact and a task about half a microsecond to schedule and release.
const GROUP_LOAD_JACOBI: usize = 32;

/// [`rb_load`] per task of a grouped block Gauss–Seidel phase at most, unless one block has more: the
/// load counts the bodies a phase gathers besides the contacts it solves. Measured with `blockflow bench
/// coupled` (2 threads): 96 runs hopper-small 3–7 % faster than 32 and no slower on the calibration
/// scene, whose blocks each see more than 96 bodies and contacts and keep a task each; 256 gains nothing
/// more on hopper-small and costs the calibration scene 1–3 %.
const GROUP_LOAD_GS: usize = 96;

/// The blocks whose rigid-body phases one task runs: every process's active blocks in id order, cut
/// into runs whose blocks' [`rb_load`] adds up to at most a limit ([`GROUP_LOAD_JACOBI`],
/// [`GROUP_LOAD_GS`]; a block with more is a run of its own). Most blocks have few contacts or none,
/// and their phase only gathers, integrates and publishes a few bodies, so one task per block and
/// phase (2·S per block and step under block Gauss–Seidel, S × (I + 1) under Jacobi, each with an edge
/// from every neighbour) costs more in scheduling than in work; blocks with many contacts keep a task each, so
/// their solves run in parallel. Under block Gauss–Seidel every phase runs grouped, an `rb` task and an
/// `rb_sync` task per group; under Jacobi the sweep rounds (1 … I), while the set-up round (gather,
/// detection) stays one task per block. A block's `rb` reads only the lists of the phase before and
/// writes only its own working memory, its `rb_sync` reads only the working memory of the phase and
/// writes only its own list, so each computes the same bits in any task.
#[derive(Clone, Debug, Default)]
pub(super) struct RbGroups {
    /// (first block, members in id order) of every group.
    groups: Vec<(usize, Vec<usize>)>,
    /// Index into `groups` of the group a block starts (`u32::MAX`: none).
    starts: Vec<u32>,
    /// The first round of a sub-step that runs grouped (0 under block Gauss–Seidel, 1 under Jacobi).
    first_round: usize,
    /// The load a group of several blocks carries at most.
    limit: usize,
}

impl RbGroups {
    /// The groups of `active` (ascending block ids) under `owners`, for `nb` blocks, from each block's
    /// load (`load`), at most `limit` per group of several; a block for which `alone` holds is a group of
    /// its own. Rounds from `first_round` on run grouped.
    fn new(
        nb: usize,
        owners: &[u32],
        active: &[usize],
        load: impl Fn(usize) -> usize,
        alone: impl Fn(usize) -> bool,
        (first_round, limit): (usize, usize),
    ) -> Self {
        let mut by_owner: std::collections::BTreeMap<u32, Vec<usize>> = Default::default();
        for &b in active {
            by_owner.entry(owners[b]).or_default().push(b);
        }
        let mut out = RbGroups {
            groups: Vec::new(),
            starts: vec![u32::MAX; nb],
            first_round,
            limit,
        };
        for blocks in by_owner.values() {
            let mut run: Vec<usize> = Vec::new();
            let mut sum = 0;
            for &b in blocks {
                if alone(b) {
                    if !run.is_empty() {
                        out.push(std::mem::take(&mut run));
                        sum = 0;
                    }
                    out.push(vec![b]);
                    continue;
                }
                let c = load(b);
                if !run.is_empty() && sum + c > limit {
                    out.push(std::mem::take(&mut run));
                    sum = 0;
                }
                run.push(b);
                sum += c;
            }
            if !run.is_empty() {
                out.push(run);
            }
        }
        out
    }

    /// Whether a graph built on these groups should be rebuilt on `fresh` ones (the same blocks' groups
    /// from the current loads `load`): a group of several blocks now carries more than twice the limit
    /// (its members would run in parallel), or the fresh grouping needs fewer than half the tasks. The
    /// margins keep a graph from being rebuilt for every small change of the loads.
    pub(super) fn outdated(&self, fresh: &RbGroups, load: impl Fn(usize) -> usize) -> bool {
        let crowded = self
            .groups
            .iter()
            .any(|(_, m)| m.len() > 1 && m.iter().map(|&b| load(b)).sum::<usize>() > 2 * self.limit);
        crowded || 2 * fresh.groups.len() < self.groups.len()
    }

    /// Adds the group `members` (ascending ids).
    fn push(&mut self, members: Vec<usize>) {
        self.starts[members[0]] = self.groups.len() as u32;
        self.groups.push((members[0], members));
    }

    /// Whether round `round` of a sub-step runs as one task per group.
    pub(super) fn runs_round(&self, round: usize) -> bool {
        round >= self.first_round && !self.groups.is_empty()
    }

    /// The groups as (first block, members).
    fn iter(&self) -> impl Iterator<Item = (usize, &[usize])> {
        self.groups.iter().map(|(f, m)| (*f, m.as_slice()))
    }

    /// The blocks the `rb` or `rb_sync` task of block `b` in round `round` runs: the group b starts in a
    /// grouped round, else `None` (b alone).
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

    /// Groups hold one process's blocks in id order, at most the limit of load together, a block
    /// with more on its own; under Jacobi (first grouped round 1) the sweep rounds run grouped, the set-up
    /// round (0) block by block; under block Gauss–Seidel (0) every round.
    #[test]
    fn rb_groups_cut_by_process_and_contacts() {
        let owners = [0, 0, 1, 0, 1, 0, 0, 0];
        let active = [0, 1, 2, 3, 4, 5, 7];
        let contacts = [10, 20, 0, 5, 0, GROUP_LOAD_JACOBI + 1, 0, 3];
        let g = RbGroups::new(
            owners.len(),
            &owners,
            &active,
            |b| contacts[b],
            |_| false,
            (1, GROUP_LOAD_JACOBI),
        );
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
        let g = RbGroups::new(
            owners.len(),
            &owners,
            &active,
            |_| 0,
            |b| b == 3,
            (1, GROUP_LOAD_JACOBI),
        );
        let got: Vec<(usize, Vec<usize>)> = g.iter().map(|(f, m)| (f, m.to_vec())).collect();
        assert_eq!(
            got,
            vec![(0, vec![0, 1]), (3, vec![3]), (5, vec![5, 7]), (2, vec![2, 4])]
        );
        let gs = RbGroups::new(
            owners.len(),
            &owners,
            &active,
            |b| contacts[b],
            |_| false,
            (0, GROUP_LOAD_JACOBI),
        );
        assert_eq!(
            gs.members(0, 0),
            Some(&[0, 1][..]),
            "block Gauss–Seidel groups its first round too"
        );
        let none = RbGroups::default();
        assert!(!none.runs_round(1) && none.members(0, 1).is_none());
    }

    /// A graph's groups are rebuilt only when a group of several blocks now carries more than twice the
    /// limit or a fresh grouping halves the tasks; a small change of the loads keeps them.
    #[test]
    fn rb_groups_outdated_by_margins_only() {
        let owners = [0u32; 6];
        let active = [0, 1, 2, 3, 4, 5];
        let lim = (0, 10);
        let built = RbGroups::new(6, &owners, &active, |_| 4, |_| false, lim);
        assert_eq!(built.iter().count(), 3, "two blocks of 4 per group of at most 10");
        let same = |l: usize| RbGroups::new(6, &owners, &active, move |_| l, |_| false, lim);
        assert!(
            !built.outdated(&same(5), |_| 5),
            "5 per block: groups of 10, within the margin"
        );
        assert!(
            built.outdated(&same(11), |_| 11),
            "22 per group of two: over twice the limit"
        );
        assert!(
            built.outdated(&same(0), |_| 0),
            "without load one task does, a third of three"
        );
        let singles = RbGroups::new(6, &owners, &active, |_| 11, |_| false, lim);
        assert!(
            !singles.outdated(&same(6), |_| 6),
            "three groups of two from six: not half"
        );
    }
}
