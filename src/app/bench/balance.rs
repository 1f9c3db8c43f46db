//! `blockflow bench balance`: the cost of the balancing step: curve keys and splits for 100 000 blocks,
//! diffusive and METIS on the hopper's 288 blocks for 32 processes.

use crate::balance::{self, by_name, curves::Curve, BlockGraph};
use crate::config::{BalanceConfig, SplitKind};
use crate::physics::domain::DomainSpec;
use crate::util::hash::SplitMix;

/// The cases of the balancing benchmark (`benches/balance.rs`, [`scale_table`]): (name, grid, P, strategy
/// name, split).
pub const SCALE_CASES: [(&str, [usize; 3], usize, &str, SplitKind); 4] = [
    (
        "hilbert keys + greedy split",
        [50, 50, 40],
        32,
        "hilbert",
        SplitKind::Greedy,
    ),
    (
        "hilbert keys + optimal split",
        [50, 50, 40],
        32,
        "hilbert",
        SplitKind::Optimal,
    ),
    ("diffusive (push)", [6, 6, 8], 32, "diffusive", SplitKind::Greedy),
    ("metis k-way + relabel", [6, 6, 8], 32, "metis", SplitKind::Greedy),
];

/// The inputs of one benchmark case: graph, weights in [0.5, 1.5) (fixed seed) and the Hilbert owners.
pub fn bench_case(grid: [usize; 3], processes: usize) -> (BlockGraph, Vec<f64>, Vec<u32>) {
    let d = DomainSpec {
        blocks: grid,
        block_size: [16, 16, 16],
        periodic: [false; 3],
    };
    let g = BlockGraph::from_domain(&d);
    let mut rng = SplitMix(42);
    let w: Vec<f64> = (0..g.len()).map(|_| rng.uniform(0.5, 1.5)).collect();
    let owners = balance::assign(grid, &vec![1.0; g.len()], processes, Curve::Hilbert);
    (g, w, owners)
}

/// Times the balancing cases (curve keys + greedy / optimal split for 100 000 blocks, diffusive and METIS
/// for 288 blocks, P = 32) with `std::time::Instant`, median of 7 repeats, as a markdown table.
pub fn scale_table() -> String {
    let mut out = String::from("| case | blocks | P | milliseconds |\n|---|---:|---:|---:|\n");
    for (name, grid, p, strat, split) in SCALE_CASES {
        let (g, w, owners) = bench_case(grid, p);
        let cfg = BalanceConfig {
            split,
            ..BalanceConfig::default()
        };
        let mut times = Vec::new();
        for _ in 0..7 {
            let mut s = by_name(strat, &cfg).expect("known strategy");
            let t0 = std::time::Instant::now();
            let d = s.distribute(&g, &w, &owners, p);
            times.push(t0.elapsed().as_secs_f64() * 1e3);
            std::hint::black_box(d);
        }
        times.sort_by(f64::total_cmp);
        out.push_str(&format!(
            "| {name} | {} | {p} | {:.3} |\n",
            g.len(),
            times[times.len() / 2]
        ));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `cargo test --release --lib print_scale_table -- --ignored --nocapture`
    #[test]
    #[ignore = "timing table; run in release"]
    fn print_scale_table() {
        let t = scale_table();
        println!("{t}");
        assert_eq!(t.lines().count(), 2 + SCALE_CASES.len());
    }

    #[test]
    fn scale_table_lists_every_case() {
        // Only the format here (timings are for `blockflow bench balance` in release builds).
        let (g, w, o) = bench_case([6, 6, 8], 32);
        assert_eq!((g.len(), w.len(), o.len()), (288, 288, 288));
        assert!(w.iter().all(|&x| (0.5..1.5).contains(&x)));
    }
}
