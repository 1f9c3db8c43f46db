//! Assignment of blocks to virtual processes: curve orders and prefix splits, and the load distribution
//! strategies behind [`strategy::Distribute`] (static, curve split, diffusive, METIS) used by the dynamic
//! rebalancing of [`dynamic::Balancer`].

pub mod curves;
pub mod diffusive;
pub mod dynamic;
pub mod graph_partition;
pub mod split;
pub mod strategy;

pub use strategy::{BlockGraph, Distribute, Distribution};

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

/// Edge cut eq. (17) of an assignment: for every pair of neighbouring blocks on different processes,
/// face b², edge b, corner 1 (shared face area and edge length for non-cubic blocks), each pair once;
/// returned per process (the mean the paper reports).
pub fn edge_cut_mean(d: &crate::domain::DomainSpec, owners: &[u32], processes: usize) -> f64 {
    let s = d.block_size;
    let mut cut = 0.0;
    for id in 0..d.num_blocks() {
        for off in crate::domain::NEIGHBOURS {
            if let Some(n) = d.neighbour(id, off) {
                if n > id && owners[n] != owners[id] {
                    let zeros: Vec<usize> = (0..3).filter(|&a| off[a] == 0).collect();
                    cut += match zeros.len() {
                        2 => (s[zeros[0]] * s[zeros[1]]) as f64,
                        1 => s[zeros[0]] as f64,
                        _ => 1.0,
                    };
                }
            }
        }
    }
    cut / processes as f64
}
