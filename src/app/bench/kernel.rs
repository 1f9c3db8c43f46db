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
use std::hint::black_box;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
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
        num.parse::<usize>().ok().map(|n| n * mult).filter(|&n| n > 0)
    };
    std::fs::read_to_string("/sys/devices/system/cpu/cpu0/cache/index3/size")
        .ok()
        .and_then(|s| parse(&s))
        .unwrap_or(32 << 20)
}

/// Copies `src` into `dst` with an explicit loop of ordinary (write-allocating) stores. The stores are
/// volatile, so the compiler cannot turn the loop into `memcpy` (which uses non-temporal stores for large
/// sizes); on x86_64 with AVX they are 32-byte `vmovaps`.
pub fn copy_plain(src: &[f64], dst: &mut [f64]) {
    copy::<false>(src, dst);
}

/// Copies `src` into `dst` with non-temporal stores (`_mm256_stream_pd` with AVX, else `_mm_stream_pd`)
/// followed by `_mm_sfence`. Plain stores where [`HAS_NT`] is false.
pub fn copy_nt(src: &[f64], dst: &mut [f64]) {
    copy::<true>(src, dst);
}

/// Shared body of [`copy_plain`] (`NT = false`) and [`copy_nt`], dispatching on the instruction set.
fn copy<const NT: bool>(src: &[f64], dst: &mut [f64]) {
    assert_eq!(src.len(), dst.len(), "copy: length mismatch");
    #[cfg(target_arch = "x86_64")]
    {
        if std::is_x86_feature_detected!("avx") {
            // SAFETY: AVX is available; lengths are equal.
            return unsafe { x86::copy_avx::<NT>(src, dst) };
        }
        // SAFETY: SSE2 is baseline on x86_64; lengths are equal.
        unsafe { x86::copy_sse2::<NT>(src, dst) }
    }
    #[cfg(not(target_arch = "x86_64"))]
    for (d, s) in dst.iter_mut().zip(src) {
        // SAFETY: `d` is a valid, aligned, exclusive reference.
        unsafe { std::ptr::write_volatile(d, *s) }
    }
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
                            write_volatile(d.add(i).cast::<$vec>(), v);
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
    copy_fn!(copy_avx, "avx", 4, __m256d, _mm256_loadu_pd, _mm256_stream_pd);
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

/// A copy routine of the roofline.
type CopyFn = fn(&[f64], &mut [f64]);

/// Measures the copy roofline with `threads` threads, each copying its own pair of arrays of
/// `array_bytes` bytes (allocated and first-touched by that thread); best of `reps` repetitions, where
/// the slowest thread decides each repetition.
pub fn measure_roofline(threads: usize, array_bytes: usize, reps: usize) -> Roofline {
    let threads = threads.max(1);
    let len = array_bytes / 8;
    let barrier = Barrier::new(threads);
    let copies: [CopyFn; 2] = [copy_plain, copy_nt];
    // Per thread, per repetition: seconds of the plain and the NT copy.
    let times: Vec<Vec<[f64; 2]>> = std::thread::scope(|s| {
        let work = || {
            let (src, mut dst) = alloc_copy_pair(len);
            let rep = |_| {
                copies.map(|copy| {
                    barrier.wait();
                    let t = Instant::now();
                    copy(src.as_slice(), dst.as_mut_slice());
                    t.elapsed().as_secs_f64()
                })
            };
            (0..reps.max(1)).map(rep).collect()
        };
        let handles: Vec<_> = (0..threads).map(|_| s.spawn(work)).collect();
        handles
            .into_iter()
            .map(|h| h.join().expect("roofline thread panicked"))
            .collect()
    });
    let best = |k: usize| {
        (0..reps.max(1))
            .map(|r| times.iter().map(|t| t[r][k]).fold(0.0, f64::max))
            .fold(f64::INFINITY, f64::min)
    };
    let elems = (len * threads) as f64;
    Roofline {
        threads,
        copy_gbs: 24.0 * elems / best(0) / 1e9,
        copy_nt_gbs: if HAS_NT { 16.0 * elems / best(1) / 1e9 } else { f64::NAN },
        array_bytes: len * 8,
    }
}

/// Worker threads that each own one `size`³ block (a source/destination field pair), kept alive between
/// timed batches so allocation and first touch are never timed. See [`with_fused_workers`].
pub struct FusedWorkers {
    barrier: Barrier,
    steps: AtomicUsize,
    stop: AtomicBool,
    slowest: AtomicU64,
}

impl FusedWorkers {
    /// Runs `steps` fused stream-collide steps on every worker, all released together by a barrier, and
    /// returns the slowest worker's seconds.
    pub fn time(&self, steps: usize) -> f64 {
        self.slowest.store(0, Ordering::SeqCst);
        self.steps.store(steps, Ordering::SeqCst);
        self.barrier.wait();
        self.barrier.wait();
        f64::from_bits(self.slowest.load(Ordering::SeqCst))
    }
}

/// Stops the workers when the driver returns or unwinds.
struct StopGuard<'a>(&'a FusedWorkers);

impl Drop for StopGuard<'_> {
    fn drop(&mut self) {
        self.0.stop.store(true, Ordering::SeqCst);
        self.0.barrier.wait();
    }
}

/// Starts `threads` workers, each allocating and first-touching its own periodic fluid block of `size`³
/// cells (precision `T`) and running 2 warm-up steps, then calls `driver` with the handle that times
/// batches of steps. The ghost layer is not refreshed: this is the fused kernel alone.
pub fn with_fused_workers<T: Real, R>(size: usize, threads: usize, driver: impl FnOnce(&FusedWorkers) -> R) -> R {
    let threads = threads.max(1);
    let size = size.max(1);
    let w = FusedWorkers {
        barrier: Barrier::new(threads + 1),
        steps: AtomicUsize::new(0),
        stop: AtomicBool::new(false),
        slowest: AtomicU64::new(0),
    };
    let params = TrtParams {
        tau: 0.6,
        magic: 3.0 / 16.0,
        force: [0.0; 3],
    };
    let worker = || {
        let layout = Layout::new::<T>([size; 3]);
        let segs = full_segments(&layout);
        let mut a = PdfField::<T>::new(layout, 0);
        let mut b = PdfField::<T>::new(layout, PAIR_SKEW_BYTES);
        a.data_mut().fill(T::ZERO);
        b.data_mut().fill(T::ZERO);
        let mut step = |steps: usize| {
            for _ in 0..steps {
                black_box(stream_collide(&a, &mut b, &segs, &params));
                std::mem::swap(&mut a, &mut b);
            }
        };
        step(2);
        loop {
            w.barrier.wait();
            if w.stop.load(Ordering::SeqCst) {
                break;
            }
            let t = Instant::now();
            step(w.steps.load(Ordering::SeqCst));
            // Positive f64 order like their bits, so fetch_max keeps the slowest worker's time.
            w.slowest
                .fetch_max(t.elapsed().as_secs_f64().to_bits(), Ordering::SeqCst);
            w.barrier.wait();
        }
    };
    std::thread::scope(|s| {
        for _ in 0..threads {
            s.spawn(worker);
        }
        let guard = StopGuard(&w);
        // An empty batch waits until every worker has allocated its block and run the warm-up steps.
        w.time(0);
        driver(guard.0)
    })
}

/// Seconds for `steps` fused stream-collide steps on one `size`³ block per thread, `threads` threads
/// started together (slowest thread; allocation, first touch and 2 warm-up steps excluded).
pub fn run_fused<T: Real>(size: usize, steps: usize, threads: usize) -> f64 {
    with_fused_workers::<T, _>(size, threads, |w| w.time(steps))
}

/// Measures one kernel row of precision `T` with the thread count of `roofline`, about `seconds` timed.
fn kernel_row<T: Real>(size: usize, roofline: &Roofline, seconds: f64) -> KernelBenchRow {
    // One step to estimate the step time, then the best of 3 repetitions of about `seconds / 3` each.
    let (steps, secs) = with_fused_workers::<T, _>(size, roofline.threads, |w| {
        let steps = ((seconds / 3.0 / w.time(1)).round() as usize).clamp(1, 1 << 20);
        (steps, (0..3).map(|_| w.time(steps)).fold(f64::INFINITY, f64::min))
    });
    let mlups = (roofline.threads * size.max(1).pow(3) * steps) as f64 / secs / 1e6;
    let (wa, nwa) = bytes_per_cell::<T>();
    let roofline_plain_mlups = roofline.copy_gbs * 1e3 / wa;
    let roofline_nt_mlups = roofline.copy_nt_gbs * 1e3 / nwa;
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
    rows.extend(rooflines.iter().map(|r| kernel_row::<f32>(opts.size, r, seconds)));
    KernelBenchReport {
        size: opts.size.max(1),
        rooflines,
        rows,
    }
}

/// CPU model name from /proc/cpuinfo.
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

/// `v` with `digits` decimals, or "n/a" when not finite.
fn num(v: f64, digits: usize) -> String {
    if v.is_finite() {
        format!("{v:.digits$}")
    } else {
        "n/a".to_string()
    }
}

/// One markdown table row from its cells.
fn table_row(cells: &[String]) -> String {
    format!("| {} |\n", cells.join(" | "))
}

impl KernelBenchReport {
    /// Markdown table as printed by `blockflow bench kernel`.
    pub fn to_markdown(&self) -> String {
        let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
        let mut s = format!(
            "Machine: {}, {cores} cores, L3 {} MiB\n\n",
            cpu_model(),
            l3_bytes() >> 20
        );
        if let Some(r) = self.rooflines.first() {
            let mib = r.array_bytes >> 20;
            s += &format!("Roofline: copy of f64 arrays of {mib} MiB, one pair per thread, best of several runs\n\n");
        }
        s += "| threads | copy GB/s (plain, 24 B/elem) | copy GB/s (NT, 16 B/elem) ";
        s += "| roofline f64 MLUPS (456 B) | roofline f64 MLUPS NT (304 B) |\n|---:|---:|---:|---:|---:|\n";
        let (wa, nwa) = bytes_per_cell::<f64>();
        for r in &self.rooflines {
            let (plain, nt) = (r.copy_gbs, r.copy_nt_gbs);
            s += &table_row(&[
                r.threads.to_string(),
                num(plain, 1),
                num(nt, 1),
                num(plain * 1e3 / wa, 1),
                num(nt * 1e3 / nwa, 1),
            ]);
        }
        s += &format!(
            "\nFused stream-collide kernel (TRT), one periodic {}^3 fluid block per thread\n\n",
            self.size
        );
        s += "| precision | threads | MLUPS | % of write-allocate roofline (456 B) | % of NT roofline (304 B) |\n";
        s += "|---|---:|---:|---:|---:|\n";
        for r in &self.rows {
            let (wa, nt) = (num(r.pct_write_allocate, 0), num(r.pct_no_write_allocate, 0));
            s += &table_row(&[r.precision.to_string(), r.threads.to_string(), num(r.mlups, 1), wa, nt]);
        }
        s += "\n- The fused kernel alone: ghost exchange excluded (the ghost layer is not refreshed). ";
        s += "f32 rows use 228 B / 152 B per cell.\n";
        s += "- Reference: waLBerla fused TRT measured on this machine: 34.7 MLUPS (1 core), 66 (2 cores); ";
        s += "lbmpy AVX2: ~36 f64 / ~69 f32 at 1 thread.\n";
        s += "- Target: f64 at 1 thread >= 75 % of the write-allocate roofline";
        match self.rows.iter().find(|r| r.precision == "f64" && r.threads == 1) {
            Some(r) if r.pct_write_allocate.is_finite() => {
                let verdict = if r.pct_write_allocate >= 75.0 { "met" } else { "not met" };
                s += &format!(": {} % ({verdict}).\n", num(r.pct_write_allocate, 1));
            }
            _ => s += ".\n",
        }
        s
    }
}
