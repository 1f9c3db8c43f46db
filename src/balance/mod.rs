//! Assignment of blocks to virtual processes: curve orders and prefix splits (the balancing issue adds
//! diffusive and METIS strategies and dynamic rebalancing on top).

pub mod curves;
pub mod dynamic;
pub mod split;

use curves::{curve_order, Curve};

/// Owner process of every block (by block id): blocks in curve order, split greedily by weight.
pub fn assign(blocks: [usize; 3], weights: &[f64], processes: usize, curve: Curve) -> Vec<u32> {
    assign_with(blocks, weights, processes, curve, crate::config::SplitKind::Greedy)
}

/// Owner process of every block: blocks in curve order, split by `split` (the paper's greedy prefix
/// split, or the contiguous split that minimises the heaviest process).
pub fn assign_with(
    blocks: [usize; 3],
    weights: &[f64],
    processes: usize,
    curve: Curve,
    kind: crate::config::SplitKind,
) -> Vec<u32> {
    let order = curve_order(blocks, curve);
    let w: Vec<f64> = order.iter().map(|&b| weights[b]).collect();
    let split = match kind {
        crate::config::SplitKind::Greedy => split::greedy_split(&w, processes),
        crate::config::SplitKind::Optimal => split::optimal_split(&w, processes),
    };
    let mut owner = vec![0u32; order.len()];
    for (pos, &b) in order.iter().enumerate() {
        owner[b] = split[pos];
    }
    owner
}
