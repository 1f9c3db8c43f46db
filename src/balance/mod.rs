//! Assignment of blocks to virtual processes (section 4): curve orders and prefix splits ([`curves`],
//! [`split`]), the block graph ([`block_graph`]), the distribution strategies behind one trait
//! ([`distribute`]: static, curve split, [`diffusive`], [`metis`]), the block weights of
//! `balance.weights` ([`weights`]) and the balancing step of a run ([`balancer`]). Strategies see block
//! weights and the block graph only, never the simulation.

pub mod balancer;
pub mod block_graph;
pub mod curves;
pub mod diffusive;
pub mod distribute;
pub mod metis;
pub mod split;
pub mod weights;

pub use balancer::Balancer;
pub use block_graph::BlockGraph;
pub use distribute::{Distribute, Distribution};

use crate::config::{BalanceConfig, SplitKind, Strategy};
use curves::{curve_order, Curve};
use distribute::{CurveSplit, Static};

/// The curve a strategy orders blocks by for the initial assignment: Morton for `morton`, Hilbert for
/// every other (`none` is the paper's static Hilbert split).
pub fn curve_of(strategy: Strategy) -> Curve {
    match strategy {
        Strategy::Morton => Curve::Morton,
        Strategy::None | Strategy::Hilbert | Strategy::Diffusive | Strategy::Metis => Curve::Hilbert,
    }
}

/// Owner process of every block (by block id): blocks in curve order, split greedily by weight.
pub fn assign(blocks: [usize; 3], weights: &[f64], processes: usize, curve: Curve) -> Vec<u32> {
    assign_with(blocks, weights, processes, curve, SplitKind::Greedy)
}

/// Owner process of every block: blocks in curve order, split by `kind` (the paper's greedy prefix
/// split, or the contiguous split that minimises the heaviest process).
pub fn assign_with(blocks: [usize; 3], weights: &[f64], processes: usize, curve: Curve, kind: SplitKind) -> Vec<u32> {
    let order = curve_order(blocks, curve);
    let w: Vec<f64> = order.iter().map(|&b| weights[b]).collect();
    let split = match kind {
        SplitKind::Greedy => split::greedy_split(&w, processes),
        SplitKind::Optimal => split::optimal_split(&w, processes),
    };
    let mut owner = vec![0u32; order.len()];
    for (pos, &b) in order.iter().enumerate() {
        owner[b] = split[pos];
    }
    owner
}

/// The strategy of `cfg` (`none` returns the owners unchanged).
pub fn strategy(cfg: &BalanceConfig) -> Box<dyn Distribute> {
    let name = match cfg.strategy {
        Strategy::None => "none",
        Strategy::Hilbert => "hilbert",
        Strategy::Morton => "morton",
        Strategy::Diffusive => "diffusive",
        Strategy::Metis => "metis",
    };
    by_name(name, cfg).expect("every Strategy has a name")
}

/// Strategy by name: "none", "hilbert", "morton", "diffusive", "metis" (others → None), with the other
/// settings from `cfg`.
pub fn by_name(name: &str, cfg: &BalanceConfig) -> Option<Box<dyn Distribute>> {
    Some(match name {
        "none" => Box::new(Static),
        "hilbert" => Box::new(CurveSplit {
            curve: Curve::Hilbert,
            split: cfg.split,
        }),
        "morton" => Box::new(CurveSplit {
            curve: Curve::Morton,
            split: cfg.split,
        }),
        "diffusive" => Box::new(diffusive::Diffusive::new(
            cfg.diffusive_iterations,
            cfg.flow_iterations,
            cfg.diffusive_mode,
        )),
        "metis" => Box::new(metis::Metis::new(cfg.metis_imbalance)),
        _ => return None,
    })
}
