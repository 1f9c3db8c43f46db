//! Block weights (`balance.weights`): fluid cells, the estimate of eq. (15), the measured m_tot of the
//! last interval or the corrected estimate. One definition each, used for the initial assignment, the
//! balancing step and the study's counterfactuals alike.

use crate::config::Weights;
use crate::estimator::{Coefficients, Quantities};
use crate::physics::simulation::Simulation;
use blockflow_kernels::Real;

/// `cells` weights: each block's fluid cells now (static fluid cells not covered by a particle: what the
/// fluid kernel updates), or its cell count in a scene without fluid.
pub fn cells<T: Real>(sim: &Simulation<T>) -> Vec<f64> {
    let dry = sim.fluid_cells() == 0;
    sim.blocks
        .iter()
        .map(|b| if dry { b.layout.interior_cells() } else { b.current_fluid_cells() } as f64)
        .collect()
}

/// `estimator` weights: each block's workload estimate of eq. (15) from its Table 1 quantities.
pub fn estimate<T: Real>(sim: &Simulation<T>, c: &Coefficients) -> Vec<f64> {
    (0..sim.blocks.len())
        .map(|b| c.total(&Quantities::of(sim, b)))
        .collect()
}

/// The weights of the initial assignment, before anything was measured: `measured` starts from `cells`,
/// `corrected` from the plain estimate (`coefficients` must be given for `estimator` and `corrected`).
pub fn initial<T: Real>(kind: Weights, sim: &Simulation<T>, coefficients: Option<&Coefficients>) -> Vec<f64> {
    match kind {
        Weights::Cells | Weights::Measured => cells(sim),
        Weights::Uniform => vec![1.0; sim.blocks.len()],
        Weights::Estimator | Weights::Corrected => {
            estimate(sim, coefficients.expect("estimator weights have coefficients"))
        }
    }
}
