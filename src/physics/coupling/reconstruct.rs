//! Reconstruction (Algorithm 6) of the cells a body uncovered, and the momentum covered and rebuilt cells
//! exchange with the bodies.

use super::cell_offset;
use crate::physics::block::Block;
use crate::physics::domain::DomainSpec;
use crate::physics::geometry::flags;
use crate::physics::particle_cells::{BodyForce, ParticleCells};
use blockflow_kernels::coupling::{surface_velocity, RHO0};
use blockflow_kernels::d3q19::{C, Q};
use blockflow_kernels::trt::{moments, post_collision_equilibrium};
use blockflow_kernels::{Real, TrtParams};
use glam::DVec3;

/// Reconstruction (Algorithm 6) of the cells that turned fluid: the (forced) equilibrium with the
/// surface velocity of the body that left, V + W × (x − X), and the mean δρ of the cell's interior fluid
/// neighbours that were fluid before; with no such neighbour, ρ = ρ0 (δρ = 0), the reference density of
/// the incompressible model.
///
/// With `conserve_momentum`, a covered cell's fluid momentum goes to the body that covers it and a rebuilt
/// cell's momentum is taken from the body that left it (fluid plus bodies conserve momentum exactly);
/// without, the bodies feel only the momentum exchange at their surface links.
///
/// # Safety
/// No other task may access this block's state of parity `p` concurrently.
pub unsafe fn reconstruct<T: Real>(
    d: &DomainSpec,
    b: &Block<T>,
    pc: &mut ParticleCells,
    p: usize,
    params: &TrtParams,
    conserve_momentum: bool,
) {
    pc.exchanged.clear();
    if pc.turned.is_empty() && pc.covered.is_empty() {
        return;
    }
    let l = b.layout;
    let f = b.field_mut(p);
    let sl = *b.slots(p);
    let mut add = |id: u64, x: usize, j: DVec3| {
        if !conserve_momentum {
            return;
        }
        let Ok(k) = pc.bodies.binary_search_by_key(&id, |m| m.id) else {
            return;
        };
        let m = &pc.bodies[k];
        let r = cell_offset(d, b.origin, l.coords(x), m.position);
        let e = match pc.exchanged.binary_search_by_key(&id, |e| e.id) {
            Ok(e) => e,
            Err(e) => {
                pc.exchanged.insert(
                    e,
                    BodyForce {
                        id,
                        force: DVec3::ZERO,
                        torque: DVec3::ZERO,
                    },
                );
                e
            }
        };
        pc.exchanged[e].force += j;
        pc.exchanged[e].torque += r.cross(j);
    };
    // A covered cell's fluid momentum ρ0 u goes to the body that covers it.
    for &(i, id) in pc.covered.iter().filter(|_| conserve_momentum) {
        let cell: [T; Q] = f.post_cell(&sl, i);
        let (_, u) = moments(&cell, params.force);
        add(id, i, RHO0 * DVec3::from(u));
    }
    let turned: std::collections::HashSet<usize> = pc.turned.iter().map(|t| t.0).collect();
    let [fx, fy, fz] = l.full();
    for &(i, id) in &pc.turned {
        let mut sum = 0.0;
        let mut count = 0usize;
        for c in C.iter().skip(1) {
            let t = (i as isize + l.offset(*c)) as usize;
            let [x, y, z] = l.coords(t);
            let interior = x >= 1 && y >= 1 && z >= 1 && x < fx - 1 && y < fy - 1 && z < fz - 1;
            if interior && b.flags[t] & flags::FLUID != 0 && pc.owner[t] == 0 && !turned.contains(&t) {
                let cell: [T; Q] = f.post_cell(&sl, t);
                sum += moments(&cell, params.force).0;
                count += 1;
            }
        }
        let drho = if count > 0 { sum / count as f64 } else { RHO0 - 1.0 };
        let u = match pc.bodies.binary_search_by_key(&id, |m| m.id) {
            Ok(k) => {
                let m = &pc.bodies[k];
                let rel = cell_offset(d, b.origin, l.coords(i), m.position);
                surface_velocity(m.velocity, m.angular_velocity, DVec3::ZERO, rel)
            }
            Err(_) => DVec3::ZERO,
        };
        let eq = post_collision_equilibrium(drho, u.to_array(), params);
        let cell: [T; Q] = std::array::from_fn(|q| T::from_f64(eq[q]));
        f.set_post_cell(&sl, i, &cell);
        // ... and a rebuilt cell's momentum comes from the body that left it.
        let (_, u_new) = moments(&cell, params.force);
        add(id, i, -RHO0 * DVec3::from(u_new));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::geometry::Geometry;
    use crate::physics::particle_cells::MapBody;

    /// Reconstruction (Algorithm 6): a cell whose neighbours are all solid gets ρ = ρ0 (δρ = 0), a cell
    /// with fluid neighbours their mean δρ; both get the body's surface velocity V + W × (x − X) (exact
    /// moments to 1e-15, the equilibrium's own rounding).
    #[test]
    fn reconstruct_uses_neighbour_density_or_rho0_and_surface_velocity() {
        let d = DomainSpec {
            blocks: [1, 1, 1],
            block_size: [10, 10, 10],
            periodic: [true; 3],
        };
        let mut blk = Block::<f64>::new(&d, &Geometry::default(), 0, blockflow_kernels::Pattern::Pull);
        let params = TrtParams {
            tau: 0.8,
            magic: 3.0 / 16.0,
            force: [0.0; 3],
        };
        blk.init(|_| post_collision_equilibrium(0.01, [0.0; 3], &params));
        let l = blk.layout;
        let lonely = l.idx(3, 3, 3);
        let open = l.idx(7, 7, 7);
        let centre = DVec3::new(3.0, 2.5, 2.5);
        let (v, w) = (DVec3::new(0.01, -0.02, 0.005), DVec3::new(0.0, 0.003, -0.001));
        // SAFETY: single-threaded test.
        let pc = unsafe { blk.particle_cells_mut() };
        pc.owner = vec![0; l.sxy * (l.size[2] + 2)];
        for c in C.iter().skip(1) {
            pc.owner[(lonely as isize + l.offset(*c)) as usize] = 8;
        }
        pc.turned = vec![(lonely, 7), (open, 7)];
        pc.bodies = vec![MapBody {
            id: 7,
            position: centre,
            velocity: v,
            angular_velocity: w,
            radius: 2.0,
        }];
        let mut pc = std::mem::take(pc);
        unsafe { reconstruct(&d, &blk, &mut pc, 0, &params, true) };
        for (cell, drho_want) in [(lonely, 0.0), (open, 0.01)] {
            let f: [f64; Q] = blk.field(0).cell(cell);
            let (drho, u) = moments(&f, [0.0; 3]);
            let r = cell_offset(&d, blk.origin, l.coords(cell), centre);
            let want = v + w.cross(r);
            assert!((drho - drho_want).abs() < 1e-15, "δρ {drho}, want {drho_want}");
            assert!((DVec3::from(u) - want).length() < 1e-15, "u {u:?}, want {want}");
        }
        // Momentum handed to the fluid by the two rebuilt cells is taken from the body.
        let e = pc.exchanged.iter().find(|e| e.id == 7).expect("exchange recorded");
        let r1 = cell_offset(&d, blk.origin, l.coords(lonely), centre);
        let r2 = cell_offset(&d, blk.origin, l.coords(open), centre);
        let total = -(v + w.cross(r1)) - (v + w.cross(r2));
        assert!((e.force - total).length() < 1e-15);
        // Without momentum conservation the same cells are rebuilt, bit for bit, and no body is charged.
        let rebuilt: Vec<[f64; Q]> = [lonely, open].iter().map(|&c| blk.field(0).cell(c)).collect();
        blk.init(|_| post_collision_equilibrium(0.01, [0.0; 3], &params));
        unsafe { reconstruct(&d, &blk, &mut pc, 0, &params, false) };
        assert!(pc.exchanged.is_empty());
        for (k, &c) in [lonely, open].iter().enumerate() {
            let f: [f64; Q] = blk.field(0).cell(c);
            assert!(f.iter().zip(&rebuilt[k]).all(|(a, b)| a.to_bits() == b.to_bits()));
        }
    }
}
