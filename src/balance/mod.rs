//! Assignment of blocks to virtual processes: curve orders and prefix splits (the balancing issue adds
//! diffusive and METIS strategies and dynamic rebalancing on top).

pub mod curves;
pub mod dynamic;
pub mod split;

use curves::{curve_order, Curve};

/// Owner process of every block (by block id): blocks in curve order, split greedily by weight.
pub fn assign(blocks: [usize; 3], weights: &[f64], processes: usize, curve: Curve) -> Vec<u32> {
    let order = curve_order(blocks, curve);
    let w: Vec<f64> = order.iter().map(|&b| weights[b]).collect();
    let split = split::greedy_split(&w, processes);
    let mut owner = vec![0u32; order.len()];
    for (pos, &b) in order.iter().enumerate() {
        owner[b] = split[pos];
    }
    owner
}
