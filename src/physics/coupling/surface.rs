//! The boundary pass at particle surfaces (eq. 6: CLI, or simple bounce-back) and the momentum exchange
//! (eqs. 7–9) summed per body.

use crate::physics::block::Block;
use crate::physics::particle_cells::{BodyForce, ParticleCells};
use blockflow_kernels::coupling::{cli_link, link_torque, momentum_exchange, sbb_link, surface_velocity};
use blockflow_kernels::d3q19::{C, OPP};
use blockflow_kernels::Real;
use glam::DVec3;

/// Boundary pass at the particle surfaces on field `p` (eq. 6, CLI or simple bounce-back), writing the
/// reflected PDFs into the particle cells, and the momentum exchange (eqs. 7–9) summed per body in link
/// order into `pc.forces`.
///
/// # Safety
/// Writes particle cells and reads fluid cells (ghosts included) of field `p`; no other task may write
/// them concurrently.
pub unsafe fn boundary<T: Real>(b: &Block<T>, pc: &mut ParticleCells, p: usize) {
    let f = b.field(p);
    let l = b.layout;
    let data = f.raw();
    let mut acc = vec![(DVec3::ZERO, DVec3::ZERO); pc.bodies.len()];
    for e in &pc.exchanged {
        if let Ok(k) = pc.bodies.binary_search_by_key(&e.id, |m| m.id) {
            acc[k] = (e.force, e.torque);
        }
    }
    for link in &pc.links {
        let q = link.q as usize;
        let m = &pc.bodies[link.body as usize];
        let f_out = (*data.add(q * l.stride + link.fluid)).to_f64();
        let rel_b = link.rel + link.delta * DVec3::new(C[q][0] as f64, C[q][1] as f64, C[q][2] as f64);
        let v_b = surface_velocity(m.velocity, m.angular_velocity, DVec3::ZERO, rel_b);
        let f_in = match link.second {
            Some(s) => {
                let opp = (*data.add(OPP[q] * l.stride + link.fluid)).to_f64();
                let sec = (*data.add(q * l.stride + s)).to_f64();
                cli_link(q, f_out, opp, sec, link.delta, v_b)
            }
            None => sbb_link(q, f_out, v_b),
        };
        let solid = (link.fluid as isize + l.offset(C[q])) as usize;
        let stored = T::from_f64(f_in);
        *data.add(OPP[q] * l.stride + solid) = stored;
        let force = momentum_exchange(q, f_out, stored.to_f64(), v_b);
        let e = &mut acc[link.body as usize];
        e.0 += force;
        e.1 += link_torque(rel_b, DVec3::ZERO, force);
    }
    pc.forces.clear();
    for (m, (force, torque)) in pc.bodies.iter().zip(acc) {
        if force != DVec3::ZERO || torque != DVec3::ZERO {
            pc.forces.push(BodyForce {
                id: m.id,
                force,
                torque,
            });
        }
    }
}
