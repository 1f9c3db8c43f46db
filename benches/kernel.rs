//! Criterion benchmarks of the memory roofline and the stream-collide kernels (pull and AA).
//!
//! `cargo bench --bench kernel`. The "roofline" group copies two f64 arrays of max(4 × L3, 64 MiB) on one
//! thread, with plain and with non-temporal stores; its GB/s count read + write-allocate + write (24 B per
//! element), resp. read + write (16 B). The "fused_kernel" group runs one periodic 128³ block per thread
//! under each streaming pattern;
//! its throughput is in cells, so criterion's Melem/s are MLUPS. The workers and their blocks persist
//! across samples; allocation, first touch and warm-up steps are not timed.

use blockflow::app::bench::kernel::{
    alloc_copy_pair, copy_nt, copy_plain, l3_bytes, pattern_name, with_kernel_workers, KernelSetup, HAS_NT, SETUPS,
};
use blockflow_kernels::Real;
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, SamplingMode, Throughput};
use std::time::Duration;

/// Cells per edge of each thread's block.
const SIZE: usize = 128;

/// Plain and non-temporal copy bandwidth, one thread.
fn roofline(c: &mut Criterion) {
    let len = (4 * l3_bytes()).max(64 << 20) / 8;
    let (src, mut dst) = alloc_copy_pair(len);
    let mut g = c.benchmark_group("roofline");
    g.sample_size(10).measurement_time(Duration::from_secs(5));
    g.throughput(Throughput::BytesDecimal((24 * len) as u64));
    g.bench_function("copy_plain", |b| {
        b.iter(|| copy_plain(src.as_slice(), dst.as_mut_slice()))
    });
    if HAS_NT {
        g.throughput(Throughput::BytesDecimal((16 * len) as u64));
        g.bench_function("copy_nt", |b| b.iter(|| copy_nt(src.as_slice(), dst.as_mut_slice())));
    }
    g.finish();
}

/// The pull and AA kernels of precision `T` on 1 and 2 threads (criterion's element is one cell update).
fn fused<T: Real>(c: &mut Criterion) {
    let mut g = c.benchmark_group("fused_kernel");
    g.sample_size(10)
        .measurement_time(Duration::from_secs(5))
        .warm_up_time(Duration::from_secs(1))
        .sampling_mode(SamplingMode::Flat);
    for threads in [1, 2] {
        for setup in SETUPS {
            let KernelSetup { pattern, huge_pages } = setup;
            g.throughput(Throughput::Elements((threads * SIZE.pow(3)) as u64));
            let pages = if huge_pages { "_thp" } else { "" };
            let id = BenchmarkId::new(
                format!("{}_{}{pages}_{SIZE}^3", T::NAME, pattern_name(pattern)),
                format!("{threads}t"),
            );
            with_kernel_workers::<T, _>(SIZE, threads, setup, |w| {
                g.bench_function(id, |b| {
                    // Whole pairs of steps, so AA's two step kinds are timed equally often.
                    b.iter_custom(|iters| {
                        let steps = 2 * usize::try_from(iters).expect("iterations");
                        Duration::from_secs_f64(w.time(steps) / 2.0)
                    });
                });
            });
        }
    }
    g.finish();
}

/// Both precisions.
fn kernels(c: &mut Criterion) {
    fused::<f64>(c);
    fused::<f32>(c);
}

criterion_group!(benches, roofline, kernels);
criterion_main!(benches);
