//! Block weights (`balance.weights`): fluid cells, the estimate of eq. (15), the measured m_tot of the
//! last interval or the corrected estimate. One definition each, used for the initial assignment, the
//! balancing step and the study's counterfactuals alike.

use crate::config::Weights;
use crate::estimator::{Coefficients, Quantities};
use crate::physics::simulation::Simulation;
use blockflow_kernels::Real;

/// What block weights are computed from: every block's Table 1 quantities now (as
/// [`Quantities::for_weights`] counts them: the mapping's jumpy counters averaged over recent steps; in
/// block-id order), and whether the scene has no fluid at all.
#[derive(Clone, Debug)]
pub struct BlockState {
    /// Quantities per block.
    pub quantities: Vec<Quantities>,
    /// No block has a fluid cell (a dry granular scene).
    pub dry: bool,
}

impl BlockState {
    /// The state of every block of `sim` (all held by this process).
    pub fn of<T: Real>(sim: &Simulation<T>) -> Self {
        BlockState {
            quantities: (0..sim.blocks.len()).map(|b| Quantities::for_weights(sim, b)).collect(),
            dry: sim.fluid_cells() == 0,
        }
    }
}

/// `cells` weights: each block's fluid cells now (static fluid cells not covered by a particle: what the
/// fluid kernel updates), or its cell count in a scene without fluid.
pub fn cells(s: &BlockState) -> Vec<f64> {
    s.quantities.iter().map(|q| if s.dry { q.c } else { q.f }).collect()
}

/// `estimator` weights: each block's workload estimate of eq. (15) from its Table 1 quantities.
pub fn estimate(s: &BlockState, c: &Coefficients) -> Vec<f64> {
    s.quantities.iter().map(|q| c.total(q)).collect()
}

/// The weights of the initial assignment, before anything was measured: `measured` starts from `cells`,
/// `corrected` from the plain estimate (`coefficients` must be given for `estimator` and `corrected`).
pub fn initial(kind: Weights, s: &BlockState, coefficients: Option<&Coefficients>) -> Vec<f64> {
    match kind {
        Weights::Cells | Weights::Measured => cells(s),
        Weights::Uniform => vec![1.0; s.quantities.len()],
        Weights::Estimator | Weights::Corrected => {
            estimate(s, coefficients.expect("estimator weights have coefficients"))
        }
    }
}

/// Whether weights of `kind` are computed from the blocks' state (else from measurements or nothing).
pub fn need_state(kind: Weights) -> bool {
    matches!(kind, Weights::Cells | Weights::Estimator | Weights::Corrected)
}
