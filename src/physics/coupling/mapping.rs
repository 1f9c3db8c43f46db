//! Mapping (Algorithm 5): the spheres near a block into its overlay, cell owners, fluid runs, links with
//! δ_q from the ray–sphere intersection, and the cells that changed state since the previous mapping.

use super::{cell_offset, min_image};
use crate::config::SurfaceBoundary;
use crate::physics::block::Block;
use crate::physics::domain::DomainSpec;
use crate::physics::geometry::flags;
use crate::physics::particle_cells::{MapBody, ParticleCells, ParticleLink};
use blockflow_kernels::coupling::crossing_fraction;
use blockflow_kernels::d3q19::{C, Q};
use blockflow_kernels::sweep::Segment;
use blockflow_kernels::Real;
use glam::DVec3;

/// Maps `bodies` (sorted by id, canonical centres) into block `b`'s overlay (Algorithm 5): owners of
/// every static fluid cell a sphere covers (the higher id wins where two overlap), fluid segments, links
/// with δ_q and the cells that turned from solid to fluid since the previous mapping.
pub fn map<T: Real>(d: &DomainSpec, b: &Block<T>, pc: &mut ParticleCells, bodies: Vec<MapBody>, mode: SurfaceBoundary) {
    map_with(d, b, pc, bodies, mode, true)
}

/// [`map`] with its fast path for a block with no body near (before or now) switched on or off: with
/// `fast_path = false` (`run.no_skip`) such a block is scanned cell by cell like any other, which gives
/// the same overlay.
pub fn map_with<T: Real>(
    d: &DomainSpec,
    b: &Block<T>,
    pc: &mut ParticleCells,
    bodies: Vec<MapBody>,
    mode: SurfaceBoundary,
    fast_path: bool,
) {
    let l = b.layout;
    let [fx, fy, fz] = l.full();
    // Cells of the block with its ghost layer (element indices run below the field's stride).
    let n = l.sxy * fz;
    if fast_path && bodies.is_empty() && !pc.owned && pc.owner.len() == n {
        // No body near before or now: the static cells are the state; nothing to rebuild or reconstruct.
        if pc.segments.len() != b.segments.len() || pc.fluid_cells != b.fluid_cells {
            pc.segments = b.segments.clone();
        }
        pc.fluid_cells = b.fluid_cells;
        pc.near_boundary_cells = b.near_boundary_cells;
        pc.near_particle_cells = 0;
        pc.links.clear();
        pc.turned.clear();
        pc.covered.clear();
        pc.bodies.clear();
        return;
    }
    let mut old = std::mem::take(&mut pc.owner);
    let mut fresh = std::mem::take(&mut pc.owner_spare);
    fresh.clear();
    fresh.resize(n, 0);
    pc.owner = fresh;
    let cells = d.cells();
    for body in &bodies {
        // Every periodic image whose bounding box meets the block with its ghost layer.
        let mut ranges = [[(0i64, -1i64); 3]; 3];
        for a in 0..3 {
            let shifts: &[f64] = if d.periodic[a] { &[-1.0, 0.0, 1.0] } else { &[0.0] };
            for (k, s) in shifts.iter().enumerate() {
                let x = body.position[a] + s * cells[a] as f64;
                let lo = ((x - body.radius - 0.5).floor() as i64 - b.origin[a] as i64 + 1).max(0);
                let hi = ((x + body.radius - 0.5).ceil() as i64 - b.origin[a] as i64 + 1).min(l.full()[a] as i64 - 1);
                ranges[a][k] = (lo, hi);
            }
        }
        let r2 = body.radius * body.radius;
        for rz in ranges[2].iter().filter(|r| r.0 <= r.1) {
            for ry in ranges[1].iter().filter(|r| r.0 <= r.1) {
                for rx in ranges[0].iter().filter(|r| r.0 <= r.1) {
                    // The offset is separable per axis: compute each axis once (same bits as cell_offset).
                    let axis = |a: usize, k: i64| {
                        let mut xyz = [1usize; 3];
                        xyz[a] = k as usize;
                        cell_offset(d, b.origin, xyz, body.position)[a]
                    };
                    let ox: Vec<f64> = (rx.0..=rx.1).map(|k| axis(0, k)).collect();
                    let oy: Vec<f64> = (ry.0..=ry.1).map(|k| axis(1, k)).collect();
                    for z in rz.0..=rz.1 {
                        let oz = axis(2, z);
                        for (jy, y) in (ry.0..=ry.1).enumerate() {
                            let yz = oy[jy] * oy[jy] + oz * oz;
                            if yz > r2 {
                                continue;
                            }
                            let row = l.idx(0, y as usize, z as usize);
                            for (jx, x) in (rx.0..=rx.1).enumerate() {
                                let i = row + x as usize;
                                if b.flags[i] & flags::FLUID != 0 && ox[jx] * ox[jx] + yz <= r2 {
                                    pc.owner[i] = body.id + 1;
                                }
                            }
                        }
                    }
                }
            }
        }
    }
    // Segments and turned cells, scanning the interior once.
    pc.segments.clear();
    pc.turned.clear();
    pc.covered.clear();
    pc.links.clear();
    pc.fluid_cells = 0;
    pc.near_particle_cells = 0;
    pc.near_boundary_cells = 0;
    for z in 1..fz - 1 {
        for y in 1..fy - 1 {
            let mut run: Option<Segment> = None;
            for x in 1..fx - 1 {
                let i = l.idx(x, y, z);
                let fluid = b.flags[i] & flags::FLUID != 0 && pc.owner[i] == 0;
                if !fluid {
                    if let Some(s) = run.take() {
                        pc.segments.push(s);
                    }
                    if pc.owner[i] != 0 && old.len() == n && old[i] == 0 {
                        pc.covered.push((i, pc.owner[i] - 1));
                    }
                    continue;
                }
                pc.fluid_cells += 1;
                if b.flags[i] & flags::NEAR_BOUNDARY != 0 {
                    pc.near_boundary_cells += 1;
                }
                match run.as_mut() {
                    Some(s) => s.len += 1,
                    None => run = Some(Segment { start: i, len: 1 }),
                }
                if old.len() == n && old[i] != 0 {
                    pc.turned.push((i, old[i] - 1));
                }
            }
            if let Some(s) = run.take() {
                pc.segments.push(s);
            }
        }
    }
    // Links: mark the cells next to a particle cell (few), then visit the marked fluid cells in cell order.
    let is_fluid = |i: usize| b.flags[i] & flags::FLUID != 0 && pc.owner[i] == 0;
    let mut mark = std::mem::take(&mut pc.mark);
    mark.clear();
    mark.resize(n, false);
    let mut any = false;
    for (t, &o) in pc.owner.iter().enumerate() {
        if o != 0 {
            any = true;
            for c in C.iter().skip(1) {
                let i = t as isize - l.offset(*c);
                if i >= 0 && (i as usize) < n {
                    mark[i as usize] = true;
                }
            }
        }
    }
    let mut found: Vec<(usize, usize, usize, [usize; 3])> = Vec::new();
    let offs: [isize; Q] = std::array::from_fn(|q| l.offset(C[q]));
    if any {
        for z in 1..fz - 1 {
            for y in 1..fy - 1 {
                let row = l.idx(0, y, z);
                for x in 1..fx - 1 {
                    let i = row + x;
                    if !mark[i] || !is_fluid(i) {
                        continue;
                    }
                    for (q, off) in offs.iter().enumerate().skip(1) {
                        let t = (i as isize + off) as usize;
                        if pc.owner[t] != 0 {
                            found.push((i, q, t, [x, y, z]));
                        }
                    }
                }
            }
        }
    }
    pc.mark = mark;
    pc.owned = any;
    let slot = |id: u64| bodies.binary_search_by_key(&id, |m| m.id).ok();
    let cells_f = [cells[0] as f64, cells[1] as f64, cells[2] as f64];
    let mut last_cell = usize::MAX;
    for (i, q, t, xyz) in found {
        let Some(k) = slot(pc.owner[t] - 1) else { continue };
        let body = &bodies[k];
        // Offset of the fluid cell centre from the body centre, nearest image. Only this block uses a
        // link, so plain local arithmetic suffices (no division, unlike `cell_offset`).
        let mut rel = DVec3::ZERO;
        for a in 0..3 {
            let x = (b.origin[a] + xyz[a]) as f64 - 0.5;
            rel[a] = min_image(x - body.position[a], cells_f[a], d.periodic[a]);
        }
        let second = (i as isize - l.offset(C[q])) as usize;
        let (delta, second) = if mode == SurfaceBoundary::Cli && is_fluid(second) {
            // x_f is outside and x_f + c_q inside the sphere (the mapping says so): the ray enters it.
            (crossing_fraction(rel, q, body.radius), Some(second))
        } else {
            (0.5, None)
        };
        pc.links.push(ParticleLink {
            fluid: i,
            q: q as u8,
            body: k as u32,
            delta,
            second,
            rel,
        });
        if i != last_cell {
            pc.near_particle_cells += 1;
            if b.flags[i] & flags::NEAR_BOUNDARY == 0 {
                pc.near_boundary_cells += 1;
            }
            last_cell = i;
        }
    }
    pc.bodies = bodies;
    old.clear();
    pc.owner_spare = old;
}
