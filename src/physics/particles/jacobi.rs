//! The rounds of a sub-step under `particles.solver = "jacobi"`: projected Jacobi with mass splitting
//! ([`blockflow_kernels::rigid::JacobiSolve`]) over the contacts of all blocks, with one exchange of
//! velocities per sweep. A sub-step of I sweeps is I + 1 rounds (phases of `rb`/`rb_sync`):
//!
//! | round | `rb(b, g)` | `rb_sync(b, g)` publishes |
//! |---|---|---|
//! | 0 | gather locals and shadows, forces, detect; keep the contacts that touch a local; count each local's contacts; targets; start every contact from `warm_start` × its impulse of the last sub-step and add those impulses | locals (velocities after forces and warm start), their contact counts |
//! | 1 … I | velocities of every gathered body from its home's list; one sweep; after the last, the impulses of the contacts b owns | locals (after the last sweep: moved) and, after the last, those impulses |
//!
//! Why the result does not depend on the layout: every block that holds a body also holds all of its
//! contacts and their partners (the halo), computes each contact's impulse change from the same
//! published velocities, counts and targets, and sums a body's changes in the contacts' (body id) order.
//! So the owner of a body computes the bits a single block holding everything would. The warm start of
//! contact (a, b) is looked up in the list that published body a, whose owner recorded it (a contact is
//! owned by the home of its lower-id body), so it too is the same in every block that solves it. In a box
//! without periodic axes the final state is bitwise the same for any block layout; across a periodic face
//! a shadow's shifted position, and with it the contact geometry, may differ by rounding.

use super::tasks::contact_key_b;
use super::{BlockBodies, OwnedImpulse, Particles, Work};
use blockflow_kernels::rigid::{
    apply_impulses, final_relaxation, project_impulse, resolve_targets, Contact, JacobiSolve,
};
use glam::DVec3;

/// A block's state of the Jacobi solve in the current sub-step (part of its [`Work`]).
#[derive(Clone, Debug, Default)]
pub struct JacobiWork {
    /// Home block of each gathered body (for locals the block itself), from the lists they were gathered
    /// from.
    pub homes: Vec<u32>,
    /// Number of contacts of each gathered body: counted here for locals; for shadows taken from their
    /// homes' lists at the first sweep.
    pub counts: Vec<u32>,
    /// (home block, entry in its published list) of each gathered body, found at the first sweep: where
    /// every sweep reads the body's velocities.
    pub sources: Vec<(u32, u32)>,
    /// The solve, from the first sweep to the last.
    pub solve: Option<JacobiSolve>,
}

impl Particles {
    /// Round 0 of a Jacobi sub-step in block `b` (module docs), after the gather into `w`.
    pub(super) fn jacobi_start(&self, b: usize, g: u64, prev: usize, scanned: u64, w: &mut Work) {
        let blk = &self.blocks[b];
        let seen = self.detect_substep(blk, g, scanned, w);
        let locals = w.locals;
        let n = w.bodies.len();
        let jw = &mut w.jacobi;
        jw.solve = None;
        jw.homes.clear();
        jw.homes.extend(w.origins.iter().enumerate().map(|(i, &(k, index))| {
            if i < locals {
                return b as u32;
            }
            // SAFETY: rb(b, g) runs after rb_sync(n, g - 1) wrote this list (tasks' module docs).
            unsafe { self.blocks[blk.neighbours[k as usize].block].published(prev).homes[index as usize] }
        }));
        let contacts: Vec<Contact> = seen
            .into_iter()
            .filter(|c| c.a < locals || c.b.is_some_and(|o| o < locals))
            .collect();
        jw.counts.clear();
        jw.counts.resize(n, 0);
        for c in &contacts {
            jw.counts[c.a] += 1;
            if let Some(o) = c.b {
                jw.counts[o] += 1;
            }
        }
        let dt = self.dt_sub();
        w.targets = resolve_targets(&w.bodies, &contacts, &self.params, dt);
        let warm: Vec<DVec3> = contacts.iter().map(|c| self.warm_impulse(blk, prev, w, c)).collect();
        apply_impulses(&mut w.bodies, &contacts, &warm);
        w.solved = warm;
        w.contact_list = contacts;
    }

    /// `warm_start` times the impulse contact `c` had at the end of the last sub-step (zero for a new
    /// contact), projected onto its constraints for the current normal. The owner of body a recorded it
    /// in the list that published a.
    fn warm_impulse(&self, blk: &BlockBodies, prev: usize, w: &Work, c: &Contact) -> DVec3 {
        if self.warm_start == 0.0 {
            return DVec3::ZERO;
        }
        let (k, _) = w.origins[c.a];
        // SAFETY: as in `jacobi_start`.
        let list = unsafe { &self.blocks[blk.neighbours[k as usize].block].published(prev).owned };
        let key = (w.bodies[c.a].id, contact_key_b(c, &w.bodies, &blk.planes));
        match list.binary_search_by_key(&key, |e| (e.a, e.b)) {
            Ok(i) => project_impulse(list[i].impulse * self.warm_start, c.normal, self.params.friction),
            Err(_) => DVec3::ZERO,
        }
    }

    /// Round `round` ≥ 1 of phase `g`, a Jacobi sub-step, in block `b`: one sweep (module docs).
    pub(super) fn jacobi_sweep(&self, b: usize, g: u64, prev: usize, round: usize, w: &mut Work) {
        w.owned.clear();
        if w.contact_list.is_empty() {
            return;
        }
        let contacts = std::mem::take(&mut w.contact_list);
        let jw = &mut w.jacobi;
        if round == 1 {
            jw.sources.clear();
            for (i, body) in w.bodies.iter().enumerate() {
                let home = jw.homes[i];
                // SAFETY: rb(b, g) runs after rb_sync(h, g - 1) of every neighbour h (tasks' module docs);
                // a gathered body's home is a neighbour of b.
                let list = unsafe { self.blocks[home as usize].published(prev) };
                let Ok(index) = list.bodies.binary_search_by_key(&body.id, |x| x.id) else {
                    // Only after a body ran away (already recorded as a failure): it was gathered from a
                    // list whose home for it is no longer a neighbour that publishes it. The sub-step's
                    // sweeps stop here; the run ends with the recorded failure.
                    self.fail(
                        g,
                        b,
                        format!(
                            "body {} gathered by block {b} is not published by its home block {home} at \
                             sub-step {}; the bodies moved more than the halo allows: raise particles.subcycles",
                            body.id,
                            (g - 1) / self.rounds as u64 + 1
                        ),
                    );
                    jw.solve = None;
                    return;
                };
                jw.sources.push((home, index as u32));
                if i >= w.locals {
                    jw.counts[i] = list.counts[index];
                }
            }
        }
        for (body, &(home, index)) in w.bodies.iter_mut().zip(&jw.sources) {
            // SAFETY: as above.
            let src = unsafe { &self.blocks[home as usize].published(prev).bodies[index as usize] };
            body.velocity = src.velocity;
            body.angular_velocity = src.angular_velocity;
        }
        let p = &self.params;
        let solve = jw.solve.get_or_insert_with(|| {
            JacobiSolve::new(
                &w.bodies,
                &contacts,
                &jw.counts,
                &w.targets,
                &w.solved,
                p,
                self.dt_sub(),
            )
        });
        let relax = final_relaxation(round - 1, self.rounds - 1, p);
        solve.sweep(&mut w.bodies, &contacts, p, relax);
        if round + 1 == self.rounds {
            let planes = &self.blocks[b].planes;
            for (k, c) in contacts.iter().enumerate().filter(|(_, c)| c.a < w.locals) {
                w.owned.push(OwnedImpulse {
                    a: w.bodies[c.a].id,
                    b: contact_key_b(c, &w.bodies, planes),
                    impulse: solve.impulse(k, c),
                });
            }
            w.owned.sort_unstable_by_key(|e| (e.a, e.b));
            jw.solve = None;
        }
        w.contact_list = contacts;
    }
}
