//! Criterion benchmarks of the memory roofline and the fused stream-collide kernel.
//!
//! `cargo bench --bench kernel`. The "roofline" group copies two f64 arrays of max(4 × L3, 64 MiB) on one
//! thread, with plain and with non-temporal stores; its GB/s count read + write-allocate + write (24 B per
//! element), resp. read + write (16 B). The "fused_kernel" group runs one periodic 128³ block per thread;
//! its throughput is in cells, so criterion's Melem/s are MLUPS. The workers and their blocks persist
//! across samples; allocation, first touch and warm-up steps are not timed.

use blockflow::app::bench::kernel::{alloc_copy_pair, copy_nt, copy_plain, l3_bytes, with_fused_workers, HAS_NT};
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

/// The fused kernel of precision `T` on 1 and 2 threads.
fn fused<T: Real>(c: &mut Criterion) {
    let mut g = c.benchmark_group("fused_kernel");
    g.sample_size(10)
        .measurement_time(Duration::from_secs(5))
        .warm_up_time(Duration::from_secs(1))
        .sampling_mode(SamplingMode::Flat);
    for threads in [1, 2] {
        g.throughput(Throughput::Elements((threads * SIZE.pow(3)) as u64));
        let id = BenchmarkId::new(format!("{}_{SIZE}^3", T::NAME), format!("{threads}t"));
        with_fused_workers::<T, _>(SIZE, threads, |w| {
            g.bench_function(id, |b| {
                b.iter_custom(|iters| Duration::from_secs_f64(w.time(usize::try_from(iters).expect("iterations"))));
            });
        });
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
