//! The two tasks of one rigid-body phase g (1-based over the whole run; parity `g % 2`). A sub-step is
//! R phases (`particles.rounds`, usually 1): the first solves the sub-step's contacts, each later one
//! continues that solve (round r = (g − 1) mod R), and only the last moves the bodies.
//!
//! | task | reads | writes |
//! |---|---|---|
//! | `rb(b, g)` | `published[(g-1) % 2]` of b and its neighbours | `work` of b |
//! | `rb_sync(b, g)` | `work` of b and its neighbours | `published[g % 2]` of b |
//!
//! `rb(b, g)`: gather the locals (bodies whose home is b) and shadows (bodies within the halo) from the
//! published lists, apply gravity, buoyancy and the held external force and torque (to shadows too, so
//! every copy of a body carries the same velocity), detect contacts, resolve all of them by projected
//! Gauss–Seidel (Algorithm 7), and record the velocity changes that the impulses of the contacts b owns
//! give their bodies (locals and shadows).
//! `rb_sync(b, g)`: add every neighbour's changes (b's own included) to the locals in ascending block-id
//! order, integrate positions and orientations (semi-implicit Euler), wrap periodic positions, publish.
//! In a round that is not the last of its sub-step it publishes the new velocities at the same positions
//! (with the owned contacts' impulses so far), and the next round's `rb` gathers the same bodies in the
//! same order, re-uses the first round's contacts and targets and continues the Gauss–Seidel sweeps from
//! the impulses so far: contacts beyond b's halo, which b cannot solve, then reach its solve through the
//! velocities within the sub-step.
//!
//! Under `particles.solver = "jacobi"` the phases are the rounds of [`super::jacobi`]: a set-up round
//! and one round per sweep. Each has no `rb_sync`: `rb(b, g)` publishes at its end, since b's locals
//! take no velocity change from a neighbour ([`Particles::has_sync_tasks`] gives its edges). A sweep
//! round of b reads only the lists of the round before and writes only b's.
//!
//! Under either solver the step graph may run a phase's `rb` (or `rb_sync`) of several blocks one after
//! the other in one task, each with the edges of every member: the tasks of one phase read only what
//! the phase before wrote and write only their own block's data.
//!
//! Edges (symmetric neighbourhoods make these enough): `rb_sync(n, g-1) → rb(b, g)` and
//! `rb(n, g) → rb_sync(b, g)` for every neighbour n of b (b included). Write-after-read follows by
//! transitivity: `rb(n, g+1)` overwrites the `work` that `rb_sync(b, g)` read, and it waits for
//! `rb_sync(b, g)`; `rb_sync(b, g+2)` overwrites the list `rb(n, g+1)` read, and it waits for
//! `rb(b, g+2)`, which waits for `rb_sync(n, g+1)`, which waits for `rb(n, g+1)`.

use super::{dist_to_box, BlockBodies, Delta, OwnedImpulse, Particles, ShadowRef, PLANE_KEY};
use crate::config::ContactSolver;
use blockflow_kernels::rigid::{
    apply_forces, integrate_positions, resolve_impulses, resolve_impulses_warm, resolve_targets, Body, Contact, Plane,
    WarmStart,
};

impl Particles {
    /// Task `rb(b, g)`; see the module docs. Under the Jacobi solver it also publishes (the work of
    /// `rb_sync(b, g)`, which that solver's graph does not have).
    ///
    /// # Safety
    /// Must run ordered by the edges of the module docs against the other rigid-body tasks.
    pub unsafe fn rb(&self, b: usize, g: u64) {
        self.solve_phase(b, g);
        if !self.has_sync_tasks() {
            self.publish(b, g);
        }
    }

    /// Whether a phase has the second task `rb_sync`: under block Gauss–Seidel a block's locals take
    /// velocity changes from its neighbours' solves, which must all have finished. Under Jacobi each
    /// block computes its locals' velocities itself (it holds all their contacts), so `rb(b, g)`
    /// publishes them at its end and a phase needs one task per block (or per group of blocks), with the edges
    /// `rb(n, g-1) → rb(b, g)` for every neighbour n of b (b included). They order every access:
    /// `rb(b, g)` reads the lists of parity (g-1) % 2 that `rb(n, g-1)` wrote, and overwrites b's list of
    /// parity g % 2 only after every `rb(n, g-1)` that read it has finished.
    pub fn has_sync_tasks(&self) -> bool {
        self.solver != ContactSolver::Jacobi
    }

    /// The computing part of `rb(b, g)` (module docs).
    ///
    /// # Safety
    /// As for [`Particles::rb`].
    unsafe fn solve_phase(&self, b: usize, g: u64) {
        let prev = ((g - 1) % 2) as usize;
        let blk = &self.blocks[b];
        let w = &mut *blk.work.get();
        let round = ((g - 1) % self.rounds as u64) as usize;
        let jacobi = self.solver == ContactSolver::Jacobi;
        if jacobi && round > 0 {
            self.jacobi_sweep(b, g, prev, round, w);
            return;
        }
        w.bodies.clear();
        w.deltas.clear();
        w.origins.clear();
        // One pass over the neighbours' lists: a body whose home is b is a local (taken once, unshifted,
        // from its block's first entry), every copy within the halo but the unshifted one of a local is a
        // shadow; locals sorted by id, shadows by (id, neighbour), so the order does not depend on the pass.
        let mut shadows = std::mem::take(&mut w.shadow_scratch);
        let mut locals = std::mem::take(&mut w.local_scratch);
        shadows.clear();
        locals.clear();
        let mut scanned = 0u64;
        for (k, nb) in blk.neighbours.iter().enumerate() {
            let pb = self.blocks[nb.block].published(prev);
            scanned += pb.bodies.len() as u64;
            let unshifted = nb.shift == glam::DVec3::ZERO;
            for (i, (body, &h)) in pb.bodies.iter().zip(&pb.homes).enumerate() {
                let local = h as usize == b;
                if local && nb.first {
                    locals.push(ShadowRef {
                        id: body.id,
                        k: k as u32,
                        index: i as u32,
                        position: body.position,
                    });
                }
                if local && unshifted {
                    continue;
                }
                let position = body.position + nb.shift;
                if dist_to_box(position, blk.lo, blk.hi) <= body.radius + self.halo {
                    shadows.push(ShadowRef {
                        id: body.id,
                        k: k as u32,
                        index: i as u32,
                        position,
                    });
                }
            }
        }
        locals.sort_unstable_by_key(|s| s.id);
        shadows.sort_unstable_by_key(|s| (s.id, s.k));
        let mut same = w.gathered.len() == locals.len() + shadows.len();
        for (j, s) in locals.iter().chain(&shadows).enumerate() {
            let nb = &blk.neighbours[s.k as usize];
            let mut c = self.blocks[nb.block].published(prev).bodies[s.index as usize];
            c.position = s.position;
            w.bodies.push(c);
            w.origins.push((s.k, s.index));
            same = same && w.gathered[j] == (s.id, s.k);
        }
        if !same {
            w.gathered.clear();
            w.gathered.extend(locals.iter().chain(&shadows).map(|s| (s.id, s.k)));
        }
        w.same_bodies = same;
        w.locals = locals.len();
        shadows.clear();
        locals.clear();
        w.shadow_scratch = shadows;
        w.local_scratch = locals;
        if jacobi {
            self.jacobi_start(b, g, prev, scanned, w);
            return;
        }
        if round > 0 {
            self.rb_round(b, prev, w);
            return;
        }
        let contacts = self.detect_substep(blk, g, scanned, w);
        // Solve every contact the block sees (its own and, as context, those among its shadows), so the
        // impulses of the owned ones account for the load the neighbourhood puts on them.
        let p = &self.params;
        let dt = self.dt_sub();
        let mut impulses = Vec::new();
        resolve_impulses(&w.bodies, &contacts, p, dt, &mut impulses);
        self.record_owned(w, &blk.planes, &contacts, &impulses, None);
        if self.rounds > 1 {
            w.targets = resolve_targets(&w.bodies, &contacts, p, dt);
            w.solved = impulses;
            w.contact_list = contacts;
        }
    }

    /// The first round of a sub-step, for either solver: forces on every gathered body (shadows too, so
    /// every copy of a body carries the same velocity), the counters of the sub-step (`scanned` list
    /// entries read by the gather) and the contacts among the gathered bodies, but a body's with its own
    /// periodic image.
    pub(super) fn detect_substep(&self, blk: &BlockBodies, g: u64, scanned: u64, w: &mut super::Work) -> Vec<Contact> {
        w.contact_list.clear();
        w.owned.clear();
        let p = &self.params;
        apply_forces(&mut w.bodies, p, self.dt_sub());
        w.contacts = 0;
        w.max_penetration = 0.0;
        if (g - 1).is_multiple_of(self.phases()) {
            w.contacts_step = 0;
            w.seen_step = 0;
            w.scanned_step = 0;
        }
        w.scanned_step += scanned;
        if w.bodies.is_empty() {
            return Vec::new();
        }
        let mut contacts = w.candidates.detect(
            &w.bodies,
            &blk.planes,
            p.contact_margin,
            p.grid_threshold,
            w.same_bodies,
        );
        let bodies = &w.bodies;
        // A body never touches its own periodic image.
        contacts.retain(|c| c.b.is_none_or(|o| bodies[o].id != bodies[c.a].id));
        w.seen_step += contacts.len() as u64;
        for c in contacts.iter().filter(|c| c.a < w.locals) {
            w.contacts += 1;
            w.max_penetration = w.max_penetration.max(c.depth);
        }
        w.contacts_total += w.contacts as u64;
        w.contacts_step += w.contacts as u64;
        w.max_penetration_total = w.max_penetration_total.max(w.max_penetration);
        contacts
    }

    /// A later round of a sub-step's contact solve in block `b` (`particles.rounds` > 1): the bodies
    /// gathered again carry the velocities every owner's impulses so far gave them (the syncs between
    /// rounds move no body), and the solve of the same contacts continues from those impulses (the
    /// block's own for the contacts it owns, the owners' published ones for the others) with the
    /// targets of the first round. The owned contacts' added impulses become the velocity changes.
    fn rb_round(&self, b: usize, prev: usize, w: &mut super::Work) {
        let blk = &self.blocks[b];
        let contacts = std::mem::take(&mut w.contact_list);
        if contacts.is_empty() {
            w.owned.clear();
            return;
        }
        let bodies = &w.bodies;
        let initial: Vec<glam::DVec3> = contacts
            .iter()
            .enumerate()
            .map(|(k, c)| {
                if c.a < w.locals {
                    return w.solved[k];
                }
                let key = (bodies[c.a].id, contact_key_b(c, bodies, &blk.planes));
                blk.near
                    .iter()
                    .find_map(|&n| {
                        // SAFETY: rb(b, g) runs after rb_sync(n, g - 1) wrote this list (module docs).
                        let list = unsafe { &self.blocks[n].published(prev).owned };
                        list.binary_search_by_key(&key, |e| (e.a, e.b))
                            .ok()
                            .map(|i| list[i].impulse)
                    })
                    .unwrap_or(glam::DVec3::ZERO)
            })
            .collect();
        let mut impulses = Vec::new();
        let warm = WarmStart {
            targets: &w.targets,
            impulses: &initial,
        };
        resolve_impulses_warm(&w.bodies, &contacts, &self.params, self.dt_sub(), warm, &mut impulses);
        self.record_owned(w, &blk.planes, &contacts, &impulses, Some(&initial));
        w.solved = impulses;
        w.contact_list = contacts;
    }

    /// Turns the owned contacts' impulses (minus `initial`, what earlier rounds already applied) into
    /// the velocity changes of the bodies they touch (`w.deltas`, one entry per body id) and records
    /// their totals in `w.owned` for the neighbours' next round.
    fn record_owned(
        &self,
        w: &mut super::Work,
        planes: &[Plane],
        contacts: &[Contact],
        impulses: &[glam::DVec3],
        initial: Option<&[glam::DVec3]>,
    ) {
        let locals = w.locals;
        w.owned.clear();
        if contacts.iter().all(|c| c.a >= locals) {
            // No contact is b's: no velocity change, no owned impulse (and no scratch to allocate).
            return;
        }
        let n = w.bodies.len();
        let mut dv = vec![glam::DVec3::ZERO; n];
        let mut dw = vec![glam::DVec3::ZERO; n];
        let mut touched = vec![false; n];
        for (k, (c, total)) in contacts.iter().zip(impulses).enumerate() {
            // Owned: the lower-id body (a) or the sphere of a plane contact is local.
            if c.a >= locals {
                continue;
            }
            if self.rounds > 1 {
                w.owned.push(OwnedImpulse {
                    a: w.bodies[c.a].id,
                    b: contact_key_b(c, &w.bodies, planes),
                    impulse: *total,
                });
            }
            let j = match initial {
                Some(i) => *total - i[k],
                None => *total,
            };
            let a = &w.bodies[c.a];
            if !a.fixed {
                dv[c.a] += j * a.inv_mass();
                dw[c.a] += (c.point - a.position).cross(j) * a.inv_inertia();
                touched[c.a] = true;
            }
            if let Some(o) = c.b {
                let b = &w.bodies[o];
                if !b.fixed {
                    dv[o] -= j * b.inv_mass();
                    dw[o] -= (c.point - b.position).cross(j) * b.inv_inertia();
                    touched[o] = true;
                }
            }
        }
        w.owned.sort_unstable_by_key(|e| (e.a, e.b));
        // Velocity changes by body id (slots are sorted by id; periodic images of one body merged).
        let mut order: Vec<usize> = (0..n).filter(|&i| touched[i]).collect();
        order.sort_by_key(|&i| (w.bodies[i].id, i));
        for i in order {
            let d = Delta {
                id: w.bodies[i].id,
                dv: dv[i],
                dw: dw[i],
            };
            match w.deltas.last_mut() {
                Some(last) if last.id == d.id => {
                    last.dv += d.dv;
                    last.dw += d.dw;
                }
                _ => w.deltas.push(d),
            }
        }
    }

    /// Task `rb_sync(b, g)`; see the module docs.
    ///
    /// # Safety
    /// Must run ordered by the edges of the module docs against the other rigid-body tasks.
    pub unsafe fn rb_sync(&self, b: usize, g: u64) {
        self.publish(b, g)
    }

    /// What `rb_sync(b, g)` does (module docs); under Jacobi the end of `rb(b, g)`.
    ///
    /// # Safety
    /// As for [`Particles::rb_sync`].
    unsafe fn publish(&self, b: usize, g: u64) {
        let blk = &self.blocks[b];
        let w = &*blk.work.get();
        let out = &mut *blk.published[(g % 2) as usize].get();
        let dt = self.dt_sub();
        // Between the rounds of a sub-step only the velocities change.
        let round = (g - 1) % self.rounds as u64;
        let last_round = round + 1 == self.rounds as u64;
        let sub = (g - 1) / self.rounds as u64 + 1;
        let jacobi = self.solver == ContactSolver::Jacobi;
        let locals = &w.bodies[..w.locals];
        // Jacobi from the second sweep on: this parity's list was published two rounds back in the same
        // sub-step, with the same bodies in the same order and the same values but the velocities.
        let same_bodies = jacobi && round >= 2 && out.bodies.len() == locals.len();
        if same_bodies {
            debug_assert!(out.bodies.iter().map(|x| x.id).eq(locals.iter().map(|x| x.id)));
            for (o, x) in out.bodies.iter_mut().zip(locals) {
                o.velocity = x.velocity;
                o.angular_velocity = x.angular_velocity;
            }
        } else {
            out.bodies.clear();
            out.bodies.extend_from_slice(locals);
            out.homes.clear();
        }
        out.owned.clear();
        out.owned.extend_from_slice(&w.owned);
        out.counts.clear();
        // Jacobi: b's own sweep gave its locals their velocities; the first round publishes their counts.
        if jacobi && round == 0 {
            out.counts.extend_from_slice(&w.jacobi.counts[..w.locals]);
        }
        for (i, x) in out.bodies.iter_mut().enumerate() {
            for &m in blk.near.iter().filter(|_| !jacobi) {
                let wm = &*self.blocks[m].work.get();
                if let Ok(k) = wm.deltas.binary_search_by_key(&x.id, |d| d.id) {
                    x.velocity += wm.deltas[k].dv;
                    x.angular_velocity += wm.deltas[k].dw;
                }
            }
            if !last_round {
                if !same_bodies {
                    out.homes.push(self.home(x.position) as u32);
                }
                continue;
            }
            let old = x.position;
            integrate_positions(std::slice::from_mut(x), dt);
            let moved = (x.position - old).length();
            x.position = self.wrap(x.position);
            let home = self.home(x.position);
            if moved.is_nan() || moved > self.max_move || !x.position.is_finite() {
                self.fail(
                    g,
                    b,
                    format!(
                        "particles unstable at sub-step {sub} (step {}): body {} in block {b} moved {moved:.3e} cells in \
                         one sub-step (at most {:.3e} allowed by the block size); raise particles.subcycles, lower \
                         the time step or the forces",
                        (sub - 1) / self.subcycles as u64 + 1,
                        x.id,
                        self.max_move
                    ),
                );
            } else if !self.active[home] {
                self.fail(
                    g,
                    b,
                    format!(
                        "body {} left the blocks that have rigid-body tasks (from block {b} into block {home}) at \
                         sub-step {sub}; lower processes.steps_per_graph",
                        x.id
                    ),
                );
            }
            if same_bodies {
                out.homes[i] = home as u32;
            } else {
                out.homes.push(home as u32);
            }
        }
    }
}

/// The second key of contact `c` for [`OwnedImpulse::b`]: body b's id, or the plane's id with
/// [`PLANE_KEY`] set.
pub(super) fn contact_key_b(c: &Contact, bodies: &[Body], planes: &[Plane]) -> u64 {
    match (c.b, c.plane) {
        (Some(o), _) => bodies[o].id,
        (None, Some(k)) => planes[k].id | PLANE_KEY,
        (None, None) => PLANE_KEY | (u64::MAX >> 1),
    }
}
