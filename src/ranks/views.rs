//! Views of the whole state of a run whose blocks are spread over ranks: what the outputs and the
//! scenes' observables read. Each is built from the ranks' per-block parts in block-id order (see the
//! module docs of [`super`]), so it has the same bits as the single-rank view; in a world of one rank
//! it is read from memory directly. Every rank must call a view at the same point.

use super::World;
use crate::error::Result;
use crate::physics::block::Block;
use crate::physics::geometry::flags;
use crate::physics::particle_cells::BodyForce;
use crate::physics::simulation::{Diagnostics, Simulation};
use crate::serialise::halo::{decode_bodies, decode_forces, encode_bodies, encode_forces};
use crate::util::bytes::Reader;
use blockflow_kernels::rigid::Body;
use blockflow_kernels::Real;

/// The held blocks of `sim`, each as (id, `f(block)`).
fn per_block<T: Real>(sim: &Simulation<T>, mut f: impl FnMut(&Block<T>) -> Vec<u8>) -> Vec<(usize, Vec<u8>)> {
    sim.blocks
        .iter()
        .filter(|b| b.is_held())
        .map(|b| (b.id, f(b)))
        .collect()
}

/// Every body of the run, sorted by id, on every rank.
pub fn bodies<T: Real>(world: &World, sim: &Simulation<T>) -> Result<Vec<Body>> {
    let Some(p) = sim.particles.as_ref() else {
        return Ok(Vec::new());
    };
    let mine = p.bodies(sim.step);
    if world.is_single() {
        return Ok(mine);
    }
    let mut bytes = Vec::new();
    encode_bodies(&mine, &mut bytes);
    let mut all = Vec::new();
    for r in world.allgather(&bytes)? {
        all.extend(decode_bodies(&mut Reader::new(&r, "bodies")).expect("bodies from a rank of this run"));
    }
    all.sort_by_key(|b| b.id);
    Ok(all)
}

/// The fluid's diagnostics ([`Simulation::diagnostics`]) of the whole domain, on every rank; a single
/// rank sums its blocks on `threads` threads ([`Simulation::diagnostics_on`], the same bits).
pub fn diagnostics<T: Real>(world: &World, sim: &Simulation<T>, threads: usize) -> Result<Diagnostics> {
    if world.is_single() {
        return Ok(sim.diagnostics_on(threads));
    }
    let mine = per_block(sim, |b| {
        let d = sim.block_diagnostics(b.id);
        let mut v = Vec::with_capacity(40);
        for x in [d.mass, d.mass_deviation, d.kinetic_energy, d.max_velocity] {
            v.extend_from_slice(&x.to_bits().to_le_bytes());
        }
        v.extend_from_slice(&(d.cells as u64).to_le_bytes());
        v
    });
    let all = world.all_blocks(sim.blocks.len(), mine)?;
    let word = |b: &[u8], k: usize| u64::from_le_bytes(b[8 * k..8 * k + 8].try_into().expect("8 bytes"));
    Ok(Diagnostics::combine(all.iter().map(|b| Diagnostics {
        mass: f64::from_bits(word(b, 0)),
        mass_deviation: f64::from_bits(word(b, 1)),
        kinetic_energy: f64::from_bits(word(b, 2)),
        max_velocity: f64::from_bits(word(b, 3)),
        cells: word(b, 4) as usize,
    })))
}

/// The checksums of the fluid and of the bodies (see [`Simulation::checksum`]) of the whole state, on
/// every rank.
pub fn checksums<T: Real>(world: &World, sim: &Simulation<T>) -> Result<(u64, Option<u64>)> {
    let p = sim.particles.as_ref().map(|p| p.checksum(sim.step));
    let mut v = [sim.checksum(), p.unwrap_or(0)];
    if !world.is_single() {
        world.sum(&mut v)?;
    }
    Ok((v[0], p.map(|_| v[1])))
}

/// The number of contacts and the largest penetration of the last rigid-body sub-step over all blocks,
/// on every rank.
pub fn last_contacts<T: Real>(world: &World, sim: &Simulation<T>) -> Result<(usize, f64)> {
    let Some(p) = sim.particles.as_ref() else {
        return Ok((0, 0.0));
    };
    let (n, pen) = p.last_contacts();
    if world.is_single() {
        return Ok((n, pen));
    }
    let mut count = [n as u64];
    world.sum(&mut count)?;
    let mut max = [pen];
    world.max_f64(&mut max)?;
    Ok((count[0] as usize, max[0]))
}

/// The hydrodynamic force and torque of every body from the last boundary pass, summed over blocks in
/// block-id order, sorted by body id, on every rank.
pub fn hydro_forces<T: Real>(world: &World, sim: &Simulation<T>) -> Result<Vec<BodyForce>> {
    if world.is_single() {
        return Ok(crate::physics::coupling::tasks::total_forces(&sim.blocks));
    }
    let mine = per_block(sim, |b| {
        let mut v = Vec::new();
        encode_forces(b.particle_cells().map_or(&[][..], |pc| &pc.forces), &mut v);
        v
    });
    let all = world.all_blocks(sim.blocks.len(), mine)?;
    let lists: Vec<Vec<BodyForce>> = all
        .iter()
        .map(|b| decode_forces(&mut Reader::new(b, "forces")).expect("forces from a rank of this run"))
        .collect();
    Ok(crate::physics::coupling::tasks::sum_forces(
        lists.iter().map(|l| l.as_slice()),
    ))
}

/// One block's interior cells as the outputs see them: x fastest, then y, then z.
#[derive(Clone, Debug, PartialEq)]
pub struct BlockCells {
    /// Block id.
    pub id: usize,
    /// Global coordinates of the first interior cell.
    pub origin: [usize; 3],
    /// Interior cells per axis.
    pub size: [usize; 3],
    /// Cell flags ([`flags`]), [`flags::PARTICLE`] for a cell covered by a body.
    pub flags: Vec<u8>,
    /// δρ of the fluid cells (0 elsewhere).
    pub delta_rho: Vec<f64>,
    /// Velocity of the fluid cells (0 elsewhere).
    pub velocity: Vec<[f64; 3]>,
}

impl BlockCells {
    /// The cells of block `b` of `sim` (held by this process) in the state after `sim.step` steps.
    pub fn of<T: Real>(sim: &Simulation<T>, b: &Block<T>) -> Self {
        let [nx, ny, nz] = b.layout.size;
        let n = nx * ny * nz;
        let mut c = BlockCells {
            id: b.id,
            origin: b.origin,
            size: b.layout.size,
            flags: Vec::with_capacity(n),
            delta_rho: Vec::with_capacity(n),
            velocity: Vec::with_capacity(n),
        };
        let (p, force) = (sim.parity(), sim.params.force);
        let covered = b.particle_cells().map(|pc| &pc.owner);
        for z in 1..=nz {
            for y in 1..=ny {
                for x in 1..=nx {
                    let i = b.layout.idx(x, y, z);
                    let mut f = b.flags[i];
                    if covered.is_some_and(|o| o.get(i).is_some_and(|&w| w != 0)) {
                        f = flags::PARTICLE;
                    }
                    let (r, u) = if f & flags::FLUID != 0 {
                        crate::physics::fluid::cell_moments(b, p, i, force)
                    } else {
                        (0.0, [0.0; 3])
                    };
                    c.flags.push(f);
                    c.delta_rho.push(r);
                    c.velocity.push(u);
                }
            }
        }
        c
    }

    /// Calls `visit(global cell, δρ, u)` for every fluid cell of the block, x fastest (the order of
    /// [`Simulation::for_each_fluid`]).
    pub fn visit(&self, visit: &mut dyn FnMut([usize; 3], f64, [f64; 3])) {
        let [nx, ny, _] = self.size;
        for (k, &f) in self.flags.iter().enumerate() {
            if f & flags::FLUID != 0 {
                let (x, y, z) = (k % nx, (k / nx) % ny, k / (nx * ny));
                let g = [self.origin[0] + x, self.origin[1] + y, self.origin[2] + z];
                visit(g, self.delta_rho[k], self.velocity[k]);
            }
        }
    }

    fn encode(&self) -> Vec<u8> {
        let n = self.flags.len();
        let mut v = Vec::with_capacity(48 + 33 * n);
        for x in self.origin.iter().chain(&self.size) {
            v.extend_from_slice(&(*x as u64).to_le_bytes());
        }
        v.extend_from_slice(&self.flags);
        for (r, u) in self.delta_rho.iter().zip(&self.velocity) {
            for x in [*r, u[0], u[1], u[2]] {
                v.extend_from_slice(&x.to_bits().to_le_bytes());
            }
        }
        v
    }

    fn decode(id: usize, b: &[u8]) -> Self {
        let word = |k: usize| u64::from_le_bytes(b[8 * k..8 * k + 8].try_into().expect("8 bytes"));
        let origin = [word(0) as usize, word(1) as usize, word(2) as usize];
        let size = [word(3) as usize, word(4) as usize, word(5) as usize];
        let n = size.iter().product::<usize>();
        let flags = b[48..48 + n].to_vec();
        let f = |k: usize| {
            let at = 48 + n + 8 * k;
            f64::from_bits(u64::from_le_bytes(b[at..at + 8].try_into().expect("8 bytes")))
        };
        BlockCells {
            id,
            origin,
            size,
            flags,
            delta_rho: (0..n).map(|k| f(4 * k)).collect(),
            velocity: (0..n).map(|k| [f(4 * k + 1), f(4 * k + 2), f(4 * k + 3)]).collect(),
        }
    }
}

/// Every block's cells, in block-id order, on rank 0 (`None` on the others).
pub fn cells<T: Real>(world: &World, sim: &Simulation<T>) -> Result<Option<Vec<BlockCells>>> {
    if world.is_single() {
        return Ok(Some(sim.blocks.iter().map(|b| BlockCells::of(sim, b)).collect()));
    }
    let mine = per_block(sim, |b| BlockCells::of(sim, b).encode());
    Ok(world.gather_blocks(sim.blocks.len(), mine)?.map(|all| {
        all.iter()
            .enumerate()
            .map(|(id, b)| BlockCells::decode(id, b))
            .collect()
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn block_cells_round_trip_and_visit_fluid_cells_in_order() {
        let c = BlockCells {
            id: 3,
            origin: [4, 0, 8],
            size: [2, 1, 2],
            flags: vec![
                flags::FLUID,
                flags::PARTICLE,
                flags::NOSLIP,
                flags::FLUID | flags::NEAR_BOUNDARY,
            ],
            delta_rho: vec![1e-3, 0.0, 0.0, -2e-17],
            velocity: vec![[0.1, -0.0, 5e-324], [0.0; 3], [0.0; 3], [1.0, 2.0, 3.0]],
        };
        assert_eq!(BlockCells::decode(3, &c.encode()), c);
        let mut seen = Vec::new();
        c.visit(&mut |g, r, u| seen.push((g, r, u)));
        assert_eq!(
            seen,
            vec![
                ([4, 0, 8], 1e-3, [0.1, -0.0, 5e-324]),
                ([5, 0, 9], -2e-17, [1.0, 2.0, 3.0])
            ]
        );
    }
}
