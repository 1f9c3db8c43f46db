//! Rigid bodies on the block grid (section 2.2 and Algorithm 7 of Rettinger & Rüde 2019, distributed the
//! way the paper's pe framework distributes them): every body is *local* to the one block that contains
//! its centre, and a *shadow* copy of it lives in every other block it reaches into within the halo. The
//! numerics are the kernels' ([`blockflow_kernels::rigid`]); this module holds the per-block bookkeeping
//! and the two tasks of a rigid-body sub-step ([`tasks`]).
//!
//! Rules that make the result independent of which process runs which block (DESIGN.md principle 1):
//! - *Home block*: `floor(x / block_size)` per axis, clamped on walled axes; periodic positions are
//!   wrapped into `[0, L)` when a body moves, so every block computes the same home for the same bits.
//! - *Halo*: a body is a shadow of block b when its sphere comes within `r_max + contact_margin` of b's
//!   box. Then every body that can touch a local body of b is present in b.
//! - *Contact ownership*: a sphere pair belongs to the home block of its lower-id body, a sphere–plane
//!   contact to the home block of the sphere: each contact is owned by exactly one block, which resolves
//!   it in the kernels' fixed (body id) order.
//! - *Owner computes, with context* (`particles.solver = "block_gauss_seidel"`, the default): a block
//!   runs projected Gauss–Seidel over every contact among its locals and shadows (the non-owned ones
//!   give its owned contacts the load of the neighbourhood), then keeps only the impulses of the
//!   contacts it owns and turns them into velocity changes of the bodies they touch. Every body's new
//!   velocity is its velocity after forces plus the changes from every block in ascending block-id
//!   order (overlapping block-Jacobi between blocks, Gauss–Seidel inside a block).
//!   Each contact's impulse acts on both of its bodies exactly once, so linear and angular momentum are
//!   conserved to rounding whatever the block layout. Cross-block coupling lags by one sub-step: more
//!   sub-steps with fewer sweeps each (`particles.subcycles`, `particles.iterations`), or more rounds of
//!   the solve inside each sub-step (`particles.rounds`: the velocity changes are exchanged between
//!   rounds and the solve continues from the impulses so far), tighten it.
//! - *Or a global iteration* (`particles.solver = "jacobi"`, [`jacobi`]): projected Jacobi with mass
//!   splitting, one round per sweep. Every block updates its locals from all their contacts, computed
//!   from the velocities every owner published after the last sweep, and sums them in contact (body id)
//!   order: a body's new velocity is the same whichever block holds it and whatever the layout.
//!
//! Requirements checked at set-up and per sub-step: `2 r_max + contact_margin` plus the largest distance a
//! body moves in one sub-step must stay below the smallest block edge, so that everything a block needs
//! lives in its 26 neighbours.

pub mod jacobi;
pub mod tasks;

use crate::config::ContactSolver;
use crate::error::{config_err, Result};
use crate::physics::domain::{DomainSpec, NEIGHBOURS};
use crate::util::hash::mix;
use blockflow_kernels::rigid::{Body, Plane, RigidParams};
use glam::DVec3;
use std::cell::UnsafeCell;
use std::sync::Mutex;

/// A neighbour block seen from a block: its id and the translation that maps its coordinates into this
/// block's frame (non-zero across a periodic face).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Neighbour {
    /// Block id (may be the block itself on a periodic axis with one or two blocks).
    pub block: usize,
    /// Added to the neighbour's body positions.
    pub shift: DVec3,
    /// Whether this is the first entry of `block` in the list (the one the block's locals are gathered
    /// from, unshifted).
    pub first: bool,
}

/// A velocity change a block's contacts gave one of its shadow bodies.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Delta {
    /// Body id.
    pub id: u64,
    /// Change of the translational velocity.
    pub dv: DVec3,
    /// Change of the angular velocity.
    pub dw: DVec3,
}

/// The total impulse a block's solve has given one contact it owns so far in the current sub-step, keyed
/// by the ids of what touches (read by the neighbours' next round, `particles.rounds` > 1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OwnedImpulse {
    /// Id of body a (the lower id of a sphere pair, or the sphere of a plane contact).
    pub a: u64,
    /// Id of body b, or the plane's id with [`PLANE_KEY`] set.
    pub b: u64,
    /// Impulse on a (b receives its negative).
    pub impulse: DVec3,
}

/// Set in [`OwnedImpulse::b`] when the contact is with a plane (plane ids and body ids are separate
/// spaces).
pub const PLANE_KEY: u64 = 1 << 63;

/// The local bodies a block published after a sub-step (or a round of one), with each body's home block
/// (computed once, by the publisher, from the new position), and its owned contacts' impulses so far.
#[derive(Clone, Debug, Default)]
pub struct Published {
    /// Bodies sorted by id.
    pub bodies: Vec<Body>,
    /// Home block of each body.
    pub homes: Vec<u32>,
    /// Impulses of the contacts the block owns, sorted by (a, b): with `particles.rounds` > 1 the
    /// impulses so far of the current sub-step; with the Jacobi solver, after a sub-step's last sweep,
    /// its final impulses (the next sub-step's warm start).
    pub owned: Vec<OwnedImpulse>,
    /// With the Jacobi solver, in the list of a sub-step's first round only: the number of contacts of
    /// each body (the mass splitting of every block that solves one of them).
    pub counts: Vec<u32>,
}

/// What `rb(b, s)` computed for block b (read by `rb_sync` of b and its neighbours).
#[derive(Clone, Debug, Default)]
pub struct Work {
    /// Local bodies sorted by id (velocities after forces and this block's contacts), then shadows
    /// sorted by (id, neighbour index).
    pub bodies: Vec<Body>,
    /// Number of local bodies at the front of `bodies`.
    pub locals: usize,
    /// Velocity changes of the shadows, sorted by id (one entry per id).
    pub deltas: Vec<Delta>,
    /// With more than one round: the contacts of the current sub-step (indices into `bodies`), their
    /// velocity targets and the block's solution so far (total impulse per contact), kept for the next
    /// round; and the owned contacts' impulses, published by `rb_sync`.
    pub contact_list: Vec<blockflow_kernels::rigid::Contact>,
    /// Velocity target of each contact of `contact_list`.
    pub targets: Vec<f64>,
    /// Total impulse of each contact of `contact_list` in the block's last solve.
    pub solved: Vec<DVec3>,
    /// Owned contacts' total impulses, sorted by (a, b).
    pub owned: Vec<OwnedImpulse>,
    /// Contacts owned by the block in this sub-step (K of Table 1).
    pub contacts: usize,
    /// Largest penetration among the owned contacts (before resolution).
    pub max_penetration: f64,
    /// Owned contacts summed over the sub-steps since the last [`Particles::collect_stats`].
    pub contacts_total: u64,
    /// Largest penetration since the last [`Particles::collect_stats`].
    pub max_penetration_total: f64,
    /// Owned contacts summed over the sub-steps of the current (or last finished) step.
    pub contacts_step: u64,
    /// Contacts the block solved (owned and among its shadows: the contacts it *sees*), summed over the
    /// sub-steps of the current (or last finished) step.
    pub seen_step: u64,
    /// Entries of the neighbours' published lists read while gathering locals and shadows, summed over
    /// the sub-steps of the current (or last finished) step.
    pub scanned_step: u64,
    /// Working memory of `rb`'s gather (the shadows found, before sorting), kept between sub-steps so
    /// that no sub-step allocates it again; empty between tasks.
    pub shadow_scratch: Vec<ShadowRef>,
    /// The same for the locals found.
    pub local_scratch: Vec<ShadowRef>,
    /// Where each body of `bodies` was gathered from: (index into the block's neighbours, entry in that
    /// neighbour's published list).
    pub origins: Vec<(u32, u32)>,
    /// With the Jacobi solver: the state of the current sub-step's solve (see [`jacobi`]).
    pub jacobi: jacobi::JacobiWork,
    /// Contact candidates kept between sub-steps: detection tests only these pairs while the gathered
    /// bodies stay the same ([`ContactCandidates`]). A cache: the contacts are those of a detection over
    /// all pairs, and a checkpoint does not keep it.
    pub candidates: blockflow_kernels::rigid::ContactCandidates,
    /// (id, neighbour index) of each body of `bodies` at the last gather: the same list at the next
    /// gather means the same bodies in the same order.
    pub gathered: Vec<(u64, u32)>,
    /// Whether the last gather found the same bodies, in the same order, as the one before it.
    pub same_bodies: bool,
}

/// A shadow found by `rb`'s gather: body `id` at `position` (its centre shifted into the block's periodic
/// frame), entry `index` of the published list of neighbour `k` (index into the block's neighbours).
#[derive(Clone, Copy, Debug, Default)]
pub struct ShadowRef {
    /// Body id.
    pub id: u64,
    /// Neighbour index.
    pub k: u32,
    /// Entry in that neighbour's published list.
    pub index: u32,
    /// Shifted centre.
    pub position: DVec3,
}

/// Rigid-body state of one block.
pub struct BlockBodies {
    /// Block id.
    pub id: usize,
    /// Lower corner of the block's box (cells).
    pub lo: DVec3,
    /// Upper corner.
    pub hi: DVec3,
    /// The block itself (zero shift) first, then its neighbours over the 26 directions, each distinct
    /// (block, shift) pair once.
    pub neighbours: Vec<Neighbour>,
    /// Distinct block ids among `neighbours` (this block included), ascending: the order in which
    /// velocity changes are summed.
    pub near: Vec<usize>,
    /// Planes a local body of this block can touch.
    pub planes: Vec<Plane>,
    /// Local bodies after phase s, by parity of s (sorted by id). Written by `rb_sync(b, s)` (under
    /// Jacobi by `rb(b, s)`).
    published: [UnsafeCell<Published>; 2],
    /// Written by `rb(b, s)`.
    work: UnsafeCell<Work>,
}

// SAFETY: the cells are written only by the tasks of this block (`rb` writes `work`, `rb_sync` writes
// `published[s % 2]`, or `rb` under Jacobi), and the task graph orders every write after the last read
// of the same data by a neighbour's task and before the next one (see `tasks`).
unsafe impl Sync for BlockBodies {}

impl BlockBodies {
    /// The local bodies published after a sub-step of parity `p`.
    ///
    /// # Safety
    /// No `rb_sync` of this block for a sub-step of parity `p` may run concurrently.
    pub unsafe fn published(&self, p: usize) -> &Published {
        &*self.published[p].get()
    }

    /// The local bodies published after a sub-step of parity `p`, for writing (the `forces` task sets the
    /// hydrodynamic force and torque in place).
    ///
    /// # Safety
    /// No other task may read or write this list concurrently.
    #[allow(clippy::mut_from_ref)]
    pub unsafe fn published_mut(&self, p: usize) -> &mut Published {
        &mut *self.published[p].get()
    }

    /// Replaces the list published after a sub-step of parity `p` and returns the old one.
    ///
    /// # Safety
    /// No task may read or write this block's lists concurrently.
    pub unsafe fn replace_published(&self, p: usize, list: Published) -> Published {
        std::mem::replace(&mut *self.published[p].get(), list)
    }

    /// Replaces the last `rb` result of this block (bodies, deltas, contact counters) and returns the old
    /// one.
    ///
    /// # Safety
    /// No task may read or write this block's `work` concurrently.
    pub unsafe fn replace_work(&self, work: Work) -> Work {
        std::mem::replace(&mut *self.work.get(), work)
    }

    /// The last `rb` result of this block.
    ///
    /// # Safety
    /// No `rb` of this block may run concurrently.
    pub unsafe fn work(&self) -> &Work {
        &*self.work.get()
    }

    /// Replaces the velocity changes of the last `rb` result (the copy of a block another rank holds).
    ///
    /// # Safety
    /// No task may read or write this block's `work` concurrently.
    pub unsafe fn set_deltas(&self, deltas: Vec<Delta>) {
        (*self.work.get()).deltas = deltas;
    }
}

/// Counters over a run (rapier-style per-stage counters).
#[derive(Clone, Copy, Debug, Default)]
pub struct RigidCounters {
    /// Rigid-body sub-steps taken.
    pub substeps: u64,
    /// Owned contacts summed over blocks and sub-steps.
    pub contacts: u64,
    /// Largest penetration seen in any owned contact.
    pub max_penetration: f64,
}

/// All rigid bodies of a run, distributed over the blocks.
pub struct Particles {
    /// Solver parameters (gravity, buoyancy, restitution, friction, iterations, ...).
    pub params: RigidParams,
    /// Sub-steps S per time step.
    pub subcycles: usize,
    /// Rounds of the contact solve per sub-step (`particles.rounds`): between rounds every block's
    /// velocity changes are summed and published, and the next round continues the solve from them.
    /// With the Jacobi solver, one set-up round and one round per sweep.
    pub rounds: usize,
    /// How the contacts are solved (`particles.solver`).
    pub solver: ContactSolver,
    /// Share of the previous sub-step's impulse a contact starts from (Jacobi solver).
    pub warm_start: f64,
    /// Time per step (1 in lattice units; fluid-off scenes may choose another).
    pub dt: f64,
    /// Per-block state, in block id order.
    pub blocks: Vec<BlockBodies>,
    /// Whether a block gets rigid-body tasks in the current graph (see [`Particles::update_active`]).
    pub active: Vec<bool>,
    /// Whether this process holds a block's bodies (every block under virtual processes; under ranks the
    /// rank's own blocks, the others' lists being copies of those near its blocks). The global views
    /// ([`Particles::bodies`], [`Particles::checksum`], the statistics) cover the held blocks.
    held: Vec<bool>,
    /// Whether any body can move (fixed bodies alone are mapped once and need no rigid-body tasks).
    moving: bool,
    /// Counters.
    pub counters: RigidCounters,
    domain: DomainSpec,
    halo: f64,
    max_radius: f64,
    /// Largest distance a body may move in one sub-step.
    max_move: f64,
    errors: Mutex<Vec<(u64, usize, String)>>,
}

fn dist_to_box(x: DVec3, lo: DVec3, hi: DVec3) -> f64 {
    let d = (lo - x).max(x - hi).max(DVec3::ZERO);
    d.length()
}

impl Particles {
    /// Distributes `bodies` over the blocks of `domain`. Checks ids (unique), radii, densities, positions
    /// (inside the domain) and that the block size leaves room for the halo; the messages name the body.
    pub fn new(
        domain: DomainSpec,
        bodies: Vec<Body>,
        planes: Vec<Plane>,
        params: RigidParams,
        subcycles: usize,
        dt: f64,
    ) -> Result<Self> {
        let cells = domain.cells();
        let len = DVec3::new(cells[0] as f64, cells[1] as f64, cells[2] as f64);
        let mut ids: Vec<u64> = bodies.iter().map(|b| b.id).collect();
        ids.sort_unstable();
        if let Some(w) = ids.windows(2).find(|w| w[0] == w[1]) {
            return config_err(format!("particles: body id {} is used twice", w[0]));
        }
        for b in &bodies {
            if !(b.radius > 0.0 && b.radius.is_finite() && b.density > 0.0 && b.density.is_finite()) {
                return config_err(format!(
                    "particles: body {} has radius {} and density {}; both must be finite and > 0",
                    b.id, b.radius, b.density
                ));
            }
            let p = b.position;
            if !p.is_finite() || (0..3).any(|a| p[a] < 0.0 || p[a] > len[a]) {
                return config_err(format!(
                    "particles: body {} at ({}, {}, {}) lies outside the {:?}-cell domain",
                    b.id, p.x, p.y, p.z, cells
                ));
            }
        }
        let max_radius = bodies.iter().map(|b| b.radius).fold(0.0, f64::max);
        let halo = max_radius + params.contact_margin;
        let min_edge = domain.block_size.iter().copied().min().unwrap_or(1) as f64;
        let max_move = min_edge - 2.0 * max_radius - params.contact_margin;
        let all_fixed = bodies.iter().all(|b| b.fixed);
        // Fixed bodies only need to be seen by the blocks they reach (radius + ghost layer within a
        // neighbour); moving ones need room for the contact halo and a sub-step's motion.
        let too_small = if all_fixed {
            max_radius + 1.0 >= min_edge
        } else {
            max_move <= 0.0
        };
        if !bodies.is_empty() && too_small {
            return config_err(format!(
                "domain.block_size = {:?}: blocks must be larger than a particle diameter plus the contact margin \
                 ({} cells here); use fewer, larger blocks",
                domain.block_size,
                2.0 * max_radius + params.contact_margin
            ));
        }
        let nb = domain.num_blocks();
        let mut blocks: Vec<BlockBodies> = (0..nb).map(|id| block_bodies(&domain, id, &planes, halo)).collect();
        let mut sorted = bodies;
        sorted.sort_by_key(|b| b.id);
        let mut parts = Particles {
            params,
            subcycles,
            rounds: 1,
            solver: ContactSolver::BlockGaussSeidel,
            warm_start: 0.0,
            dt,
            blocks: Vec::new(),
            active: vec![false; nb],
            held: vec![true; nb],
            moving: !all_fixed,
            counters: RigidCounters::default(),
            domain,
            halo,
            max_radius,
            max_move,
            errors: Mutex::new(Vec::new()),
        };
        for mut b in sorted {
            b.position = parts.wrap(b.position);
            let h = parts.home(b.position);
            let out = blocks[h].published[0].get_mut();
            out.bodies.push(b);
            out.homes.push(h as u32);
        }
        parts.blocks = blocks;
        Ok(parts)
    }

    /// The same bodies with `rounds` rounds of the contact solve per sub-step (at least 1).
    pub fn with_rounds(mut self, rounds: usize) -> Self {
        self.rounds = rounds.max(1);
        self
    }

    /// The same bodies solved by projected Jacobi with mass splitting ([`jacobi`]): `params.iterations`
    /// sweeps per sub-step, each its own round after a set-up round, each contact starting from
    /// `warm_start` times its impulse of the previous sub-step.
    pub fn with_jacobi(mut self, warm_start: f64) -> Self {
        self.solver = ContactSolver::Jacobi;
        self.warm_start = warm_start;
        self.rounds = self.params.iterations + 1;
        self
    }

    /// Rigid-body phases per step: sub-steps times rounds (each phase is one `rb`/`rb_sync` pair, or one
    /// `rb` under Jacobi).
    pub fn phases(&self) -> u64 {
        (self.subcycles * self.rounds) as u64
    }

    /// Whether any body can move (fixed bodies alone are mapped once and need no rigid-body tasks).
    pub fn has_moving(&self) -> bool {
        self.moving
    }

    /// Whether this process holds block `b`'s bodies (see the field's docs).
    pub fn is_held(&self, b: usize) -> bool {
        self.held[b]
    }

    /// Holds the blocks of `held` only: the lists and rigid-body results of every other block are
    /// emptied (they become copies, filled from the messages of the rank that holds the block).
    ///
    /// # Safety
    /// No task may run.
    pub unsafe fn hold_only(&mut self, held: Vec<bool>) {
        assert_eq!(held.len(), self.blocks.len());
        for (b, blk) in self.blocks.iter().enumerate() {
            if !held[b] {
                blk.replace_published(0, Published::default());
                blk.replace_published(1, Published::default());
                blk.replace_work(Work::default());
            }
        }
        self.held = held;
    }

    /// The block decomposition the bodies live on.
    pub fn domain(&self) -> &DomainSpec {
        &self.domain
    }

    /// Time of one sub-step.
    pub fn dt_sub(&self) -> f64 {
        self.dt / self.subcycles as f64
    }

    /// The halo width: a body within `radius + halo` of a block's box is present in that block.
    pub fn halo(&self) -> f64 {
        self.halo
    }

    /// The home block of a (wrapped) position: the block containing it, clamped to the domain.
    pub fn home(&self, x: DVec3) -> usize {
        let d = &self.domain;
        let c: [usize; 3] = std::array::from_fn(|a| {
            let i = (x[a] / d.block_size[a] as f64).floor();
            if i.is_nan() || i < 0.0 {
                0
            } else {
                (i as usize).min(d.blocks[a] - 1)
            }
        });
        d.id(c)
    }

    /// Wraps a position into `[0, L)` along periodic axes (one period at most: bodies move less than a
    /// block per sub-step).
    pub fn wrap(&self, mut x: DVec3) -> DVec3 {
        let cells = self.domain.cells();
        for a in 0..3 {
            if self.domain.periodic[a] {
                let l = cells[a] as f64;
                if x[a] >= l {
                    x[a] -= l;
                } else if x[a] < 0.0 {
                    x[a] += l;
                }
            }
        }
        x
    }

    /// Parity of the published lists holding the state after `steps` whole steps.
    pub fn parity(&self, steps: u64) -> usize {
        ((steps * self.phases()) % 2) as usize
    }

    /// All bodies of the held blocks after `steps` whole steps, sorted by id (the global view for output
    /// and observables; under ranks the rank's share of it).
    pub fn bodies(&self, steps: u64) -> Vec<Body> {
        let p = self.parity(steps);
        // SAFETY: called between graph runs (nothing runs concurrently).
        let mut all: Vec<Body> = self
            .blocks
            .iter()
            .filter(|b| self.held[b.id])
            .flat_map(|b| unsafe { b.published(p) }.bodies.iter().copied())
            .collect();
        all.sort_by_key(|b| b.id);
        all
    }

    /// A hash of the exact bits of every body's state (id, position, orientation, velocities) of the held
    /// blocks, combined by wrapping addition: independent of the block layout, process count and order
    /// (under ranks, the ranks' hashes add up to it).
    pub fn checksum(&self, steps: u64) -> u64 {
        let mut sum = 0u64;
        for b in self.bodies(steps) {
            let mut h = mix(0x243f_6a88_85a3_08d3 ^ b.id);
            let q = b.orientation;
            for v in [
                b.position.x,
                b.position.y,
                b.position.z,
                q.x,
                q.y,
                q.z,
                q.w,
                b.velocity.x,
                b.velocity.y,
                b.velocity.z,
                b.angular_velocity.x,
                b.angular_velocity.y,
                b.angular_velocity.z,
            ] {
                h = mix(h ^ v.to_bits());
            }
            sum = sum.wrapping_add(h);
        }
        sum
    }

    /// Marks the blocks that get rigid-body tasks for the next `steps` steps: every block a body (with
    /// its halo) can reach in that time, from a bound on its travel (twice the distance at the current
    /// largest speed and acceleration, plus one cell). A body that still leaves this region stops the
    /// run with an error naming it (checked in `rb_sync`). Returns whether the set changed.
    pub fn update_active(&mut self, steps: u64, bodies: &[Body]) -> bool {
        let active = self.reach(steps, bodies);
        self.set_active(active)
    }

    /// Sets the blocks that get rigid-body tasks (e.g. the union of every rank's [`Particles::reach`]);
    /// returns whether the set changed.
    pub fn set_active(&mut self, active: Vec<bool>) -> bool {
        assert_eq!(active.len(), self.blocks.len());
        let changed = active != self.active;
        self.active = active;
        changed
    }

    /// The blocks `bodies` can reach in the next `steps` steps (see [`Particles::update_active`]).
    pub fn reach(&self, steps: u64, bodies: &[Body]) -> Vec<bool> {
        let t = steps as f64 * self.dt;
        let g = self.params.gravity.length();
        let d = self.domain;
        let mut active = vec![false; self.blocks.len()];
        for b in bodies {
            let a = g + b.force.length() / b.mass();
            let travel = 2.0 * (b.velocity.length() * t + a * t * t) + 1.0;
            let reach = b.radius + self.halo + travel;
            let mut lo = [0i64; 3];
            let mut hi = [0i64; 3];
            for ax in 0..3 {
                let bs = d.block_size[ax] as f64;
                let n = d.blocks[ax] as i64;
                let (lf, hf) = (
                    ((b.position[ax] - reach) / bs).floor(),
                    ((b.position[ax] + reach) / bs).floor(),
                );
                // In f64 first: a runaway body (huge or non-finite reach) must not overflow the block range.
                let (l, h) = (
                    lf.clamp(-(n as f64), 2.0 * n as f64) as i64,
                    hf.clamp(-(n as f64), 2.0 * n as f64) as i64,
                );
                if d.periodic[ax] {
                    let span = hf - lf + 1.0;
                    if span.is_nan() || span >= n as f64 {
                        (lo[ax], hi[ax]) = (0, n - 1);
                    } else {
                        (lo[ax], hi[ax]) = (l, h);
                    }
                } else {
                    (lo[ax], hi[ax]) = (l.clamp(0, n - 1), h.clamp(0, n - 1));
                }
            }
            for z in lo[2]..=hi[2] {
                for y in lo[1]..=hi[1] {
                    for x in lo[0]..=hi[0] {
                        let c = [x, y, z];
                        let w: [usize; 3] = std::array::from_fn(|a| c[a].rem_euclid(d.blocks[a] as i64) as usize);
                        active[d.id(w)] = true;
                    }
                }
            }
        }
        active
    }

    /// Records a failure found by a task (reported after the graph run, lowest sub-step then block first).
    pub(crate) fn fail(&self, substep: u64, block: usize, msg: String) {
        self.errors.lock().expect("particle errors").push((substep, block, msg));
    }

    /// The first failure recorded since the last call, if any.
    pub fn take_error(&self) -> Option<String> {
        self.take_error_keyed().map(|x| x.2)
    }

    /// Adds the per-block statistics gathered since the last call to the counters, in block order (call
    /// between graph runs).
    pub fn collect_stats(&mut self, substeps: u64) {
        let (contacts, pen) = self.take_stats();
        self.add_stats(substeps, contacts, pen);
    }

    /// The held blocks' statistics since the last call (owned contacts summed over sub-steps, the largest
    /// penetration), reset to zero: this process's part of [`Particles::collect_stats`].
    pub fn take_stats(&mut self) -> (u64, f64) {
        let mut contacts = 0u64;
        let mut pen: f64 = 0.0;
        let held = &self.held;
        for b in self.blocks.iter_mut().filter(|b| held[b.id]) {
            let w = b.work.get_mut();
            contacts += w.contacts_total;
            pen = pen.max(w.max_penetration_total);
            w.contacts_total = 0;
            w.max_penetration_total = 0.0;
        }
        (contacts, pen)
    }

    /// Adds `substeps` sub-steps with `contacts` owned contacts and a largest penetration of `pen` (every
    /// process's [`Particles::take_stats`] combined) to the counters.
    pub fn add_stats(&mut self, substeps: u64, contacts: u64, pen: f64) {
        self.counters.max_penetration = self.counters.max_penetration.max(pen);
        self.counters.substeps += substeps;
        self.counters.contacts += contacts;
    }

    /// The first failure recorded since the last call, with its key (sub-step, block), if any.
    pub fn take_error_keyed(&self) -> Option<(u64, usize, String)> {
        let mut e = self.errors.lock().expect("particle errors");
        e.sort_by_key(|x| (x.0, x.1));
        let first = e.first().cloned();
        e.clear();
        first
    }

    /// Largest penetration and number of contacts of the last sub-step, over the held blocks (block
    /// order).
    pub fn last_contacts(&self) -> (usize, f64) {
        let mut n = 0;
        let mut pen: f64 = 0.0;
        for b in self.blocks.iter().filter(|b| self.active[b.id] && self.held[b.id]) {
            // SAFETY: between graph runs.
            let w = unsafe { b.work() };
            n += w.contacts;
            pen = pen.max(w.max_penetration);
        }
        (n, pen)
    }

    /// Largest radius.
    pub fn max_radius(&self) -> f64 {
        self.max_radius
    }

    /// Advances `steps` steps without the scheduler: every phase runs `rb` on all active blocks, then
    /// `rb_sync` on all of them (where the solver has it), in block order. The reference the task graph
    /// must reproduce bitwise.
    pub fn advance_serial(&mut self, start_step: u64, steps: u64) -> std::result::Result<(), String> {
        let bodies = self.bodies(start_step);
        self.update_active(steps, &bodies);
        let s = self.phases();
        for k in 0..steps * s {
            let g = start_step * s + k + 1;
            for b in 0..self.blocks.len() {
                if self.active[b] {
                    // SAFETY: serial: no task runs concurrently.
                    unsafe { self.rb(b, g) };
                }
            }
            if self.has_sync_tasks() {
                for b in 0..self.blocks.len() {
                    if self.active[b] {
                        // SAFETY: as above.
                        unsafe { self.rb_sync(b, g) };
                    }
                }
            }
            if g.is_multiple_of(self.rounds as u64) {
                self.collect_stats(1);
            }
            if let Some(e) = self.take_error() {
                return Err(e);
            }
        }
        Ok(())
    }
}

/// Builds the bookkeeping of block `id`: box, neighbour list with periodic shifts, nearby planes.
fn block_bodies(d: &DomainSpec, id: usize, planes: &[Plane], halo: f64) -> BlockBodies {
    let o = d.origin(id);
    let s = d.block_size;
    let lo = DVec3::new(o[0] as f64, o[1] as f64, o[2] as f64);
    let hi = lo + DVec3::new(s[0] as f64, s[1] as f64, s[2] as f64);
    let cells = d.cells();
    let c = d.coords(id);
    let mut neighbours = vec![Neighbour {
        block: id,
        shift: DVec3::ZERO,
        first: true,
    }];
    for off in NEIGHBOURS {
        let Some(n) = d.neighbour(id, off) else {
            continue;
        };
        let mut shift = DVec3::ZERO;
        for a in 0..3 {
            let v = c[a] as i64 + off[a] as i64;
            if v < 0 {
                shift[a] = -(cells[a] as f64);
            } else if v >= d.blocks[a] as i64 {
                shift[a] = cells[a] as f64;
            }
        }
        if !neighbours.iter().any(|m| m.block == n && m.shift == shift) {
            let first = !neighbours.iter().any(|m| m.block == n);
            neighbours.push(Neighbour { block: n, shift, first });
        }
    }
    let mut near: Vec<usize> = neighbours.iter().map(|n| n.block).collect();
    near.sort_unstable();
    near.dedup();
    // A local body (centre inside the box) touches a plane only if some point of the box lies within
    // r_max + margin = halo of it: the lowest signed distance over the 8 corners decides.
    let near_planes = planes
        .iter()
        .filter(|p| {
            let mut m = f64::INFINITY;
            for k in 0..8 {
                let x = DVec3::new(
                    if k & 1 == 0 { lo.x } else { hi.x },
                    if k & 2 == 0 { lo.y } else { hi.y },
                    if k & 4 == 0 { lo.z } else { hi.z },
                );
                m = m.min(p.distance(x));
            }
            m <= halo
        })
        .copied()
        .collect();
    BlockBodies {
        id,
        lo,
        hi,
        neighbours,
        near,
        planes: near_planes,
        published: [
            UnsafeCell::new(Published::default()),
            UnsafeCell::new(Published::default()),
        ],
        work: UnsafeCell::new(Work::default()),
    }
}
