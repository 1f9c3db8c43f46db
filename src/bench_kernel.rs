//! `blockflow bench kernel`: the fused stream-collide kernel against a memory-bandwidth roofline.
//!
//! The roofline is a copy of two f64 arrays far larger than L3, once with ordinary stores (each element
//! costs a read, a write-allocate read and a write: 3 × 8 B) and once with non-temporal stores (2 × 8 B).
//! A D3Q19 cell update moves 19 reads and 19 writes, plus 19 write-allocate reads unless the stores
//! bypass the cache: 456 B (f64) with write-allocate, 304 B without. The kernel rows run one periodic
//! fluid block per thread through `stream_collide` and compare the MLUPS with both rooflines.

use blockflow_kernels::field::AlignedBuf;
use blockflow_kernels::sweep::{full_segments, stream_collide};
use blockflow_kernels::{Layout, PdfField, Real, TrtParams};
use std::fmt::Write as _;
use std::hint::black_box;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Barrier;
use std::time::Instant;

/// Whether [`copy_nt`] really uses non-temporal stores on this target (x86_64 only).
pub const HAS_NT: bool = cfg!(target_arch = "x86_64");

/// Skew of the second array of a pair, so source and destination do not alias on 4 KiB.
const PAIR_SKEW_BYTES: usize = 2048 + 96;

/// Options of `blockflow bench kernel`.
#[derive(Clone, Debug)]
pub struct KernelBenchOptions {
    /// Short timings and the smallest roofline arrays (still at least 4 × L3).
    pub quick: bool,
    /// Cells per edge of each thread's cubic block.
    pub size: usize,
    /// Thread counts to measure.
    pub threads: Vec<usize>,
}

impl Default for KernelBenchOptions {
    fn default() -> Self {
        KernelBenchOptions {
            quick: false,
            size: 128,
            threads: vec![1, 2],
        }
    }
}

/// One measured row.
#[derive(Clone, Debug)]
pub struct KernelBenchRow {
    /// "f64" or "f32".
    pub precision: &'static str,
    /// Worker threads, one block each.
    pub threads: usize,
    /// Aggregate million lattice updates per second.
    pub mlups: f64,
    /// Roofline with write-allocate (456 B per cell for f64, 228 B for f32), MLUPS.
    pub roofline_plain_mlups: f64,
    /// Roofline without write-allocate (304 B per cell for f64, 152 B for f32), MLUPS.
    pub roofline_nt_mlups: f64,
    /// `mlups` as a percentage of `roofline_plain_mlups`.
    pub pct_write_allocate: f64,
    /// `mlups` as a percentage of `roofline_nt_mlups`.
    pub pct_no_write_allocate: f64,
}

/// The roofline measurement.
#[derive(Clone, Debug)]
pub struct Roofline {
    /// Threads copying at once, each its own pair of arrays.
    pub threads: usize,
    /// Aggregate copy bandwidth with plain stores, counting read + write-allocate + write (3 × 8 B per element).
    pub copy_gbs: f64,
    /// Aggregate copy bandwidth with non-temporal stores (2 × 8 B per element); NaN where unavailable.
    pub copy_nt_gbs: f64,
    /// Bytes of each array.
    pub array_bytes: usize,
}

/// Everything `blockflow bench kernel` measured.
#[derive(Clone, Debug)]
pub struct KernelBenchReport {
    /// Cells per edge of each thread's block.
    pub size: usize,
    /// One roofline per thread count.
    pub rooflines: Vec<Roofline>,
    /// Kernel rows: f64 for each thread count, then f32.
    pub rows: Vec<KernelBenchRow>,
}

/// Bytes a cell update of precision `T` moves with write-allocate (57 accesses) and without (38 accesses).
pub fn bytes_per_cell<T: Real>() -> (f64, f64) {
    ((57 * T::BYTES) as f64, (38 * T::BYTES) as f64)
}

/// L3 size of cpu0 from sysfs, or 32 MiB when it cannot be read.
pub fn l3_bytes() -> usize {
    let parse = |s: &str| -> Option<usize> {
        let s = s.trim();
        let (num, mult) = match s.chars().last()? {
            'K' => (&s[..s.len() - 1], 1 << 10),
            'M' => (&s[..s.len() - 1], 1 << 20),
            'G' => (&s[..s.len() - 1], 1 << 30),
            _ => (s, 1),
        };
        num.parse::<usize>()
            .ok()
            .map(|n| n * mult)
            .filter(|&n| n > 0)
    };
    std::fs::read_to_string("/sys/devices/system/cpu/cpu0/cache/index3/size")
        .ok()
        .and_then(|s| parse(&s))
        .unwrap_or(32 << 20)
}

/// Copies `src` into `dst` with an explicit loop of ordinary (write-allocating) stores. The stores are
/// volatile, so the compiler cannot turn the loop into `memcpy` (which uses non-temporal stores for large
/// sizes); on x86_64 with AVX they are 32-byte `vmovapd`/`vmovupd`.
pub fn copy_plain(src: &[f64], dst: &mut [f64]) {
    assert_eq!(src.len(), dst.len(), "copy_plain: length mismatch");
    #[cfg(target_arch = "x86_64")]
    {
        if std::is_x86_feature_detected!("avx") {
            // SAFETY: AVX is available; lengths are equal.
            return unsafe { x86::copy_avx::<false>(src, dst) };
        }
        // SAFETY: SSE2 is baseline on x86_64; lengths are equal.
        unsafe { x86::copy_sse2::<false>(src, dst) }
    }
    #[cfg(not(target_arch = "x86_64"))]
    for (d, s) in dst.iter_mut().zip(src) {
        // SAFETY: `d` is a valid, aligned, exclusive reference.
        unsafe { std::ptr::write_volatile(d, *s) }
    }
}

/// Copies `src` into `dst` with non-temporal stores (`_mm256_stream_pd` with AVX, else `_mm_stream_pd`)
/// followed by `_mm_sfence`. Falls back to [`copy_plain`] where [`HAS_NT`] is false.
pub fn copy_nt(src: &[f64], dst: &mut [f64]) {
    assert_eq!(src.len(), dst.len(), "copy_nt: length mismatch");
    #[cfg(target_arch = "x86_64")]
    {
        if std::is_x86_feature_detected!("avx") {
            // SAFETY: AVX is available; lengths are equal.
            return unsafe { x86::copy_avx::<true>(src, dst) };
        }
        // SAFETY: SSE2 is baseline on x86_64; lengths are equal.
        unsafe { x86::copy_sse2::<true>(src, dst) }
    }
    #[cfg(not(target_arch = "x86_64"))]
    copy_plain(src, dst);
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use std::arch::x86_64::*;
    use std::ptr::write_volatile;

    /// Scalar volatile copy of elements `from..to` (head and tail of the vector loops).
    ///
    /// # Safety
    /// `from <= to <= len` of both slices.
    #[inline(always)]
    unsafe fn scalar(src: &[f64], dst: &mut [f64], from: usize, to: usize) {
        for i in from..to {
            unsafe { write_volatile(dst.as_mut_ptr().add(i), *src.get_unchecked(i)) }
        }
    }

    macro_rules! copy_fn {
        ($name:ident, $feat:literal, $lanes:expr, $vec:ty, $load:ident, $stream:ident) => {
            /// Copy with aligned vector stores: non-temporal when `NT`, else volatile ordinary stores.
            ///
            /// # Safety
            /// The CPU supports the target feature; `src.len() == dst.len()`.
            #[target_feature(enable = $feat)]
            pub unsafe fn $name<const NT: bool>(src: &[f64], dst: &mut [f64]) {
                let n = dst.len();
                let head = dst.as_ptr().align_offset($lanes * 8).min(n);
                let end = head + (n - head) / $lanes * $lanes;
                unsafe {
                    scalar(src, dst, 0, head);
                    let (s, d) = (src.as_ptr(), dst.as_mut_ptr());
                    let mut i = head;
                    while i < end {
                        let v = $load(s.add(i));
                        if NT {
                            $stream(d.add(i), v);
                        } else {
                            write_volatile(d.add(i) as *mut $vec, v);
                        }
                        i += $lanes;
                    }
                    scalar(src, dst, end, n);
                    if NT {
                        _mm_sfence();
                    }
                }
            }
        };
    }
    copy_fn!(
        copy_avx,
        "avx",
        4,
        __m256d,
        _mm256_loadu_pd,
        _mm256_stream_pd
    );
    copy_fn!(copy_sse2, "sse2", 2, __m128d, _mm_loadu_pd, _mm_stream_pd);
}

/// A source/destination pair of `len` f64 each, allocated and first-touched by the calling thread; the
/// destination is skewed by 2 KiB + 96 B so the pair does not alias on 4 KiB.
pub fn alloc_copy_pair(len: usize) -> (AlignedBuf<f64>, AlignedBuf<f64>) {
    let mut src = AlignedBuf::<f64>::zeroed(len, 0);
    let mut dst = AlignedBuf::<f64>::zeroed(len, PAIR_SKEW_BYTES);
    for (i, v) in src.as_mut_slice().iter_mut().enumerate() {
        *v = i as f64;
    }
    copy_plain(src.as_slice(), dst.as_mut_slice());
    (src, dst)
}

/// Runs `work` on `threads` scoped threads (each gets the shared start barrier) and collects the results.
fn on_threads<R: Send>(threads: usize, work: impl Fn(&Barrier) -> R + Sync) -> Vec<R> {
    let barrier = Barrier::new(threads);
    std::thread::scope(|s| {
        let handles: Vec<_> = (0..threads).map(|_| s.spawn(|| work(&barrier))).collect();
        handles
            .into_iter()
            .map(|h| h.join().expect("benchmark thread panicked"))
            .collect()
    })
}

/// Best repetition over per-thread repetition times, where the slowest thread decides each repetition.
fn best_of(per_thread: &[&[f64]]) -> f64 {
    let reps = per_thread.iter().map(|t| t.len()).min().unwrap_or(0);
    (0..reps)
        .map(|r| per_thread.iter().map(|t| t[r]).fold(0.0, f64::max))
        .fold(f64::INFINITY, f64::min)
}

/// Measures the copy roofline with `threads` threads, each copying its own pair of arrays of
/// `array_bytes` bytes; best of `reps` repetitions.
pub fn measure_roofline(threads: usize, array_bytes: usize, reps: usize) -> Roofline {
    let threads = threads.max(1);
    let len = array_bytes / 8;
    let per_thread = |barrier: &Barrier| {
        let (src, mut dst) = alloc_copy_pair(len);
        let (mut plain, mut nt) = (Vec::new(), Vec::new());
        for _ in 0..reps.max(1) {
            barrier.wait();
            let t = Instant::now();
            copy_plain(src.as_slice(), dst.as_mut_slice());
            plain.push(t.elapsed().as_secs_f64());
            barrier.wait();
            let t = Instant::now();
            copy_nt(src.as_slice(), dst.as_mut_slice());
            nt.push(t.elapsed().as_secs_f64());
        }
        black_box(dst.as_slice());
        (plain, nt)
    };
    let results = on_threads(threads, per_thread);
    let plain = best_of(&results.iter().map(|r| &r.0[..]).collect::<Vec<_>>());
    let nt = best_of(&results.iter().map(|r| &r.1[..]).collect::<Vec<_>>());
    let elems = (len * threads) as f64;
    Roofline {
        threads,
        copy_gbs: 24.0 * elems / plain / 1e9,
        copy_nt_gbs: if HAS_NT {
            16.0 * elems / nt / 1e9
        } else {
            f64::NAN
        },
        array_bytes: len * 8,
    }
}

/// How many timed steps the kernel runs per repetition.
#[derive(Clone, Copy, Debug)]
enum StepPlan {
    Fixed(usize),
    /// About this many seconds, from the slowest thread's warm-up step time.
    Seconds(f64),
}

/// Runs the fused kernel on one `size`³ fluid block per thread: fields allocated and first-touched in the
/// worker, 2 warm-up steps, then `reps` timed repetitions. Returns (steps per repetition, best seconds).
fn fused_timing<T: Real>(size: usize, threads: usize, plan: StepPlan, reps: usize) -> (usize, f64) {
    let threads = threads.max(1);
    let size = size.max(1);
    let warm_step = AtomicU64::new(0);
    let params = TrtParams {
        tau: 0.6,
        magic: 3.0 / 16.0,
        force: [0.0; 3],
    };
    let per_thread = |barrier: &Barrier| {
        let layout = Layout::new::<T>([size; 3]);
        let segs = full_segments(&layout);
        let mut a = PdfField::<T>::new(layout, 0);
        let mut b = PdfField::<T>::new(layout, PAIR_SKEW_BYTES);
        a.data_mut().fill(T::ZERO);
        b.data_mut().fill(T::ZERO);
        barrier.wait();
        let t = Instant::now();
        for _ in 0..2 {
            black_box(stream_collide(&a, &mut b, &segs, &params));
            std::mem::swap(&mut a, &mut b);
        }
        // Positive f64 order like their bits, so fetch_max keeps the slowest thread's step time.
        warm_step.fetch_max(
            (t.elapsed().as_secs_f64() / 2.0).to_bits(),
            Ordering::Relaxed,
        );
        barrier.wait();
        let steps = match plan {
            StepPlan::Fixed(n) => n,
            StepPlan::Seconds(s) => {
                (s / f64::from_bits(warm_step.load(Ordering::Relaxed))).round() as usize
            }
        }
        .clamp(1, 1 << 20);
        let mut times = Vec::new();
        for _ in 0..reps.max(1) {
            barrier.wait();
            let t = Instant::now();
            for _ in 0..steps {
                black_box(stream_collide(&a, &mut b, &segs, &params));
                std::mem::swap(&mut a, &mut b);
            }
            times.push(t.elapsed().as_secs_f64());
        }
        black_box(a.data());
        (steps, times)
    };
    let results = on_threads(threads, per_thread);
    (
        results[0].0,
        best_of(&results.iter().map(|r| &r.1[..]).collect::<Vec<_>>()),
    )
}

/// Seconds for `steps` fused stream-collide steps on one `size`³ block per thread, `threads` threads
/// started together (slowest thread; allocation, first touch and 2 warm-up steps excluded).
pub fn run_fused<T: Real>(size: usize, steps: usize, threads: usize) -> f64 {
    fused_timing::<T>(size, threads, StepPlan::Fixed(steps), 1).1
}

fn kernel_row<T: Real>(size: usize, roofline: &Roofline, seconds: f64) -> KernelBenchRow {
    let (steps, secs) =
        fused_timing::<T>(size, roofline.threads, StepPlan::Seconds(seconds / 3.0), 3);
    let mlups = (roofline.threads * size.max(1).pow(3) * steps) as f64 / secs / 1e6;
    let (wa, nwa) = bytes_per_cell::<T>();
    let roofline_plain_mlups = roofline.copy_gbs * 1e9 / wa;
    let roofline_nt_mlups = roofline.copy_nt_gbs * 1e9 / nwa;
    KernelBenchRow {
        precision: T::NAME,
        threads: roofline.threads,
        mlups,
        roofline_plain_mlups,
        roofline_nt_mlups,
        pct_write_allocate: mlups / roofline_plain_mlups * 100.0,
        pct_no_write_allocate: mlups / roofline_nt_mlups * 100.0,
    }
}

/// Runs the benchmark: roofline for each thread count, then the fused kernel on one periodic fluid block
/// of size³ per thread (f64 and f32), and returns the table.
pub fn run(opts: &KernelBenchOptions) -> KernelBenchReport {
    let four_l3 = 4 * l3_bytes();
    let (array_bytes, copy_reps, seconds) = if opts.quick {
        (four_l3, 5, 0.5)
    } else {
        (four_l3.max(64 << 20), 15, 2.5)
    };
    let rooflines: Vec<Roofline> = opts
        .threads
        .iter()
        .map(|&t| measure_roofline(t, array_bytes, copy_reps))
        .collect();
    let mut rows: Vec<KernelBenchRow> = rooflines
        .iter()
        .map(|r| kernel_row::<f64>(opts.size, r, seconds))
        .collect();
    rows.extend(
        rooflines
            .iter()
            .map(|r| kernel_row::<f32>(opts.size, r, seconds)),
    );
    KernelBenchReport {
        size: opts.size.max(1),
        rooflines,
        rows,
    }
}

fn cpu_model() -> String {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|m| m.trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".to_string())
}

fn num(v: f64, digits: usize) -> String {
    if v.is_finite() {
        format!("{v:.digits$}")
    } else {
        "n/a".to_string()
    }
}

impl KernelBenchReport {
    /// Markdown table as printed by `blockflow bench kernel`.
    pub fn to_markdown(&self) -> String {
        let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
        let l3 = l3_bytes();
        let mut s = String::new();
        let _ = writeln!(
            s,
            "Machine: {}, {cores} cores, L3 {} MiB\n",
            cpu_model(),
            l3 >> 20
        );
        if let Some(r) = self.rooflines.first() {
            let _ = writeln!(
                s,
                "Roofline: copy of f64 arrays, {} MiB each, one pair per thread\n",
                r.array_bytes >> 20
            );
        }
        s.push_str("| threads | copy GB/s (plain, 24 B/elem) | copy GB/s (NT, 16 B/elem) ");
        s.push_str("| roofline f64 MLUPS (456 B) | roofline f64 MLUPS NT (304 B) |\n|---:|---:|---:|---:|---:|\n");
        for r in &self.rooflines {
            let (wa, nwa) = bytes_per_cell::<f64>();
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} |",
                r.threads,
                num(r.copy_gbs, 1),
                num(r.copy_nt_gbs, 1),
                num(r.copy_gbs * 1e9 / wa / 1e6, 1),
                num(r.copy_nt_gbs * 1e9 / nwa / 1e6, 1)
            );
        }
        let n = self.size;
        let _ = writeln!(
            s,
            "\nFused stream-collide kernel (TRT), one periodic {n}^3 fluid block per thread\n"
        );
        s.push_str("| precision | threads | MLUPS | % of write-allocate roofline (456 B) | % of NT roofline (304 B) |\n");
        s.push_str("|---|---:|---:|---:|---:|\n");
        for r in &self.rows {
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} |",
                r.precision,
                r.threads,
                num(r.mlups, 1),
                num(r.pct_write_allocate, 0),
                num(r.pct_no_write_allocate, 0)
            );
        }
        s.push_str("\nThe fused kernel alone: ghost exchange excluded (the ghost layer is not refreshed). ");
        s.push_str("f32 rows use 228 B / 152 B per cell.\n");
        s.push_str("Reference: waLBerla fused TRT measured on this machine: 34.7 MLUPS (1 core), 66 (2 cores); ");
        s.push_str("lbmpy AVX2: ~36 f64 / ~69 f32 at 1 thread.\n");
        s.push_str("Target: f64 at 1 thread >= 75 % of the write-allocate roofline");
        match self
            .rows
            .iter()
            .find(|r| r.precision == "f64" && r.threads == 1)
        {
            Some(r) if r.pct_write_allocate.is_finite() => {
                let verdict = if r.pct_write_allocate >= 75.0 {
                    "met"
                } else {
                    "not met"
                };
                let _ = writeln!(s, ": {} % ({verdict}).", num(r.pct_write_allocate, 0));
            }
            _ => s.push_str(".\n"),
        }
        s
    }
}
