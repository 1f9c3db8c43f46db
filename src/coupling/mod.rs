//! Fluid–particle coupling on a block (section 2.3 of Rettinger & Rüde 2019): mapping of the spheres
//! into cells (Algorithm 5), the CLI / simple bounce-back boundary of eq. (6) at their surfaces with the
//! momentum exchange of eqs. (7)–(9), and the reconstruction of cells that turn from solid to fluid
//! (Algorithm 6). The per-link numerics are the kernels' ([`blockflow_kernels::coupling`]); this module
//! finds the cells and links of a block and sums the forces per body.
//!
//! Geometry is evaluated in a way every block agrees on bit for bit: a cell is addressed by its wrapped
//! global index, a body by its canonical (wrapped) centre, and their offset is taken as the minimum image
//! on periodic axes. So a cell in one block's ghost layer is solid exactly when the same cell is solid in
//! the block that owns it.
//!
//! Static geometry (walls, planes) stays in the block's flags, mapped once; particles live in an overlay
//! ([`ParticleCells`]) that is rebuilt by the `map` task of every step. Fixed bodies alone are mapped
//! once at set-up.

pub mod tasks;

use crate::block::Block;
use crate::domain::DomainSpec;
use crate::geometry::flags;
use blockflow_kernels::coupling::{
    cli_link, crossing_fraction, link_torque, momentum_exchange, sbb_link, surface_velocity, RHO0,
};
use blockflow_kernels::d3q19::{C, OPP, Q};
use blockflow_kernels::sweep::Segment;
use blockflow_kernels::trt::{moments, post_collision_equilibrium};
use blockflow_kernels::{Real, TrtParams};
use glam::DVec3;

/// Boundary condition at particle surfaces (`particles.boundary`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum SurfaceBoundary {
    /// Central linear interpolation with δ_q from the ray–sphere intersection (eq. 6), simple bounce-back
    /// where the second fluid cell is missing.
    #[default]
    Cli,
    /// Simple bounce-back (δ_q = 1/2 everywhere).
    Sbb,
}

/// What the mapping needs of a body.
#[derive(Clone, Copy, Debug)]
pub struct MapBody {
    /// Body id.
    pub id: u64,
    /// Canonical centre X.
    pub position: DVec3,
    /// Translational velocity V.
    pub velocity: DVec3,
    /// Angular velocity W.
    pub angular_velocity: DVec3,
    /// Radius.
    pub radius: f64,
}

/// A fluid cell's link into a particle cell.
#[derive(Clone, Copy, Debug)]
pub struct ParticleLink {
    /// Element index of the fluid cell x_f.
    pub fluid: usize,
    /// Outgoing direction q (c_q points into the body).
    pub q: u8,
    /// Index of the body in [`ParticleCells::bodies`].
    pub body: u32,
    /// δ_q in (0, 1] (1/2 for simple bounce-back).
    pub delta: f64,
    /// Element index of the second fluid cell x_f − c_q for CLI; `None`: simple bounce-back.
    pub second: Option<usize>,
    /// Offset x_f − X of the fluid cell centre from the body centre (minimum image).
    pub rel: DVec3,
}

/// Hydrodynamic force and torque the block's links put on one body.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BodyForce {
    /// Body id.
    pub id: u64,
    /// Force, eq. (8) restricted to this block's links.
    pub force: DVec3,
    /// Torque, eq. (9) restricted to this block's links.
    pub torque: DVec3,
}

/// The particle overlay of one block.
#[derive(Clone, Debug, Default)]
pub struct ParticleCells {
    /// Id + 1 of the body covering each cell (ghost layer included); 0: none.
    pub owner: Vec<u64>,
    /// The previous mapping's buffer, reused.
    owner_spare: Vec<u64>,
    /// Scratch: cells next to a particle cell.
    mark: Vec<bool>,
    /// Whether any cell of `owner` is covered.
    owned: bool,
    /// Runs of interior cells that are fluid now (static fluid and not covered by a body).
    pub segments: Vec<Segment>,
    /// Interior fluid cells now.
    pub fluid_cells: usize,
    /// Interior fluid cells with at least one particle link.
    pub near_particle_cells: usize,
    /// Interior fluid cells next to a wall or a particle (NB of Table 1).
    pub near_boundary_cells: usize,
    /// The bodies mapped in this step (locals and shadows), sorted by id.
    pub bodies: Vec<MapBody>,
    /// Links from fluid cells into particle cells, in cell order.
    pub links: Vec<ParticleLink>,
    /// Interior cells that turned from solid to fluid in this step, with the id of the body that left.
    pub turned: Vec<(usize, u64)>,
    /// Interior cells that a body covered in this step (fluid to solid), with its id.
    pub covered: Vec<(usize, u64)>,
    /// Momentum the covered and reconstructed cells exchanged with each body in this step (the fluid
    /// momentum a body swallows, minus what a rebuilt cell receives), sorted by id; added to the force.
    pub exchanged: Vec<BodyForce>,
    /// Forces of the last boundary pass, sorted by id.
    pub forces: Vec<BodyForce>,
}

impl ParticleCells {
    /// Whether any cell of `owner` was covered by the last mapping (the mapping's fast path for blocks
    /// with no body near depends on it).
    pub fn owned(&self) -> bool {
        self.owned
    }

    /// Sets [`ParticleCells::owned`] (for rebuilding an overlay from its serialised form; it must agree
    /// with `owner`).
    pub fn set_owned(&mut self, owned: bool) {
        self.owned = owned;
    }
}

/// Minimum-image offset along one axis.
#[inline]
fn min_image(d: f64, len: f64, periodic: bool) -> f64 {
    if periodic {
        if d > 0.5 * len {
            d - len
        } else if d < -0.5 * len {
            d + len
        } else {
            d
        }
    } else {
        d
    }
}

/// Offset of the centre of the cell at full-layout coordinates (x, y, z) of block `b` from `centre`,
/// computed from the wrapped global cell index (the same bits in every block that holds the cell).
#[inline]
pub fn cell_offset(d: &DomainSpec, origin: [usize; 3], xyz: [usize; 3], centre: DVec3) -> DVec3 {
    let n = d.cells();
    let mut out = DVec3::ZERO;
    for a in 0..3 {
        let g = origin[a] as i64 + xyz[a] as i64 - 1;
        let len = n[a] as i64;
        // Ghost cells lie at most one cell outside the domain: one period wraps them.
        let gw = if !d.periodic[a] || (0..len).contains(&g) {
            g
        } else if g < 0 {
            g + len
        } else {
            g - len
        };
        out[a] = min_image(gw as f64 + 0.5 - centre[a], n[a] as f64, d.periodic[a]);
    }
    out
}

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

/// Reconstruction (Algorithm 6) of the cells that turned fluid: the (forced) equilibrium with the
/// surface velocity of the body that left, V + W × (x − X), and the mean δρ of the cell's interior fluid
/// neighbours that were fluid before; with no such neighbour, ρ = ρ0 (δρ = 0), the reference density of
/// the incompressible model.
///
/// # Safety
/// No other task may access field `p` of this block concurrently.
pub unsafe fn reconstruct<T: Real>(d: &DomainSpec, b: &Block<T>, pc: &mut ParticleCells, p: usize, params: &TrtParams) {
    pc.exchanged.clear();
    if pc.turned.is_empty() && pc.covered.is_empty() {
        return;
    }
    let l = b.layout;
    let f = b.field_mut(p);
    let mut add = |id: u64, x: usize, j: DVec3| {
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
    for &(i, id) in &pc.covered {
        let cell: [T; Q] = f.cell(i);
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
                let cell: [T; Q] = f.cell(t);
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
        f.set_cell(i, &cell);
        // ... and a rebuilt cell's momentum comes from the body that left it.
        let (_, u_new) = moments(&cell, params.force);
        add(id, i, -RHO0 * DVec3::from(u_new));
    }
}

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Geometry;

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
        let mut blk = Block::<f64>::new(&d, &Geometry::default(), 0);
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
        unsafe { reconstruct(&d, &blk, &mut pc, 0, &params) };
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
    }
}
