//! Criterion benchmarks of the rigid-body sub-step and of contact detection.
//!
//! `cargo bench --bench rigid`. The packings are those of `blockflow bench rigid`
//! ([`blockflow::app::bench::rigid::packing`]: equal spheres of diameter 1 on a jittered simple-cubic lattice
//! squeezed by 1 % in a box of six planes, ~5 contacts per sphere). The "substep" group times one
//! `substep` with the grid (`RigidParams::default()` otherwise, gravity on) for N = 1000 and 10 000;
//! its throughput is in spheres, so criterion's elem/s are spheres per second. Every sample starts from a
//! fresh copy of the packing (copying is not timed). The "detect" group times all pairs against the grid at
//! N = 64, around the default `RigidParams::grid_threshold`.

use blockflow::app::bench::rigid::{packing, DT};
use blockflow_kernels::rigid::{detect_all_pairs, detect_grid, substep, RigidParams};
use criterion::{criterion_group, criterion_main, BatchSize, BenchmarkId, Criterion, Throughput};
use std::hint::black_box;
use std::time::Duration;

/// One grid sub-step for N = 1000 and 10 000.
fn substeps(c: &mut Criterion) {
    let p = RigidParams {
        grid_threshold: 0,
        ..RigidParams::default()
    };
    let mut g = c.benchmark_group("substep");
    g.sample_size(20).measurement_time(Duration::from_secs(5));
    for n in [1000, 10_000] {
        let (bodies, planes) = packing(n, n as u64);
        g.throughput(Throughput::Elements(n as u64));
        g.bench_function(BenchmarkId::new("grid", n), |b| {
            b.iter_batched_ref(
                || bodies.clone(),
                |bodies| substep(bodies, &planes, &p, DT),
                BatchSize::LargeInput,
            )
        });
    }
    g.finish();
}

/// All pairs vs grid detection at N = 64.
fn detection(c: &mut Criterion) {
    let margin = RigidParams::default().contact_margin;
    let n = 64;
    let (bodies, planes) = packing(n, n as u64);
    let mut g = c.benchmark_group("detect");
    g.sample_size(50).measurement_time(Duration::from_secs(3));
    g.bench_function(BenchmarkId::new("all_pairs", n), |b| {
        b.iter(|| detect_all_pairs(black_box(&bodies), &planes, margin))
    });
    g.bench_function(BenchmarkId::new("grid", n), |b| {
        b.iter(|| detect_grid(black_box(&bodies), &planes, margin))
    });
    g.finish();
}

criterion_group!(benches, substeps, detection);
criterion_main!(benches);
