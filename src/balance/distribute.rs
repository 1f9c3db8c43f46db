//! Load distribution strategies behind one trait (waLBerla's `blockforest/loadbalancing` policy classes
//! are the model): [`Distribute`] and its implementations for the static assignment ([`Static`]), curve
//! splits ([`CurveSplit`]), diffusive balancing ([`super::diffusive::Diffusive`]) and METIS graph
//! partitioning ([`super::metis::Metis`]); [`super::strategy`] makes the one of a configuration.

use super::block_graph::BlockGraph;
use super::curves::Curve;
use crate::config::SplitKind;

/// Result of one distribution.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Distribution {
    /// The new owner process of every block.
    pub owners: Vec<u32>,
    /// Blocks that would move without METIS relabelling (None for other strategies).
    pub migrated_unrelabelled: Option<usize>,
}

/// A load distribution strategy: given the block graph, block weights, current owners and P, return new
/// owners. Deterministic: the same inputs give the same output (no thread or time dependence).
pub trait Distribute: Send {
    /// The strategy's name (`balance.strategy`).
    fn name(&self) -> &'static str;
    /// The new owner of every block.
    fn distribute(&mut self, g: &BlockGraph, weights: &[f64], owners: &[u32], processes: usize) -> Distribution;
}

/// `none`: every block stays where it is.
pub struct Static;

impl Distribute for Static {
    fn name(&self) -> &'static str {
        "none"
    }

    fn distribute(&mut self, _g: &BlockGraph, _weights: &[f64], owners: &[u32], _processes: usize) -> Distribution {
        Distribution {
            owners: owners.to_vec(),
            migrated_unrelabelled: None,
        }
    }
}

/// `hilbert` / `morton`: blocks in curve order, cut by `split` (see [`super::assign_with`]); the current
/// owners play no part.
pub struct CurveSplit {
    /// The curve.
    pub curve: Curve,
    /// How the curve order is cut.
    pub split: SplitKind,
}

impl Distribute for CurveSplit {
    fn name(&self) -> &'static str {
        match self.curve {
            Curve::Hilbert => "hilbert",
            Curve::Morton => "morton",
        }
    }

    fn distribute(&mut self, g: &BlockGraph, weights: &[f64], _owners: &[u32], processes: usize) -> Distribution {
        Distribution {
            owners: super::assign_with(g.grid, weights, processes, self.curve, self.split),
            migrated_unrelabelled: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::balance::block_graph::BlockGraph;
    use crate::balance::{by_name, strategy};
    use crate::config::{BalanceConfig, Strategy};
    use crate::physics::domain::DomainSpec;

    fn random_owners(n: usize, p: usize, seed: u64) -> Vec<u32> {
        let mut r = crate::util::hash::SplitMix(seed);
        (0..n).map(|_| (r.next_u64() % p as u64) as u32).collect()
    }

    #[test]
    fn static_and_curve_strategies() {
        let d = DomainSpec {
            blocks: [4, 4, 2],
            block_size: [4, 4, 4],
            periodic: [false; 3],
        };
        let g = BlockGraph::from_domain(&d);
        let w: Vec<f64> = (0..g.len()).map(|i| 1.0 + (i % 3) as f64).collect();
        let owners = random_owners(g.len(), 4, 9);
        let cfg = BalanceConfig::default();
        assert_eq!(
            by_name("none", &cfg).unwrap().distribute(&g, &w, &owners, 4).owners,
            owners
        );
        let h = by_name("hilbert", &cfg).unwrap().distribute(&g, &w, &owners, 4);
        assert_eq!(h.owners, super::super::assign(d.blocks, &w, 4, Curve::Hilbert));
        assert!(h.migrated_unrelabelled.is_none());
        assert!(by_name("bogus", &cfg).is_none());
        for s in [
            Strategy::None,
            Strategy::Hilbert,
            Strategy::Morton,
            Strategy::Diffusive,
            Strategy::Metis,
        ] {
            let c = BalanceConfig {
                strategy: s,
                ..BalanceConfig::default()
            };
            assert_eq!(format!("{s:?}").to_lowercase(), strategy(&c).name());
        }
    }

    /// Every strategy gives the same owners for the same inputs, twice and from fresh instances.
    #[test]
    fn every_strategy_is_deterministic() {
        let d = DomainSpec {
            blocks: [6, 6, 8],
            block_size: [8, 8, 8],
            periodic: [true, false, false],
        };
        let g = BlockGraph::from_domain(&d);
        let mut r = crate::util::hash::SplitMix(7);
        let w: Vec<f64> = (0..g.len()).map(|_| r.uniform(0.2, 3.0)).collect();
        let owners = super::super::assign(d.blocks, &vec![1.0; g.len()], 8, Curve::Hilbert);
        for name in ["none", "hilbert", "morton", "diffusive", "metis"] {
            for mode in [crate::config::DiffusiveMode::Push, crate::config::DiffusiveMode::Pull] {
                let cfg = BalanceConfig {
                    diffusive_mode: mode,
                    ..BalanceConfig::default()
                };
                let mut s = by_name(name, &cfg).unwrap();
                let a = s.distribute(&g, &w, &owners, 8);
                let b = s.distribute(&g, &w, &owners, 8);
                let c = by_name(name, &cfg).unwrap().distribute(&g, &w, &owners, 8);
                assert_eq!(a, b, "{name}");
                assert_eq!(a, c, "{name}");
                assert_eq!(a.owners.len(), g.len());
                assert!(a.owners.iter().all(|&o| o < 8));
            }
        }
    }
}
