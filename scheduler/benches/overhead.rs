//! Scheduler overhead: empty tasks on small pools (criterion prints tasks/s).
//!
//! Graphs: (a) 10 000 independent tasks, (b) a chain of 10 000 tasks, (c) one step of 64 blocks × 6 tasks
//! with face-neighbour edges between the exchange parts (a 4×4×4 periodic stencil). Pools: 1×1, 1×2, 2×1
//! (processes × threads), unpinned so the bench runs anywhere.

use blockflow_scheduler::executor::{empty_task_overhead_ns, Executor, PoolConfig};
use blockflow_scheduler::{GraphBuilder, TaskGraph, TaskSpec};
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use std::time::Duration;

fn spec(owner: u32, part: u8, block: u32) -> TaskSpec {
    TaskSpec {
        owner,
        part,
        block,
        payload: 0,
    }
}

fn independent(n: u32, processes: u32) -> TaskGraph {
    let mut g = GraphBuilder::new();
    for i in 0..n {
        g.add(spec(i % processes, 0, i));
    }
    g.build().expect("acyclic")
}

fn chain(n: u32, processes: u32) -> TaskGraph {
    let mut g = GraphBuilder::new();
    for i in 0..n {
        // Blocks of 100 consecutive tasks per process, so a few hand-offs between processes happen.
        g.add(spec((i / 100) % processes, 0, i));
    }
    for i in 1..n {
        g.edge(i - 1, i);
    }
    g.build().expect("acyclic")
}

fn bench(c: &mut Criterion) {
    let shapes = [(1usize, 1usize), (1, 2), (2, 1)];
    for (p, t) in shapes {
        let pool = match Executor::new(PoolConfig::unpinned(p, t)) {
            Ok(pool) => pool,
            Err(e) => {
                eprintln!("skipping {p}x{t}: {e}");
                continue;
            }
        };
        eprintln!(
            "pool {p}x{t}: {:.0} ns wall per empty independent task (best of 7 runs of 10000)",
            empty_task_overhead_ns(&pool, 10_000)
        );
        let graphs = [
            ("independent_10000", independent(10_000, p as u32)),
            ("chain_10000", chain(10_000, p as u32)),
            ("stencil_64x6", TaskGraph::synthetic_stencil(p as u32).0),
        ];
        let mut group = c.benchmark_group(format!("scheduler_{p}x{t}"));
        group.sample_size(10);
        group.warm_up_time(Duration::from_millis(500));
        group.measurement_time(Duration::from_secs(2));
        for (name, graph) in &graphs {
            group.throughput(Throughput::Elements(graph.len() as u64));
            group.bench_function(*name, |b| {
                b.iter(|| pool.run(graph, |_, _, _| {}));
            });
        }
        group.finish();
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
