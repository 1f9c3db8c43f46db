//! The plain serial time step over all blocks: the reference the task-graph pipeline is tested and
//! benchmarked against (bitwise), for fluid-only scenes.

use super::fluid;
use super::simulation::Simulation;
use crate::error::Instability;
use blockflow_kernels::sweep::SweepStats;
use blockflow_kernels::Real;

/// One time step of every block in block order: exchange (every ghost region copied from its sender),
/// boundary (blocks with wall links), stream + collide into the other field (eqs. 2–5). Stops with the
/// location of the first unstable cell (lowest block id) if the detector fires.
pub fn step<T: Real>(sim: &mut Simulation<T>) -> Result<(), Instability> {
    let p = sim.parity();
    for b in &sim.blocks {
        for r in &b.recv {
            fluid::copy_ghost(&sim.blocks[r.from], b, p, r);
        }
    }
    let mut stats = Vec::with_capacity(sim.blocks.len());
    for b in &sim.blocks {
        if b.fluid_cells == 0 {
            stats.push(SweepStats::default());
            continue;
        }
        if !b.links.is_empty() {
            fluid::boundary(b, p);
        }
        // SAFETY: serial loop: nothing else touches the block.
        stats.push(unsafe { fluid::stream_collide(b, p, &sim.params, sim.kernel) });
    }
    sim.finish_step(&stats)
}
