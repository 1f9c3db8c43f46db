//! Reconstruction (Algorithm 6) of the cells a body uncovered, and the momentum covered and rebuilt cells
//! exchange with the bodies.

use super::cell_offset;
use crate::config::Refill;
use crate::physics::block::Block;
use crate::physics::domain::DomainSpec;
use crate::physics::geometry::flags;
use crate::physics::particle_cells::{BodyForce, ParticleCells};
use blockflow_kernels::coupling::{grad_non_equilibrium, surface_velocity, RHO0};
use blockflow_kernels::d3q19::{C, Q};
use blockflow_kernels::trt::{moments, post_collision_equilibrium};
use blockflow_kernels::{Layout, PdfField, Real, Slots, TrtParams};
use glam::DVec3;

/// How [`reconstruct`] treats the cells that change state.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rebuild {
    /// Exchange the momentum of covered and rebuilt cells with the bodies (`particles.conserve_momentum`).
    pub conserve_momentum: bool,
    /// Populations of a rebuilt cell (`particles.refill`).
    pub refill: Refill,
}

/// Reconstruction (Algorithm 6) of the cells that turned fluid: the (forced) equilibrium with the
/// surface velocity of the body that left, V + W × (x − X), and the mean δρ of the cell's interior fluid
/// neighbours that were fluid before; with no such neighbour, ρ = ρ0 (δρ = 0), the reference density of
/// the incompressible model.
///
/// With `how.refill = Grad` the rebuilt cell also gets Grad's non-equilibrium part
/// ([`grad_non_equilibrium`]) from the velocity gradient: central differences of the neighbours'
/// velocities where both neighbours along an axis were fluid before, one-sided differences against the
/// rebuilt cell's own velocity where one was, zero where none was. With `how.refill = Extrapolation` the
/// populations are extrapolated along the lattice direction c closest to the outward normal x − X
/// (largest c·(x − X)/|c|) from the cells x + c, x + 2c, x + 3c that were fluid before: quadratic
/// (3f₁ − 3f₂ + f₃) with all three, linear (2f₁ − f₂) with the first two, and as with `Grad` otherwise.
/// With `how.conserve_momentum`, a covered cell's fluid momentum goes to the body that covers it and a
/// rebuilt cell's momentum is taken from the body that left it (fluid plus bodies conserve momentum);
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
    how: Rebuild,
) {
    let conserve_momentum = how.conserve_momentum;
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
    // Interior cells that were fluid before this step's mapping (the rebuilt cells' sources).
    let was_fluid = |t: usize| {
        let [x, y, z] = l.coords(t);
        let interior = x >= 1 && y >= 1 && z >= 1 && x < fx - 1 && y < fy - 1 && z < fz - 1;
        interior && b.flags[t] & flags::FLUID != 0 && pc.owner[t] == 0 && !turned.contains(&t)
    };
    for &(i, id) in &pc.turned {
        let mut sum = 0.0;
        let mut count = 0usize;
        for c in C.iter().skip(1) {
            let t = (i as isize + l.offset(*c)) as usize;
            if was_fluid(t) {
                let cell: [T; Q] = f.post_cell(&sl, t);
                sum += moments(&cell, params.force).0;
                count += 1;
            }
        }
        let drho = if count > 0 { sum / count as f64 } else { RHO0 - 1.0 };
        let body = pc
            .bodies
            .binary_search_by_key(&id, |m| m.id)
            .ok()
            .map(|k| &pc.bodies[k]);
        let rel = body.map(|m| cell_offset(d, b.origin, l.coords(i), m.position));
        let u = match (body, rel) {
            (Some(m), Some(rel)) => surface_velocity(m.velocity, m.angular_velocity, DVec3::ZERO, rel),
            _ => DVec3::ZERO,
        };
        if how.refill == Refill::Extrapolation {
            if let Some(cell) = rel.and_then(|rel| extrapolate(&l, f, &sl, i, rel, &was_fluid)) {
                f.set_post_cell(&sl, i, &cell);
                let (_, u_new) = moments(&cell, params.force);
                add(id, i, -RHO0 * DVec3::from(u_new));
                continue;
            }
        }
        let mut eq = post_collision_equilibrium(drho, u.to_array(), params);
        if matches!(how.refill, Refill::Grad | Refill::Extrapolation) {
            // ∂_a u_b from the axis neighbours that were fluid before.
            let vel = |t: usize| DVec3::from(moments(&f.post_cell(&sl, t), params.force).1);
            let mut grad = [[0.0; 3]; 3];
            for (a, row) in grad.iter_mut().enumerate() {
                let mut e = [0i32; 3];
                e[a] = 1;
                let (hi, lo) = ((i as isize + l.offset(e)) as usize, (i as isize - l.offset(e)) as usize);
                let du = match (was_fluid(hi), was_fluid(lo)) {
                    (true, true) => 0.5 * (vel(hi) - vel(lo)),
                    (true, false) => vel(hi) - u,
                    (false, true) => u - vel(lo),
                    (false, false) => DVec3::ZERO,
                };
                *row = du.to_array();
            }
            let neq = grad_non_equilibrium(params.tau, RHO0 + drho, grad);
            for (v, n) in eq.iter_mut().zip(neq) {
                *v += n;
            }
        }
        let cell: [T; Q] = std::array::from_fn(|q| T::from_f64(eq[q]));
        f.set_post_cell(&sl, i, &cell);
        // ... and a rebuilt cell's momentum comes from the body that left it.
        let (_, u_new) = moments(&cell, params.force);
        add(id, i, -RHO0 * DVec3::from(u_new));
    }
}

/// The populations of cell `i` extrapolated along the lattice direction closest to `normal` (the
/// outward normal x − X of the sphere that left it) from the cells that were fluid before
/// (`was_fluid`): 3f₁ − 3f₂ + f₃ with three of them in a row, 2f₁ − f₂ with two, `None` with fewer. The
/// weights sum to one, so the stored (zero-centred) values extrapolate like the populations.
fn extrapolate<T: Real>(
    l: &Layout,
    f: &PdfField<T>,
    sl: &Slots,
    i: usize,
    normal: DVec3,
    was_fluid: &impl Fn(usize) -> bool,
) -> Option<[T; Q]> {
    let mut best = (0.0, 0);
    for (q, c) in C.iter().enumerate().skip(1) {
        let c = DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64);
        let align = c.dot(normal) / c.length();
        if align > best.0 {
            best = (align, q);
        }
    }
    if best.1 == 0 {
        return None;
    }
    let (c, at, full) = (C[best.1], l.coords(i), l.full());
    let mut along = Vec::with_capacity(3);
    // The cell x + j c, if it lies in the block's array (ghost layer included; `was_fluid` then keeps
    // interior cells only).
    let cell_along = |j: i32| -> Option<usize> {
        let mut t = [0usize; 3];
        for a in 0..3 {
            t[a] = usize::try_from(at[a] as i32 + j * c[a]).ok().filter(|&v| v < full[a])?;
        }
        Some(l.idx(t[0], t[1], t[2]))
    };
    for j in 1..=3 {
        match cell_along(j) {
            Some(t) if was_fluid(t) => along.push(f.post_cell(sl, t)),
            _ => break,
        }
    }
    let v = |k: usize, q: usize| along[k][q].to_f64();
    match along.len() {
        3 => Some(std::array::from_fn(|q| {
            T::from_f64(3.0 * v(0, q) - 3.0 * v(1, q) + v(2, q))
        })),
        2 => Some(std::array::from_fn(|q| T::from_f64(2.0 * v(0, q) - v(1, q)))),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::geometry::Geometry;
    use crate::physics::particle_cells::MapBody;

    /// One periodic block of n³ cells.
    fn periodic_cube(n: usize) -> DomainSpec {
        DomainSpec {
            blocks: [1, 1, 1],
            block_size: [n; 3],
            periodic: [true; 3],
        }
    }

    /// TRT at τ = 0.8 with Λ = 3/16, no body force.
    fn trt() -> TrtParams {
        TrtParams {
            tau: 0.8,
            magic: 3.0 / 16.0,
            force: [0.0; 3],
        }
    }

    /// Reconstruction (Algorithm 6): a cell whose neighbours are all solid gets ρ = ρ0 (δρ = 0), a cell
    /// with fluid neighbours their mean δρ; both get the body's surface velocity V + W × (x − X) (exact
    /// moments to 1e-15, the equilibrium's own rounding).
    #[test]
    fn reconstruct_uses_neighbour_density_or_rho0_and_surface_velocity() {
        let (d, params) = (periodic_cube(10), trt());
        let mut blk = Block::<f64>::new(&d, &Geometry::default(), 0, blockflow_kernels::Pattern::Pull);
        blk.init(|_| post_collision_equilibrium(0.01, [0.0; 3], &params));
        let l = blk.layout;
        let lonely = l.idx(3, 3, 3);
        let open = l.idx(7, 7, 7);
        let centre = DVec3::new(3.0, 2.5, 2.5);
        let (v, w) = (DVec3::new(0.01, -0.02, 0.005), DVec3::new(0.0, 0.003, -0.001));
        // SAFETY: single-threaded test.
        let pc = unsafe { blk.particle_cells_mut() };
        pc.owner = vec![0; l.slots()];
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
        unsafe {
            reconstruct(
                &d,
                &blk,
                &mut pc,
                0,
                &params,
                Rebuild {
                    conserve_momentum: true,
                    refill: Refill::Equilibrium,
                },
            )
        };
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
        // The cells as rebuilt with momentum conservation, for the comparison below.
        let rebuilt: Vec<[f64; Q]> = [lonely, open].iter().map(|&c| blk.field(0).cell(c)).collect();
        // Grad's refill adds a non-equilibrium part without mass or momentum: in a shear flow
        // u_x = 1e-3 y the rebuilt cells keep their moments (to 1e-15) and the open one gets a stress.
        blk.init(|g| post_collision_equilibrium(0.01, [1e-3 * g[1] as f64, 0.0, 0.0], &params));
        let want_at = |cell: usize| v + w.cross(cell_offset(&d, blk.origin, l.coords(cell), centre));
        let mut grad_pc = ParticleCells {
            owner: pc.owner.clone(),
            turned: pc.turned.clone(),
            bodies: pc.bodies.clone(),
            ..Default::default()
        };
        unsafe {
            reconstruct(
                &d,
                &blk,
                &mut grad_pc,
                0,
                &params,
                Rebuild {
                    conserve_momentum: false,
                    refill: Refill::Grad,
                },
            )
        };
        for (cell, drho_want) in [(lonely, 0.0), (open, 0.01)] {
            let (drho, u) = moments(&blk.field(0).cell(cell), [0.0; 3]);
            let want = v + w.cross(cell_offset(&d, blk.origin, l.coords(cell), centre));
            assert!((drho - drho_want).abs() < 1e-15 && (DVec3::from(u) - want).length() < 1e-15);
        }
        let plain = post_collision_equilibrium(0.01, want_at(open).to_array(), &params);
        let f_open = blk.field(0).cell(open);
        assert!(
            f_open.iter().zip(&plain).any(|(a, b)| (a - b).abs() > 1e-7),
            "no stress added"
        );
        // Without momentum conservation the same cells are rebuilt, bit for bit, and no body is charged.
        blk.init(|_| post_collision_equilibrium(0.01, [0.0; 3], &params));
        unsafe {
            reconstruct(
                &d,
                &blk,
                &mut pc,
                0,
                &params,
                Rebuild {
                    conserve_momentum: false,
                    refill: Refill::Equilibrium,
                },
            )
        };
        assert!(pc.exchanged.is_empty());
        for (k, &c) in [lonely, open].iter().enumerate() {
            let f: [f64; Q] = blk.field(0).cell(c);
            assert!(f.iter().zip(&rebuilt[k]).all(|(a, b)| a.to_bits() == b.to_bits()));
        }
    }

    /// Extrapolation refill: along the lattice direction closest to the normal (here +x), three fluid
    /// cells reproduce a field quadratic in x exactly (3f₁ − 3f₂ + f₃ is exact for quadratics), two give
    /// the linear 2f₁ − f₂, and one falls back to the Grad refill.
    #[test]
    fn extrapolation_is_exact_for_quadratic_fields_and_falls_back_with_few_cells() {
        let (d, params) = (periodic_cube(12), trt());
        // Populations quadratic in x and linear in y (global cell coordinates).
        let field = |g: [usize; 3]| -> [f64; Q] {
            let mut f = post_collision_equilibrium(0.01, [0.002, 0.0, 0.0], &params);
            for (q, v) in f.iter_mut().enumerate() {
                let (x, y) = (g[0] as f64, g[1] as f64);
                *v += (q + 1) as f64 * (1e-5 * (x - 1.5) * (x - 1.5) + 1e-6 * y);
            }
            f
        };
        let rebuilt = |refill: Refill, solid_at: Option<usize>| {
            let mut blk = Block::<f64>::new(&d, &Geometry::default(), 0, blockflow_kernels::Pattern::Pull);
            blk.init(field);
            let l = blk.layout;
            // SAFETY: single-threaded test.
            let pc = unsafe { blk.particle_cells_mut() };
            pc.owner = vec![0; l.slots()];
            if let Some(x) = solid_at {
                pc.owner[l.idx(x, 5, 5)] = 8;
            }
            let cell = l.idx(3, 5, 5); // centre (2.5, 4.5, 4.5); the sphere left towards −x
            pc.turned = vec![(cell, 7)];
            pc.bodies = vec![MapBody {
                id: 7,
                position: DVec3::new(0.5, 4.5, 4.5),
                velocity: DVec3::ZERO,
                angular_velocity: DVec3::ZERO,
                radius: 1.5,
            }];
            let mut pc = std::mem::take(pc);
            let how = Rebuild {
                conserve_momentum: false,
                refill,
            };
            unsafe { reconstruct(&d, &blk, &mut pc, 0, &params, how) };
            let near: Vec<[f64; Q]> = (4..=5).map(|x| blk.field(0).cell(l.idx(x, 5, 5))).collect();
            (blk.field(0).cell(cell), near)
        };
        let exact = field([2, 4, 4]);
        let (three, _) = rebuilt(Refill::Extrapolation, None);
        for q in 0..Q {
            assert!(
                (three[q] - exact[q]).abs() < 1e-15,
                "q {q}: {} against {}",
                three[q],
                exact[q]
            );
        }
        let (two, near) = rebuilt(Refill::Extrapolation, Some(6));
        for q in 0..Q {
            assert_eq!(two[q].to_bits(), (2.0 * near[0][q] - near[1][q]).to_bits());
        }
        assert!(
            (0..Q).any(|q| (two[q] - exact[q]).abs() > 1e-6),
            "linear is not exact for a quadratic"
        );
        let (one, _) = rebuilt(Refill::Extrapolation, Some(5));
        let (grad, _) = rebuilt(Refill::Grad, Some(5));
        assert!(one.iter().zip(&grad).all(|(a, b)| a.to_bits() == b.to_bits()));
    }
}
