//! Criterion benchmarks of the load distribution strategies (`cargo bench --bench balance`).
//!
//! The cases are [`blockflow::app::bench::balance::SCALE_CASES`] (the same as `scale_table`): Hilbert keys
//! plus the greedy and the optimal split for 100 000 blocks (50 × 50 × 40) on 32 processes, and one
//! diffusive balancing step and one METIS k-way partition (with relabelling) of 288 blocks (6 × 6 × 8) on
//! 32 processes. Block weights are uniform in [0.5, 1.5) with a fixed seed; the current owners are the
//! Hilbert split of uniform weights.

use blockflow::app::bench::balance::{bench_case, SCALE_CASES};
use blockflow::balance::by_name;
use blockflow::config::BalanceConfig;
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use std::hint::black_box;
use std::time::Duration;

fn strategies(c: &mut Criterion) {
    let mut g = c.benchmark_group("balance");
    g.sample_size(20).measurement_time(Duration::from_secs(3));
    for (name, grid, p, strat, split) in SCALE_CASES {
        let (graph, w, owners) = bench_case(grid, p);
        let cfg = BalanceConfig {
            split,
            ..BalanceConfig::default()
        };
        g.throughput(Throughput::Elements(graph.len() as u64));
        g.bench_function(BenchmarkId::new(name, graph.len()), |b| {
            b.iter(|| {
                let mut s = by_name(strat, &cfg).expect("known strategy");
                black_box(s.distribute(&graph, &w, &owners, p))
            })
        });
    }
    g.finish();
}

criterion_group!(benches, strategies);
criterion_main!(benches);
