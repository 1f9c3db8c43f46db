//! The Table 1 quantities of a block, as this engine counts them.

use crate::physics::simulation::Simulation;
use blockflow_kernels::Real;

/// Table 1 quantities of one block in one step (all f64, so that they enter the regressions directly).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Quantities {
    /// C: total number of cells on the block (eqs. 10–13).
    pub c: f64,
    /// F: number of cells flagged as fluid (eqs. 10, 12, 13).
    pub f: f64,
    /// NB: number of cells flagged as near boundary (Table 1's B; eq. 11).
    pub nb: f64,
    /// P_L: number of local particles (eqs. 12–14).
    pub pl: f64,
    /// P_S: number of shadow particles (eqs. 12–14).
    pub ps: f64,
    /// K: number of contacts between rigid bodies (eq. 14).
    pub k: f64,
    /// S: number of sub-cycles of the rigid-body simulation (the factor of eq. 14).
    pub s: f64,
}

impl Quantities {
    /// The quantities of block `b` of `sim` after the last step: C, F, NB from the block and its particle
    /// overlay, P_L and P_S from the block's last rigid-body sub-step, K the contacts it owned averaged
    /// over the step's sub-steps, S the sub-steps (0 for a block without rigid-body tasks). Call between
    /// graph runs.
    pub fn of<T: Real>(sim: &Simulation<T>, b: usize) -> Quantities {
        let blk = &sim.blocks[b];
        let (f, nb) = match blk.particle_cells() {
            Some(pc) => (pc.fluid_cells, pc.near_boundary_cells),
            None => (blk.fluid_cells, blk.near_boundary_cells),
        };
        let mut q = Quantities {
            c: blk.layout.interior_cells() as f64,
            f: f as f64,
            nb: nb as f64,
            ..Default::default()
        };
        if let Some(p) = sim.particles.as_ref().filter(|p| p.active[b]) {
            // SAFETY: called between graph runs.
            let w = unsafe { p.blocks[b].work() };
            let s = p.subcycles as f64;
            q.pl = w.locals as f64;
            q.ps = (w.bodies.len() - w.locals) as f64;
            q.k = w.contacts_step as f64 / s;
            q.s = s;
        }
        q
    }
}
