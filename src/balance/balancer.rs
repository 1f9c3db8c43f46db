//! The balancing step (section 4): at the end of every `balance.interval` steps, weigh every block
//! (`balance.weights`) and let the strategy ([`Distribute`]: curve split, diffusive, METIS) distribute
//! them; the time loop hands the new owners to the pipeline, which moves the blocks whose owner changed.
//! The numerics never see an owner, so the result stays bitwise identical whatever the weights and moves.

use super::block_graph::BlockGraph;
use super::distribute::{Distribute, Distribution};
use super::weights::{self, BlockState};
use crate::config::{BalanceConfig, Weights};
use crate::estimator::{Coefficients, Corrector};

/// State of the dynamic balancing of one run.
pub struct Balancer {
    /// What a block weighs.
    pub weights: Weights,
    /// The distribution strategy.
    pub strategy: Box<dyn Distribute>,
    /// The block graph the strategy works on.
    pub graph: BlockGraph,
    /// Virtual processes.
    pub processes: usize,
    /// Whether `estimator` weights are forecast ([`crate::estimator::forecast`]; `balance.forecast`).
    pub forecast: bool,
    /// Estimator coefficients (for `estimator` and `corrected`).
    pub coefficients: Option<Coefficients>,
    /// Predictor–corrector state (for `corrected`).
    pub corrector: Corrector,
    /// Prediction of eq. (15) summed over the current interval's steps, per block.
    predicted: Vec<f64>,
    /// Blocks moved so far.
    pub migrated: u64,
    /// Seconds spent balancing.
    pub seconds: f64,
    /// Balancing steps taken.
    pub steps: u64,
    /// The block weights of the last balancing step.
    last: Vec<f64>,
    /// Every block's estimate at the last balancing step (`estimator` weights: the start of the trend
    /// [`crate::estimator::forecast`] extends).
    previous_estimate: Vec<f64>,
}

impl Balancer {
    /// A balancer of the blocks of `domain` with the distribution `strategy` (`estimator` weights
    /// forecast).
    pub fn new(
        weights: Weights,
        strategy: Box<dyn Distribute>,
        processes: usize,
        coefficients: Option<Coefficients>,
        domain: &crate::physics::domain::DomainSpec,
    ) -> Self {
        let graph = BlockGraph::from_domain(domain);
        let blocks = graph.len();
        Balancer {
            weights,
            forecast: true,
            strategy,
            graph,
            processes,
            coefficients,
            corrector: Corrector::new(blocks),
            predicted: vec![0.0; blocks],
            migrated: 0,
            seconds: 0.0,
            steps: 0,
            last: Vec::new(),
            previous_estimate: Vec::new(),
        }
    }

    /// The balancer of `cfg.strategy` with `cfg.weights` (`coefficients` for `estimator` and `corrected`
    /// weights) on `processes` processes; `None` for `"none"` (the assignment never changes).
    pub fn of(
        cfg: &BalanceConfig,
        processes: usize,
        coefficients: Option<Coefficients>,
        domain: &crate::physics::domain::DomainSpec,
    ) -> Option<Balancer> {
        (cfg.strategy != crate::config::Strategy::None).then(|| Balancer {
            forecast: cfg.forecast,
            ..Balancer::new(cfg.weights, super::strategy(cfg), processes, coefficients, domain)
        })
    }

    fn estimate(&self, s: &BlockState) -> Vec<f64> {
        weights::estimate(
            s,
            self.coefficients.as_ref().expect("estimator weights have coefficients"),
        )
    }

    /// Whether the weights are computed from the blocks' state ([`BlockState`], for [`Balancer::after_run`]
    /// and [`Balancer::rebalance`]; else any state will do, an empty one too).
    pub fn needs_state(&self) -> bool {
        weights::need_state(self.weights)
    }

    /// Whether [`Balancer::after_run`] reads the blocks' state.
    pub fn needs_state_after_runs(&self) -> bool {
        self.weights == Weights::Corrected
    }

    /// Bookkeeping after a graph run of `k` steps from the blocks' state after it: the corrector's
    /// prediction for the interval.
    pub fn after_run(&mut self, s: &BlockState, k: usize) {
        if self.weights == Weights::Corrected {
            let e = self.estimate(s);
            for (p, x) in self.predicted.iter_mut().zip(e) {
                *p += k as f64 * x;
            }
        }
    }

    /// Block weights for the next distribution, from the blocks' state and the interval's measured
    /// per-block load.
    pub fn block_weights(&mut self, s: &BlockState, block_load: &[f64]) -> Vec<f64> {
        match self.weights {
            Weights::Cells => weights::cells(s),
            Weights::Uniform => vec![1.0; self.graph.len()],
            Weights::Estimator => {
                let e = self.estimate(s);
                let w = if self.forecast {
                    crate::estimator::forecast(&e, &self.previous_estimate)
                } else {
                    e.clone()
                };
                self.previous_estimate = e;
                w
            }
            Weights::Measured => crate::estimator::measured(block_load),
            Weights::Corrected => {
                self.corrector.update(&self.predicted, block_load);
                self.predicted.iter_mut().for_each(|p| *p = 0.0);
                let e = self.estimate(s);
                self.corrector.weights(&e)
            }
        }
    }

    /// The balancing step: block weights, then the strategy's distribution starting from the current
    /// `owners`; returns the new owner of every block (and, for METIS, the moves without relabelling).
    pub fn rebalance(&mut self, s: &BlockState, block_load: &[f64], owners: &[u32]) -> Distribution {
        self.steps += 1;
        self.last = self.block_weights(s, block_load);
        self.strategy
            .distribute(&self.graph, &self.last, owners, self.processes)
    }

    /// The corrector's prediction summed over the interval under way, per block (checkpoints store it).
    pub fn predicted(&self) -> &[f64] {
        &self.predicted
    }

    /// Restores the interval's prediction from a checkpoint (see [`Balancer::predicted`]).
    pub fn set_predicted(&mut self, predicted: Vec<f64>) {
        self.predicted = predicted;
    }

    /// Every block's estimate at the last balancing step under `estimator` weights (empty before the
    /// first; checkpoints store it).
    pub fn previous_estimate(&self) -> &[f64] {
        &self.previous_estimate
    }

    /// Restores the estimate of the last balancing step from a checkpoint (see
    /// [`Balancer::previous_estimate`]).
    pub fn set_previous_estimate(&mut self, e: Vec<f64>) {
        self.previous_estimate = e;
    }

    /// The block weights of the last balancing step (empty before the first).
    pub fn last_weights(&self) -> &[f64] {
        &self.last
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::balance::block_graph::closed_domain;
    use crate::config::Strategy;
    use crate::estimator::{Model, Provenance, Quantities};

    /// `estimator` weights at successive balancing steps: the plain estimate at the first, then each
    /// block's estimate extended by half its change since the step before (a load rising from 1 to 1.5
    /// weighs 1.75, one falling from 2 to 0.5 is held at half its estimate, 0.25).
    #[test]
    fn estimator_weights_extend_the_change_since_the_balancing_step_before() {
        let mut c = Coefficients::zeros(Model::Paper, Provenance::default());
        c.parts[0] = vec![0.0, 1e-3, 0.0]; // LBM = 1e-3 F
        let cfg = BalanceConfig {
            strategy: Strategy::Hilbert,
            ..Default::default()
        };
        let d = closed_domain([2, 1, 1]);
        let new = || {
            Balancer::new(
                Weights::Estimator,
                crate::balance::strategy(&cfg),
                2,
                Some(c.clone()),
                &d,
            )
        };
        let mut b = new();
        let state = |f: [f64; 2]| BlockState {
            quantities: f
                .iter()
                .map(|&f| Quantities {
                    c: 4096.0,
                    f,
                    ..Default::default()
                })
                .collect(),
            dry: false,
        };
        let load = [0.0, 0.0];
        assert_eq!(b.block_weights(&state([1000.0, 2000.0]), &load), vec![1.0, 2.0]);
        assert_eq!(b.previous_estimate(), &[1.0, 2.0]);
        assert_eq!(b.block_weights(&state([1500.0, 500.0]), &load), vec![1.75, 0.25]);
        // Without the forecast (the paper's weights): the estimate itself.
        let mut plain = Balancer {
            forecast: false,
            ..new()
        };
        plain.block_weights(&state([1000.0, 2000.0]), &load);
        assert_eq!(plain.block_weights(&state([1500.0, 500.0]), &load), vec![1.5, 0.5]);
        // A restored balancer continues the same trend.
        let mut r = new();
        r.set_previous_estimate(b.previous_estimate().to_vec());
        assert_eq!(
            r.block_weights(&state([2000.0, 500.0]), &load),
            b.block_weights(&state([2000.0, 500.0]), &load)
        );
    }
}
