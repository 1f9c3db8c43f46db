//! Criterion benchmarks of the memory roofline and the stream-collide kernels (pull and AA).
//!
//! `cargo bench --bench kernel`. The "roofline" group copies two f64 arrays of max(4 × L3, 64 MiB) on one
//! thread, with plain and with non-temporal stores; its GB/s count read + write-allocate + write (24 B per
//! element), resp. read + write (16 B). The "fused_kernel" group runs one periodic 128³ block per thread
//! under each streaming pattern;
//! its throughput is in cells, so criterion's Melem/s are MLUPS. The workers and their blocks persist
//! across samples; allocation, first touch and warm-up steps are not timed. The "cut_rows" group runs the
//! AA kernel on one thread over 64 blocks of 16³ whose rows a pseudo-random pattern cuts into runs of 1 to
//! `max` cells with one-cell gaps (as walls and bodies cut them); its element is one fluid cell update.

use blockflow::app::bench::kernel::{
    alloc_copy_pair, copy_nt, copy_plain, l3_bytes, pattern_name, with_kernel_workers, KernelSetup, HAS_NT, SETUPS,
};
use blockflow_kernels::{sweep, Layout, PdfField, Real, Segment, TrtParams};
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

/// The runs of a 16³ block's rows cut into pieces of 1 to `max` cells with one-cell gaps (a fixed
/// pseudo-random pattern); `max = 0` leaves the rows whole.
fn cut_rows(l: &Layout, max: usize) -> Vec<Segment> {
    let n = l.size[0];
    let mut s: u64 = 12345;
    let mut segs = Vec::new();
    for z in 1..=n {
        for y in 1..=n {
            let mut x = 1;
            while x <= n {
                s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                let len = if max == 0 {
                    n
                } else {
                    (1 + (s >> 33) as usize % max).min(n + 1 - x)
                };
                segs.push(Segment {
                    start: l.idx(x, y, z),
                    len,
                });
                x += len + 1;
            }
        }
    }
    segs
}

/// The AA kernel (f64, one thread) on 64 blocks of 16³ with whole rows and with rows cut into short runs,
/// out of cache as a particulate scene's blocks are.
fn cut(c: &mut Criterion) {
    let mut g = c.benchmark_group("cut_rows");
    g.sample_size(10).measurement_time(Duration::from_secs(3));
    let l = Layout::new::<f64>([16; 3]);
    let mut fields: Vec<PdfField<f64>> = (0..64).map(|_| PdfField::<f64>::new(l, 0)).collect();
    let p = TrtParams {
        tau: 0.7,
        magic: 3.0 / 16.0,
        force: [0.0; 3],
    };
    for max in [0, 16, 8, 5] {
        let segs = cut_rows(&l, max);
        let cells: usize = segs.iter().map(|s| s.len).sum();
        g.throughput(Throughput::Elements((cells * fields.len()) as u64));
        let id = if max == 0 {
            "whole_rows".to_string()
        } else {
            format!("runs_of_1_to_{max}")
        };
        g.bench_function(id, |b| {
            // Whole pairs of steps, so AA's two step kinds are timed equally often.
            b.iter_custom(|iters| {
                let start = std::time::Instant::now();
                for step in 0..2 * iters {
                    for f in fields.iter_mut() {
                        sweep::aa_step(f, step, &segs, &p);
                    }
                }
                start.elapsed() / 2
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

criterion_group!(benches, roofline, kernels, cut);
criterion_main!(benches);
