//! The boundary pass at particle surfaces (eq. 6: CLI, or simple bounce-back) and the momentum exchange
//! (eqs. 7–9) summed per body. The links are those of the mapping's link cells; each link's body, offset
//! from the body centre and second fluid cell are gathered here (as waLBerla's boundary handling does),
//! in batches whose δ_q, boundary velocity and returned PDF the kernels compute in vector lanes
//! ([`blockflow_kernels::link_batch`]); the PDFs a batch needs are prefetched a few cells ahead, since
//! they lie in up to 19 arrays.

use super::min_image;
use crate::config::SurfaceBoundary;
use crate::physics::block::Block;
use crate::physics::domain::DomainSpec;
use crate::physics::particle_cells::{BodyForce, ParticleCells};
use blockflow_kernels::coupling::{link_torque, momentum_exchange, RHO0};
use blockflow_kernels::d3q19::{C, OPP, Q, W};
use blockflow_kernels::link_batch::{LinkBatch, LINK_BATCH};
use blockflow_kernels::prefetch::prefetch;
use blockflow_kernels::Real;
use glam::DVec3;

/// How many link cells ahead the boundary pass asks for PDFs.
const PREFETCH_AHEAD: usize = 8;

/// Entries of the boundary pass's direct-mapped cache of body slots (a power of two).
const BODY_CACHE: usize = 64;

/// Boundary pass at the particle surfaces on the state of parity `p` (eq. 6, CLI or simple bounce-back by `mode`),
/// writing the reflected PDFs into the particle cells, and the momentum exchange (eqs. 7–9) summed per
/// body in link order (cells in order, directions ascending) into `pc.forces`. Each link of a link cell
/// gets its body from the owner of x_f + c_q, δ_q from the ray–sphere intersection when `mode` asks for
/// the CLI and the second fluid cell x_f − c_q exists (else simple bounce-back, δ_q = 1/2), and the
/// boundary velocity v_b at x_b = x_f + δ_q c_q (below eq. 6).
///
/// # Safety
/// Writes particle cells and reads fluid cells (ghosts included) of the state of parity `p`; no other task may write
/// them concurrently.
pub unsafe fn boundary<T: Real>(d: &DomainSpec, b: &Block<T>, pc: &mut ParticleCells, p: usize, mode: SurfaceBoundary) {
    let l = b.layout;
    let data = b.field(p).raw();
    let sl = *b.slots(p);
    let mut acc = vec![(DVec3::ZERO, DVec3::ZERO); pc.bodies.len()];
    for e in &pc.exchanged {
        if let Ok(k) = pc.bodies.binary_search_by_key(&e.id, |m| m.id) {
            acc[k] = (e.force, e.torque);
        }
    }
    let cells = d.cells();
    let cells_f = [cells[0] as f64, cells[1] as f64, cells[2] as f64];
    let offs: [isize; Q] = std::array::from_fn(|q| l.offset(C[q]));
    let cli_wanted = mode == SurfaceBoundary::Cli;
    let (owner, bodies) = (&pc.owner, &pc.bodies);
    let batch = &mut *pc.link_batch;
    batch.len = 0;
    // Per link of the batch: direction, covered cell, body slot.
    let mut slots = [(0u8, 0u32, 0u32); LINK_BATCH];
    // Applies the batch: the returned PDFs into the covered cells, the momentum exchange (eqs. 7–9)
    // summed per body in link order.
    let mut flush = |batch: &mut LinkBatch, slots: &[(u8, u32, u32)]| {
        batch.solve();
        for (j, &(q, solid, k)) in slots[..batch.len].iter().enumerate() {
            let q = q as usize;
            let stored = T::from_f64(batch.f_in[j]);
            *data.add(sl.at(OPP[q], solid as usize)) = stored;
            let v_b = DVec3::new(batch.v_b[0][j], batch.v_b[1][j], batch.v_b[2][j]);
            let rel_b = DVec3::new(batch.rel_b[0][j], batch.rel_b[1][j], batch.rel_b[2][j]);
            let force = momentum_exchange(q, batch.f_out[j], stored.to_f64(), v_b);
            let e = &mut acc[k as usize];
            e.0 += force;
            e.1 += link_torque(rel_b, DVec3::ZERO, force);
        }
        batch.len = 0;
    };
    // Slots of the bodies met, direct-mapped by id (links of one cell and of neighbouring cells mostly
    // share a body, and a block sees few bodies): a hit replaces the binary search.
    let mut seen = [(u64::MAX, 0usize); BODY_CACHE];
    let link_cells = &pc.link_cells;
    for (j, lc) in link_cells.iter().enumerate() {
        // The PDFs of a link cell lie in up to 19 arrays: ask for those of a cell a few ahead.
        if let Some(ahead) = link_cells.get(j + PREFETCH_AHEAD) {
            let i = ahead.cell as usize;
            let mut dirs = ahead.dirs;
            while dirs != 0 {
                let q = dirs.trailing_zeros() as usize;
                dirs &= dirs - 1;
                let solid = (i as isize + offs[q]) as usize;
                prefetch(data.add(sl.at(q, i)));
                prefetch(data.add(sl.at(OPP[q], solid)));
                prefetch(owner.as_ptr().add(solid));
                if cli_wanted && ahead.second_fluid & (1 << q) != 0 {
                    prefetch(data.add(sl.at(OPP[q], i)));
                    prefetch(data.add(sl.at(q, (i as isize - offs[q]) as usize)));
                }
            }
        }
        let i = lc.cell as usize;
        // The fluid cell's centre (the integer coordinates are exact in f64).
        let xc: [f64; 3] = std::array::from_fn(|a| (b.origin[a] as u32 + lc.xyz[a]) as f64 - 0.5);
        let mut dirs = lc.dirs;
        while dirs != 0 {
            let q = dirs.trailing_zeros() as usize;
            dirs &= dirs - 1;
            let solid = (i as isize + offs[q]) as usize;
            let id = owner[solid] - 1;
            let e = &mut seen[id as usize % BODY_CACHE];
            let k = if e.0 == id {
                e.1
            } else {
                match bodies.binary_search_by_key(&id, |m| m.id) {
                    Ok(k) => {
                        *e = (id, k);
                        k
                    }
                    Err(_) => continue,
                }
            };
            let m = &bodies[k];
            let second = (i as isize - offs[q]) as usize;
            let cli = cli_wanted && lc.second_fluid & (1 << q) != 0;
            let n = batch.len;
            // Offset of the fluid cell centre from the body centre, nearest image.
            batch.rel[0][n] = min_image(xc[0] - m.position.x, cells_f[0], d.periodic[0]);
            batch.rel[1][n] = min_image(xc[1] - m.position.y, cells_f[1], d.periodic[1]);
            batch.rel[2][n] = min_image(xc[2] - m.position.z, cells_f[2], d.periodic[2]);
            batch.radius[n] = m.radius;
            for (a, &c) in C[q].iter().enumerate() {
                batch.velocity[a][n] = m.velocity[a];
                batch.angular_velocity[a][n] = m.angular_velocity[a];
                batch.c[a][n] = c as f64;
            }
            batch.w12[n] = W12[q];
            batch.w6[n] = W6[q];
            batch.cli[n] = cli;
            batch.f_out[n] = (*data.add(sl.at(q, i))).to_f64();
            (batch.f_opp[n], batch.f_second[n]) = if cli {
                (
                    (*data.add(sl.at(OPP[q], i))).to_f64(),
                    (*data.add(sl.at(q, second))).to_f64(),
                )
            } else {
                (0.0, 0.0)
            };
            slots[n] = (q as u8, solid as u32, k as u32);
            batch.len += 1;
            if batch.len == LINK_BATCH {
                flush(batch, &slots);
            }
        }
    }
    if batch.len > 0 {
        flush(batch, &slots);
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

/// 12 w_q ρ0 per direction (the CLI's moving-wall coefficient times 1 + 2δ_q), as `cli_link` computes it.
const W12: [f64; Q] = {
    let mut w = [0.0; Q];
    let mut q = 0;
    while q < Q {
        w[q] = 12.0 * W[q] * RHO0;
        q += 1;
    }
    w
};

/// 6 w_q ρ0 per direction (simple bounce-back's moving-wall coefficient), as `sbb_link` computes it.
const W6: [f64; Q] = {
    let mut w = [0.0; Q];
    let mut q = 0;
    while q < Q {
        w[q] = 6.0 * W[q] * RHO0;
        q += 1;
    }
    w
};
