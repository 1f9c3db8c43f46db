//! The coupling tasks of a time step and the global force view:
//!
//! | task | reads | writes |
//! |---|---|---|
//! | `map(b, t)` | published bodies of b's neighbours (state after step t−1) | b's particle overlay (owners, segments, links, bodies) |
//! | `reconstruct(b, t)` | b's overlay, b's field | b's field: cells that turned fluid |
//! | `boundary(b, t)` (with particles) | b's field, overlay links | particle cells of b's field, overlay forces |
//! | `forces(b, t)` | overlay forces of b's neighbours | force and torque of the bodies b published |
//!
//! `forces(b, t)` sums, for every body b published, the partial forces of the blocks around b in
//! ascending block-id order (eq. 8, 9) and stores them in the body, averaged with the previous step's
//! force when `particles.force_averaging` is on: the hydrodynamic force is then held constant over the S
//! rigid-body sub-steps that follow (Algorithm 1).

use super::map_with;
use crate::physics::block::Block;
use crate::physics::domain::DomainSpec;
use crate::physics::particle_cells::{BodyForce, MapBody, ParticleCells};
use crate::physics::particles::Particles;
use blockflow_kernels::Real;
use glam::DVec3;

/// Distance from `x` to the box [lo, hi] taking the nearest periodic image on periodic axes.
fn image_distance(d: &DomainSpec, x: DVec3, lo: DVec3, hi: DVec3) -> f64 {
    let n = d.cells();
    let mut s = 0.0;
    for a in 0..3 {
        let len = n[a] as f64;
        let shifts: &[f64] = if d.periodic[a] { &[-1.0, 0.0, 1.0] } else { &[0.0] };
        let mut best = f64::INFINITY;
        for k in shifts {
            let y = x[a] + k * len;
            best = best.min((lo[a] - y).max(y - hi[a]).max(0.0));
        }
        s += best * best;
    }
    s.sqrt()
}

/// The bodies whose spheres reach block `b` or its ghost layer, from the lists its neighbours published
/// after `steps` steps, sorted by id.
pub fn bodies_near<T: Real>(parts: &Particles, blk: &Block<T>, steps: u64) -> Vec<MapBody> {
    let d = parts.domain();
    let pb = &parts.blocks[blk.id];
    let lo = pb.lo - DVec3::ONE;
    let hi = pb.hi + DVec3::ONE;
    let par = parts.parity(steps);
    let mut out = Vec::new();
    for &n in &pb.near {
        // SAFETY: the graph orders the publishing rb_sync (rb under Jacobi) before and the next forces
        // task after.
        let list = unsafe { parts.blocks[n].published(par) };
        for body in &list.bodies {
            if image_distance(d, body.position, lo, hi) <= body.radius {
                out.push(MapBody {
                    id: body.id,
                    position: body.position,
                    velocity: body.velocity,
                    angular_velocity: body.angular_velocity,
                    radius: body.radius,
                });
            }
        }
    }
    out.sort_by_key(|m| m.id);
    out
}

/// Task `map(b, t)`: maps the bodies as they are after `steps` steps (with `no_skip`, a block with no
/// body near is scanned like any other instead of taking the mapping's fast path).
///
/// # Safety
/// No other task may access b's overlay concurrently (see the module table).
pub unsafe fn map_task<T: Real>(parts: &Particles, blk: &Block<T>, steps: u64, no_skip: bool) {
    let bodies = bodies_near(parts, blk, steps);
    let pc: &mut ParticleCells = blk.particle_cells_mut();
    map_with(parts.domain(), blk, pc, bodies, !no_skip);
}

/// Task `map(b, t)` of a block without fluid (only with `run.no_skip`): maps the bodies near it into a
/// scratch overlay and drops it. The block keeps having no overlay (a block without
/// fluid never has one; block serialisation relies on that), so nothing changes.
pub fn map_scratch<T: Real>(parts: &Particles, blk: &Block<T>, steps: u64) {
    let bodies = bodies_near(parts, blk, steps);
    let mut pc = ParticleCells::default();
    map_with(parts.domain(), blk, &mut pc, bodies, false);
    std::hint::black_box(&pc);
}

/// Task `forces(b, t)`: the hydrodynamic force and torque of every body b published after `steps` steps,
/// summed over the blocks around b in ascending block-id order.
///
/// # Safety
/// No other task may access b's published list of that parity, or write the overlays of b's neighbours,
/// concurrently.
pub unsafe fn forces_task<T: Real>(parts: &Particles, blocks: &[Block<T>], b: usize, steps: u64, average: bool) {
    let pb = &parts.blocks[b];
    let list = pb.published_mut(parts.parity(steps));
    for body in list.bodies.iter_mut() {
        let (mut f, mut t) = (DVec3::ZERO, DVec3::ZERO);
        for &m in &pb.near {
            let forces = blocks[m].body_forces();
            if let Ok(k) = forces.binary_search_by_key(&body.id, |x| x.id) {
                f += forces[k].force;
                t += forces[k].torque;
            }
        }
        if average {
            // Mean of this and the previous step's force: removes the period-2 oscillation of the
            // momentum exchange that otherwise destabilises light particles (ρp/ρf ≲ 2). Before the first
            // step the previous force is zero, so every step's impulse reaches the body in full, half now
            // and half one step later (momentum stays balanced up to the half step in flight).
            body.force = 0.5 * (f + body.force_prev);
            body.torque = 0.5 * (t + body.torque_prev);
        } else {
            body.force = f;
            body.torque = t;
        }
        body.force_prev = f;
        body.torque_prev = t;
    }
}

/// Maps every block with fluid (set-up, and the only mapping when all bodies are fixed).
pub fn map_all<T: Real>(parts: &Particles, blocks: &[Block<T>], steps: u64) {
    for blk in blocks.iter().filter(|b| b.fluid_cells > 0) {
        // SAFETY: set-up, nothing runs concurrently.
        unsafe { map_task(parts, blk, steps, false) };
    }
}

/// Hydrodynamic force and torque on every body from the last boundary pass, summed over blocks in
/// block-id order, sorted by body id.
pub fn total_forces<T: Real>(blocks: &[Block<T>]) -> Vec<BodyForce> {
    sum_forces(
        blocks
            .iter()
            .map(|b| b.particle_cells().map_or(&[][..], |pc| &pc.forces)),
    )
}

/// The per-block force lists (given in ascending block-id order) summed per body in that order, sorted
/// by body id.
pub fn sum_forces<'a>(per_block: impl IntoIterator<Item = &'a [BodyForce]>) -> Vec<BodyForce> {
    let mut all: Vec<BodyForce> = Vec::new();
    for list in per_block {
        for f in list {
            match all.iter_mut().find(|x| x.id == f.id) {
                Some(x) => {
                    x.force += f.force;
                    x.torque += f.torque;
                }
                None => all.push(*f),
            }
        }
    }
    all.sort_by_key(|x| x.id);
    all
}
