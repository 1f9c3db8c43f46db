//! `blockflow bench kernel`: the stream-collide kernels (pull and in-place AA) against memory-bandwidth
//! rooflines.
//!
//! The rooflines come from f64 arrays far larger than L3: a copy with ordinary stores (each element costs
//! a read, a write-allocate read and a write: 3 × 8 B), a copy with non-temporal stores (2 × 8 B) and an
//! in-place update (read and write-back, 2 × 8 B). A D3Q19 cell update moves 19 reads and 19 writes: the
//! pull kernel writes another field (plus 19 write-allocate reads: 456 B per f64 cell), the AA kernel
//! writes back the lines it read (304 B). Each kernel row runs one periodic fluid block per thread and
//! compares the MLUPS with its pattern's roofline; AA rows time the steps after even and odd step
//! counts separately (the odd step reads and writes shifted, unaligned addresses).

use blockflow_kernels::field::AlignedBuf;
use blockflow_kernels::sweep::{aa_step, full_segments, stream_collide};
use blockflow_kernels::{Layout, Pattern, PdfField, Real, TrtParams};
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
    /// Streaming pattern of the kernel.
    pub pattern: Pattern,
    /// Whether the fields were advised to transparent huge pages.
    pub huge_pages: bool,
    /// Worker threads, one block each.
    pub threads: usize,
    /// Aggregate million lattice updates per second over even and odd steps.
    pub mlups: f64,
    /// MLUPS of the steps that start after an even number of steps (for AA: the local, aligned step).
    pub mlups_even: f64,
    /// MLUPS of the steps that start after an odd number of steps (for AA: the shifted step).
    pub mlups_odd: f64,
    /// The pattern's roofline, MLUPS: pull at 456 B per cell (f64; 228 B f32) on the plain-copy bandwidth,
    /// AA at 304 B (152 B) on the in-place update bandwidth.
    pub roofline_mlups: f64,
    /// `mlups` as a percentage of `roofline_mlups`.
    pub pct_roofline: f64,
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
    /// Aggregate bandwidth of an in-place update (each element read and written back, 2 × 8 B): the
    /// traffic pattern of an in-place (AA) kernel.
    pub update_gbs: f64,
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
    /// Kernel rows: per precision, per thread count, pull then AA (plain pages, then huge pages).
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

/// Updates every element of `a` in place (read, then write back the value doubled) with volatile loads
/// and stores the compiler keeps: one read and one write-back per element, no write-allocate (the line
/// was just read), the traffic pattern of an in-place kernel.
pub fn update_in_place(a: &mut [f64]) {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx") {
        // SAFETY: AVX is available.
        return unsafe { x86::update_avx(a) };
    }
    let p = a.as_mut_ptr();
    for i in 0..a.len() {
        // SAFETY: i < len; exclusive access through &mut.
        unsafe {
            let v = std::ptr::read_volatile(p.add(i));
            std::ptr::write_volatile(p.add(i), v + v);
        }
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

    /// In-place update with 32-byte volatile loads and stores (see [`super::update_in_place`]).
    ///
    /// # Safety
    /// The CPU supports AVX.
    #[target_feature(enable = "avx")]
    pub unsafe fn update_avx(a: &mut [f64]) {
        let n = a.len();
        let p = a.as_mut_ptr();
        let head = (p.align_offset(32)).min(n);
        let end = head + (n - head) / 4 * 4;
        let scalar = |i: usize| unsafe {
            let v = std::ptr::read_volatile(p.add(i));
            write_volatile(p.add(i), v + v);
        };
        (0..head).for_each(scalar);
        let mut i = head;
        while i < end {
            unsafe {
                let v = std::ptr::read_volatile(p.add(i).cast::<__m256d>());
                write_volatile(p.add(i).cast::<__m256d>(), _mm256_add_pd(v, v));
            }
            i += 4;
        }
        (end..n).for_each(scalar);
    }
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
    // Per thread, per repetition: seconds of the plain copy, the NT copy and the in-place update.
    let times: Vec<Vec<[f64; 3]>> = std::thread::scope(|s| {
        let work = || {
            let (mut src, mut dst) = alloc_copy_pair(len);
            let rep = |_| {
                let [plain, nt] = copies.map(|copy| {
                    barrier.wait();
                    let t = Instant::now();
                    copy(src.as_slice(), dst.as_mut_slice());
                    t.elapsed().as_secs_f64()
                });
                barrier.wait();
                let t = Instant::now();
                update_in_place(src.as_mut_slice());
                [plain, nt, t.elapsed().as_secs_f64()]
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
        update_gbs: 16.0 * elems / best(2) / 1e9,
        array_bytes: len * 8,
    }
}

/// Worker threads that each own one `size`³ block (two fields under pull, one under AA), kept alive
/// between timed batches so allocation and first touch are never timed. See [`with_kernel_workers`].
pub struct KernelWorkers {
    barrier: Barrier,
    steps: AtomicUsize,
    stop: AtomicBool,
    /// Slowest worker's seconds: all steps, steps after an even, after an odd number of steps.
    slowest: [AtomicU64; 3],
}

impl KernelWorkers {
    /// Runs `steps` steps on every worker, all released together by a barrier, and returns the slowest
    /// worker's seconds.
    pub fn time(&self, steps: usize) -> f64 {
        self.time_split(steps)[0]
    }

    /// As [`KernelWorkers::time`], with the slowest worker's seconds of all steps, of the steps after an
    /// even number of steps and of those after an odd number.
    pub fn time_split(&self, steps: usize) -> [f64; 3] {
        for t in &self.slowest {
            t.store(0, Ordering::SeqCst);
        }
        self.steps.store(steps, Ordering::SeqCst);
        self.barrier.wait();
        self.barrier.wait();
        std::array::from_fn(|k| f64::from_bits(self.slowest[k].load(Ordering::SeqCst)))
    }
}

/// Stops the workers when the driver returns or unwinds.
struct StopGuard<'a>(&'a KernelWorkers);

impl Drop for StopGuard<'_> {
    fn drop(&mut self) {
        self.0.stop.store(true, Ordering::SeqCst);
        self.0.barrier.wait();
    }
}

/// Which kernel [`with_kernel_workers`] runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct KernelSetup {
    /// Streaming pattern.
    pub pattern: Pattern,
    /// Advise the fields to transparent huge pages before first touch.
    pub huge_pages: bool,
}

/// Starts `threads` workers, each allocating and first-touching its own periodic fluid block of `size`³
/// cells (precision `T`) and running 2 warm-up steps, then calls `driver` with the handle that times
/// batches of steps. The ghost layer is not refreshed: this is the stream-collide kernel alone.
pub fn with_kernel_workers<T: Real, R>(
    size: usize,
    threads: usize,
    setup: KernelSetup,
    driver: impl FnOnce(&KernelWorkers) -> R,
) -> R {
    let threads = threads.max(1);
    let size = size.max(1);
    let w = KernelWorkers {
        barrier: Barrier::new(threads + 1),
        steps: AtomicUsize::new(0),
        stop: AtomicBool::new(false),
        slowest: std::array::from_fn(|_| AtomicU64::new(0)),
    };
    let params = TrtParams {
        tau: 0.6,
        magic: 3.0 / 16.0,
        force: [0.0; 3],
    };
    let worker = || {
        let layout = Layout::new::<T>([size; 3]);
        let segs = full_segments(&layout);
        let mut fields: Vec<PdfField<T>> = (0..setup.pattern.fields())
            .map(|k| PdfField::<T>::new(layout, if k == 0 { 0 } else { PAIR_SKEW_BYTES }))
            .collect();
        for f in &mut fields {
            if setup.huge_pages {
                f.advise_huge_pages();
            }
            f.data_mut().fill(T::ZERO);
        }
        let mut done = 0u64;
        // Seconds of steps after an even and after an odd number of steps.
        let mut step = |steps: usize| {
            let mut t = [0.0; 2];
            for _ in 0..steps {
                let start = Instant::now();
                match setup.pattern {
                    Pattern::Pull => {
                        let (a, b) = fields.split_at_mut(1);
                        let (src, dst) = if done.is_multiple_of(2) {
                            (&a[0], &mut b[0])
                        } else {
                            (&b[0], &mut a[0])
                        };
                        black_box(stream_collide(src, dst, &segs, &params));
                    }
                    Pattern::Aa => {
                        black_box(aa_step(&mut fields[0], done, &segs, &params));
                    }
                }
                t[(done % 2) as usize] += start.elapsed().as_secs_f64();
                done += 1;
            }
            t
        };
        step(2);
        loop {
            w.barrier.wait();
            if w.stop.load(Ordering::SeqCst) {
                break;
            }
            let [even, odd] = step(w.steps.load(Ordering::SeqCst));
            // Positive f64 order like their bits, so fetch_max keeps the slowest worker's time.
            for (k, v) in [even + odd, even, odd].into_iter().enumerate() {
                w.slowest[k].fetch_max(v.to_bits(), Ordering::SeqCst);
            }
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

/// Seconds for `steps` steps of the kernel `setup` on one `size`³ block per thread, `threads` threads
/// started together (slowest thread; allocation, first touch and 2 warm-up steps excluded).
pub fn run_kernel<T: Real>(size: usize, steps: usize, threads: usize, setup: KernelSetup) -> f64 {
    with_kernel_workers::<T, _>(size, threads, setup, |w| w.time(steps))
}

/// Measures one kernel row of precision `T` with the thread count of `roofline`, about `seconds` timed.
fn kernel_row<T: Real>(size: usize, roofline: &Roofline, setup: KernelSetup, seconds: f64) -> KernelBenchRow {
    // Two steps to estimate the step time, then the best of 3 repetitions of about `seconds / 3` each
    // (an even number of steps, so even and odd steps are as many).
    let (steps, secs) = with_kernel_workers::<T, _>(size, roofline.threads, setup, |w| {
        let per_step = w.time(2) / 2.0;
        let steps = (((seconds / 3.0 / per_step) / 2.0).round() as usize).clamp(1, 1 << 19) * 2;
        let best = (0..3)
            .map(|_| w.time_split(steps))
            .fold([f64::INFINITY; 3], |a, b| std::array::from_fn(|k| a[k].min(b[k])));
        (steps, best)
    });
    let cells = (roofline.threads * size.max(1).pow(3)) as f64;
    let mlups = cells * steps as f64 / secs[0] / 1e6;
    let (wa, nwa) = bytes_per_cell::<T>();
    let roofline_mlups = match setup.pattern {
        Pattern::Pull => roofline.copy_gbs * 1e3 / wa,
        Pattern::Aa => roofline.update_gbs * 1e3 / nwa,
    };
    KernelBenchRow {
        precision: T::NAME,
        pattern: setup.pattern,
        huge_pages: setup.huge_pages,
        threads: roofline.threads,
        mlups,
        mlups_even: cells * (steps / 2) as f64 / secs[1] / 1e6,
        mlups_odd: cells * (steps / 2) as f64 / secs[2] / 1e6,
        roofline_mlups,
        pct_roofline: mlups / roofline_mlups * 100.0,
    }
}

/// The kernels measured per precision and thread count: pull, AA, AA on huge pages.
pub const SETUPS: [KernelSetup; 3] = [
    KernelSetup {
        pattern: Pattern::Pull,
        huge_pages: false,
    },
    KernelSetup {
        pattern: Pattern::Aa,
        huge_pages: false,
    },
    KernelSetup {
        pattern: Pattern::Aa,
        huge_pages: true,
    },
];

/// Bytes of each roofline array: four times L3, and at least 64 MiB unless `quick`.
fn roofline_array_bytes(quick: bool) -> usize {
    let four_l3 = 4 * l3_bytes();
    if quick {
        four_l3
    } else {
        four_l3.max(64 << 20)
    }
}

/// Bytes the benchmark holds at its peak: per thread of its largest thread count, the roofline's two
/// arrays or one f64 block's fields (two under pull), whichever is larger, and the thread's stack.
pub fn memory_needed(opts: &KernelBenchOptions) -> u128 {
    let threads = opts.threads.iter().copied().max().unwrap_or(1) as u128;
    let arrays = 2 * roofline_array_bytes(opts.quick) as u128;
    let fields = 2 * 8 * Layout::new::<f64>([opts.size; 3]).len() as u128;
    threads * (arrays.max(fields) + crate::app::run::resources::THREAD_BYTES)
}

/// Runs the benchmark: roofline for each thread count, then the kernels of [`SETUPS`] on one periodic fluid
/// block of size³ per thread (f64 and f32), and returns the table.
pub fn run(opts: &KernelBenchOptions) -> KernelBenchReport {
    let array_bytes = roofline_array_bytes(opts.quick);
    let (copy_reps, seconds) = if opts.quick { (5, 0.5) } else { (15, 2.5) };
    let rooflines: Vec<Roofline> = opts
        .threads
        .iter()
        .map(|&t| measure_roofline(t, array_bytes, copy_reps))
        .collect();
    let mut rows = Vec::new();
    for f32 in [false, true] {
        for r in &rooflines {
            for setup in SETUPS {
                rows.push(if f32 {
                    kernel_row::<f32>(opts.size, r, setup, seconds)
                } else {
                    kernel_row::<f64>(opts.size, r, setup, seconds)
                });
            }
        }
    }
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
        s +=
            "| threads | copy GB/s (plain, 24 B/elem) | copy GB/s (NT, 16 B/elem) | update GB/s (in place, 16 B/elem) ";
        s += "| pull roofline f64 MLUPS (456 B) | AA roofline f64 MLUPS (304 B) |\n|---:|---:|---:|---:|---:|---:|\n";
        let (wa, nwa) = bytes_per_cell::<f64>();
        for r in &self.rooflines {
            s += &table_row(&[
                r.threads.to_string(),
                num(r.copy_gbs, 1),
                num(r.copy_nt_gbs, 1),
                num(r.update_gbs, 1),
                num(r.copy_gbs * 1e3 / wa, 1),
                num(r.update_gbs * 1e3 / nwa, 1),
            ]);
        }
        s += &format!(
            "\nStream-collide kernels (TRT), one periodic {}^3 fluid block per thread; even/odd: steps after an even / odd number of steps\n\n",
            self.size
        );
        s += "| precision | pattern | pages | threads | MLUPS | even | odd | roofline MLUPS | % of roofline | vs pull |\n";
        s += "|---|---|---|---:|---:|---:|---:|---:|---:|---:|\n";
        for r in &self.rows {
            let pull = self
                .rows
                .iter()
                .find(|p| p.precision == r.precision && p.threads == r.threads && p.pattern == Pattern::Pull)
                .map_or(f64::NAN, |p| r.mlups / p.mlups);
            s += &table_row(&[
                r.precision.to_string(),
                pattern_name(r.pattern).to_string(),
                if r.huge_pages { "huge" } else { "4 KiB" }.to_string(),
                r.threads.to_string(),
                num(r.mlups, 1),
                num(r.mlups_even, 1),
                num(r.mlups_odd, 1),
                num(r.roofline_mlups, 1),
                num(r.pct_roofline, 0),
                format!("{}x", num(pull, 2)),
            ]);
        }
        s += "\n- The kernel alone: ghost exchange excluded (the ghost layer is not refreshed). Pull moves 456 B ";
        s += "per f64 cell update (read, write-allocate, write; roofline from the plain copy), AA 304 B (read and ";
        s += "write-back of the same lines; roofline from the in-place update); f32 half of each.\n";
        s += "- Peers measured on a 2-core Zen 3 machine (f64, 1 / 2 threads): waLBerla fused TRT 34.7 / 66 MLUPS; ";
        s += "lbmpy AVX2 36 / 48 (f32 69 / 95).\n";
        s
    }
}

/// The config word of a pattern.
pub fn pattern_name(p: Pattern) -> &'static str {
    match p {
        Pattern::Pull => "pull",
        Pattern::Aa => "aa",
    }
}
