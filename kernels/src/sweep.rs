//! Sweeps over a block: pull streaming (eq. 4), in-place TRT collision (eq. 2) and the fused
//! stream-collide kernel. All three walk a list of [`Segment`]s (runs of consecutive fluid cells along x),
//! so a block with obstacles computes only its fluid cells while an obstacle-free block gets one segment
//! per row. Vector lanes are processed as `[T; L]` arrays inside an AVX2 function selected at run time;
//! the last len mod L cells of a segment take one more vector step whose other lanes are blended back
//! unchanged. Every lane computes what the one-lane code computes, so results do not depend on where a
//! segment starts (bitwise equal for any block decomposition) and the fused kernel is bitwise equal to
//! stream followed by collide.

use crate::d3q19::{C, OPP, Q};
use crate::field::{Layout, PdfField};
use crate::prefetch::prefetch;
use crate::real::Real;
use crate::simd::Vector;
use crate::trt::{trt_cell, LaneStats, TrtParams, VConsts};

/// How many runs ahead a sweep asks for the lines of a run's populations. From memory, the hardware
/// prefetcher alone leaves a block's sweep latency-bound wherever its runs are short or few per plane
/// (rows a wall or the spheres cut short, a wall-cut block's few rows per plane): each run starts Q load
/// streams the prefetcher has yet to pick up. Asked for a few runs ahead, those lines arrive in time.
const PREFETCH_RUNS: usize = 4;

/// Runs of this many cache lines or more stream long enough for the hardware prefetcher alone (the rows of
/// big blocks, where the hint only costs instructions).
const PREFETCH_BELOW_LINES: usize = 8;

/// A run of `len` consecutive fluid cells along x starting at element index `start`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Segment {
    /// Element index of the first cell.
    pub start: usize,
    /// Number of cells.
    pub len: usize,
}

/// What a collision sweep saw: the largest |u|² and whether any density or velocity was non-finite.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SweepStats {
    /// Largest u·u over the swept cells.
    pub max_u2: f64,
    /// True when a NaN or infinity was met.
    pub nonfinite: bool,
}

impl SweepStats {
    /// Combines the statistics of two sweeps.
    pub fn merge(self, o: SweepStats) -> SweepStats {
        SweepStats {
            max_u2: self.max_u2.max(o.max_u2),
            nonfinite: self.nonfinite || o.nonfinite,
        }
    }
}

fn finish<V: Vector>(a: LaneStats<V>) -> SweepStats {
    SweepStats {
        max_u2: a.max_u2.hmax(),
        nonfinite: a.poison.any_nonzero(),
    }
}

fn offsets(layout: &Layout) -> [isize; Q] {
    std::array::from_fn(|q| layout.offset(C[q]))
}

/// Asserts that every segment lies in the block interior. That also keeps a tail step's L − 1 elements
/// past a run inside the field: after the last interior cell come the ghost row and plane (and, past the
/// ghost corner, the direction stride's page rounding and skew), which hold more than the largest
/// offset plus L − 1 elements.
fn check_segments(layout: &Layout, segs: &[Segment]) {
    let lo = layout.idx(1, 1, 1);
    let hi = layout.idx(layout.size[0], layout.size[1], layout.size[2]);
    for s in segs {
        assert!(
            s.start >= lo && s.start + s.len <= hi + 1,
            "segment outside the block interior"
        );
    }
}

/// The collision sweep over vector type V (the last len mod L cells of a run in one step whose other lanes
/// are left as they were): cell i's population
/// q is loaded from `lp[q] + i` and its post-collision value stored to `sp[q] + i`. The kernels differ only
/// in these pointers (offsets folded in): fused pull `lp[q] = src_q − off_q`, `sp[q] = dst_q`; in-place
/// collision `lp[q] = sp[q] = f_q`; AA after an even number of steps `lp[q] = f_q`, `sp[q] = f_q̄` (x, q̄);
/// AA after an odd number `lp[q] = f_q̄ − off_q` (x − c_q, q̄), `sp[q] = f_q + off_q` (x + c_q, q). In the
/// in-place cases each stored element is one the same cell loaded before (the pair (q, q̄) is reloaded just
/// before both are stored), so lanes and cells never conflict.
///
/// # Safety
/// Every `lp[q] + i` and `sp[q] + i` for i in a segment, and for the L − 1 elements after a segment, is an
/// element of the field(s), which no other thread accesses during the sweep; a store never hits an element
/// another cell of the sweep loads. (A tail step loads and rewrites the elements past its run with the
/// values they hold at that moment.)
#[inline(always)]
unsafe fn sweep_impl<V: Vector, const FORCE: bool, const FMA: bool>(
    lp: &[*const V::S; Q],
    sp: &[*mut V::S; Q],
    segs: &[Segment],
    p: &TrtParams,
) -> SweepStats
where
    V::S: Vector<S = V::S>,
{
    let kc = p.consts::<V::S>();
    let k = VConsts::<V>::new(&kc);
    let mut st = LaneStats::<V>::new();
    // Elements of one 64-byte cache line.
    let line = (64 / std::mem::size_of::<V::S>()).max(1);
    for (j, s) in segs.iter().enumerate() {
        match segs.get(j + PREFETCH_RUNS) {
            Some(ahead) if ahead.len < PREFETCH_BELOW_LINES * line => prefetch_run(lp, ahead, line, V::LANES),
            _ => {}
        }
        let mut i = s.start;
        let end = s.start + s.len;
        while i + V::LANES <= end {
            trt_cell::<V, FORCE, FMA>(|q| V::load(lp[q].add(i)), |q, v| v.store(sp[q].add(i)), &k, &mut st);
            i += V::LANES;
        }
        let rest = end - i;
        if rest > 0 {
            // The last len mod L cells in one more vector step: the other lanes load what follows the run
            // and write it back unchanged, and their statistics are dropped.
            let mut tail = LaneStats::<V>::new();
            trt_cell::<V, FORCE, FMA>(
                |q| V::load_first(lp[q].add(i), rest),
                |q, v| v.store_first(sp[q].add(i), rest),
                &k,
                &mut tail,
            );
            st.max_u2 = st.max_u2.max(tail.max_u2.keep_first(rest));
            st.poison = st.poison + tail.poison.keep_first(rest);
        }
    }
    finish(st)
}

/// Asks for every line of run `s` in the Q arrays a sweep loads from (`lp`), through the last element of
/// its last vector step (`lanes` wide: a tail step also reads the elements after the run); the stores go
/// to lines the loads of the same or a neighbouring row bring in.
///
/// # Safety
/// As for [`sweep_impl`]: `s` is one of its segments.
#[inline(always)]
unsafe fn prefetch_run<S>(lp: &[*const S; Q], s: &Segment, line: usize, lanes: usize) {
    let last = s.start + s.len.div_ceil(lanes) * lanes - 1;
    for p in lp {
        let mut i = s.start;
        while i < last {
            prefetch(p.add(i));
            i += line;
        }
        prefetch(p.add(last));
    }
}

/// # Safety
/// `src` and `dst` point to distinct fields of one layout; every segment lies in the interior.
#[inline(always)]
unsafe fn stream_impl<T: Real>(src: *const T, dst: *mut T, stride: usize, offs: &[isize; Q], segs: &[Segment]) {
    for (q, &off) in offs.iter().enumerate() {
        let sp = src.add(q * stride).offset(-off);
        let dp = dst.add(q * stride);
        for s in segs {
            std::ptr::copy_nonoverlapping(sp.add(s.start), dp.add(s.start), s.len);
        }
    }
}

/// Which collision sweep [`RawArgs`] runs.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Mode {
    /// Fused pull-stream and collide from `src` into `dst`.
    Fused,
    /// Collision in place on `dst`.
    Collide,
    /// AA step after an even number of steps, in place on `dst`.
    AaEven,
    /// AA step after an odd number of steps, in place on `dst`.
    AaOdd,
}

/// Arguments of a collision sweep with type-erased pointers, so one dispatcher serves both precisions
/// and every kernel.
struct RawArgs<'a> {
    src: *const u8,
    dst: *mut u8,
    stride: usize,
    offs: [isize; Q],
    segs: &'a [Segment],
    p: TrtParams,
    mode: Mode,
}

impl RawArgs<'_> {
    #[inline(always)]
    unsafe fn run<V: Vector, const F: bool, const FMA: bool>(&self) -> SweepStats
    where
        V::S: Vector<S = V::S>,
    {
        let (src, dst, stride, off) = (self.src as *const V::S, self.dst as *mut V::S, self.stride, &self.offs);
        let f = |q: usize| dst.add(q * stride);
        let (lp, sp): ([*const V::S; Q], [*mut V::S; Q]) = match self.mode {
            Mode::Fused => (
                std::array::from_fn(|q| src.add(q * stride).offset(-off[q])),
                std::array::from_fn(f),
            ),
            Mode::Collide => (std::array::from_fn(|q| f(q) as *const V::S), std::array::from_fn(f)),
            Mode::AaEven => (
                std::array::from_fn(|q| f(q) as *const V::S),
                std::array::from_fn(|q| f(OPP[q])),
            ),
            Mode::AaOdd => (
                std::array::from_fn(|q| f(OPP[q]).offset(-off[q]) as *const V::S),
                std::array::from_fn(|q| f(q).offset(off[q])),
            ),
        };
        sweep_impl::<V, F, FMA>(&lp, &sp, self.segs, &self.p)
    }
}

/// Runs a collision sweep with the best instruction set this CPU offers: AVX2 + FMA when detected at run
/// time (vector lanes and scalar remainders both use fused multiply-adds, so they agree bit for bit),
/// otherwise the scalar build for any target with separate multiplies and adds. A process always takes
/// the same path, so results are bitwise reproducible on a machine.
fn dispatch<T: Real>(args: RawArgs<'_>) -> SweepStats {
    let force = args.p.has_force();
    #[cfg(target_arch = "x86_64")]
    {
        use crate::simd::{F32x8, F64x4};
        #[target_feature(enable = "avx2,fma")]
        unsafe fn avx2<V: Vector, const F: bool>(a: &RawArgs<'_>) -> SweepStats
        where
            V::S: Vector<S = V::S>,
        {
            a.run::<V, F, true>()
        }
        if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma") {
            // SAFETY: the CPU supports AVX2; arguments were validated by the public wrapper.
            return unsafe {
                match (T::BYTES, force) {
                    (8, true) => avx2::<F64x4, true>(&args),
                    (8, false) => avx2::<F64x4, false>(&args),
                    (_, true) => avx2::<F32x8, true>(&args),
                    (_, false) => avx2::<F32x8, false>(&args),
                }
            };
        }
    }
    // SAFETY: arguments were validated by the public wrapper.
    unsafe {
        match (T::BYTES, force) {
            (8, true) => args.run::<f64, true, false>(),
            (8, false) => args.run::<f64, false, false>(),
            (_, true) => args.run::<f32, true, false>(),
            (_, false) => args.run::<f32, false, false>(),
        }
    }
}

/// Fused pull-stream and collide (eqs. 4 then 2) of the cells in `segs`: reads `src` (post-collision state
/// of the previous step, ghost layer filled, boundary values set) and writes the new post-collision state
/// of those cells into `dst`.
pub fn stream_collide<T: Real>(
    src: &PdfField<T>,
    dst: &mut PdfField<T>,
    segs: &[Segment],
    p: &TrtParams,
) -> SweepStats {
    assert_eq!(src.layout, dst.layout);
    check_segments(&src.layout, segs);
    dispatch::<T>(RawArgs {
        src: src.data().as_ptr() as *const u8,
        dst: dst.data_mut().as_mut_ptr() as *mut u8,
        stride: src.layout.stride,
        offs: offsets(&src.layout),
        segs,
        p: *p,
        mode: Mode::Fused,
    })
}

/// In-place TRT collision (eq. 2) of the cells in `segs`.
pub fn collide<T: Real>(f: &mut PdfField<T>, segs: &[Segment], p: &TrtParams) -> SweepStats {
    check_segments(&f.layout, segs);
    dispatch::<T>(RawArgs {
        src: std::ptr::null(),
        dst: f.data_mut().as_mut_ptr() as *mut u8,
        stride: f.layout.stride,
        offs: [0; Q],
        segs,
        p: *p,
        mode: Mode::Collide,
    })
}

/// One AA-pattern step (stream and collide, eqs. 4 and 2, in place) of the cells in `segs` on the state
/// after `steps` steps: reads the incoming populations where [`crate::field::Slots`] puts the state of
/// that parity and writes the new post-collision state where it puts the next parity's. Bitwise equal
/// to [`stream_collide`] on the same state. Segments must lie in the interior and the ghost layer must
/// hold the neighbours' and the walls' populations (exchange and boundary pass done).
pub fn aa_step<T: Real>(f: &mut PdfField<T>, steps: u64, segs: &[Segment], p: &TrtParams) -> SweepStats {
    check_segments(&f.layout, segs);
    dispatch::<T>(RawArgs {
        src: std::ptr::null(),
        stride: f.layout.stride,
        offs: offsets(&f.layout),
        dst: f.data_mut().as_mut_ptr() as *mut u8,
        segs,
        p: *p,
        mode: if steps.is_multiple_of(2) {
            Mode::AaEven
        } else {
            Mode::AaOdd
        },
    })
}

/// Pull streaming (eq. 4) of the cells in `segs`: dst_q(x) = src_q(x - c_q).
pub fn stream<T: Real>(src: &PdfField<T>, dst: &mut PdfField<T>, segs: &[Segment]) {
    assert_eq!(src.layout, dst.layout);
    check_segments(&src.layout, segs);
    let offs = offsets(&src.layout);
    // SAFETY: distinct fields (borrow rules), segments checked to lie in the interior, so x - c_q is a
    // real (interior or ghost) cell.
    unsafe {
        stream_impl(
            src.data().as_ptr(),
            dst.data_mut().as_mut_ptr(),
            src.layout.stride,
            &offs,
            segs,
        )
    }
}

/// One segment per interior row: the segment list of an obstacle-free block.
pub fn full_segments(layout: &Layout) -> Vec<Segment> {
    let [nx, ny, nz] = layout.size;
    let mut v = Vec::with_capacity(ny * nz);
    for z in 1..=nz {
        for y in 1..=ny {
            v.push(Segment {
                start: layout.idx(1, y, z),
                len: nx,
            });
        }
    }
    v
}

#[cfg(test)]
// Direction and axis indices name lattice vectors here, as in the equations.
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::*;
    use crate::trt::equilibrium;

    fn random_field<T: Real>(l: Layout, seed: u64) -> PdfField<T> {
        let mut f = PdfField::<T>::new(l, 0);
        let mut s = seed;
        for v in f.data_mut().iter_mut() {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            *v = T::from_f64(((s >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 0.01);
        }
        f
    }

    fn fused_equals_split<T: Real>() {
        let l = Layout::new::<T>([13, 5, 4]);
        let segs = full_segments(&l);
        for force in [[0.0; 3], [1e-5, 2e-5, -3e-5]] {
            let p = TrtParams {
                tau: 0.73,
                magic: 3.0 / 16.0,
                force,
            };
            let src = random_field::<T>(l, 7);
            let mut a = PdfField::<T>::new(l, 0);
            let mut b = PdfField::<T>::new(l, 0);
            let sa = stream_collide(&src, &mut a, &segs, &p);
            stream(&src, &mut b, &segs);
            let sb = collide(&mut b, &segs, &p);
            assert_eq!(sa, sb);
            for s in &segs {
                for i in s.start..s.start + s.len {
                    for q in 0..Q {
                        assert_eq!(a.get(q, i).bits(), b.get(q, i).bits());
                    }
                }
            }
        }
    }

    #[test]
    fn fused_is_bitwise_stream_then_collide() {
        fused_equals_split::<f64>();
        fused_equals_split::<f32>();
    }

    /// One AA step from a state of either parity equals one pull step from the same physical state, bit
    /// for bit, and lands where the next parity's map says.
    fn aa_equals_pull<T: Real>() {
        use crate::field::{Pattern, Slots};
        let l = Layout::new::<T>([13, 5, 4]);
        let segs = full_segments(&l);
        let [fx, fy, fz] = l.full();
        for force in [[0.0; 3], [1e-5, 2e-5, -3e-5]] {
            let p = TrtParams {
                tau: 0.73,
                magic: 3.0 / 16.0,
                force,
            };
            for steps in [0u64, 1] {
                let src = random_field::<T>(l, 11 + steps);
                let before = Slots::new(Pattern::Aa, &l, (steps % 2) as usize);
                let after = Slots::new(Pattern::Aa, &l, ((steps + 1) % 2) as usize);
                // The same physical state in AA layout: f*_q(y) of every cell whose slot lies in the grid.
                let mut aa = PdfField::<T>::new(l, 0);
                for z in 0..fz {
                    for y in 0..fy {
                        for x in 0..fx {
                            let i = l.idx(x, y, z);
                            for q in 0..Q {
                                let t = [x as i32 + C[q][0], y as i32 + C[q][1], z as i32 + C[q][2]];
                                let inside = (0..3).all(|a| t[a] >= 0 && t[a] < l.full()[a] as i32);
                                if inside || steps % 2 == 1 {
                                    let k = before.at(q, i);
                                    aa.data_mut()[k] = src.get(q, i);
                                }
                            }
                        }
                    }
                }
                let mut pull = PdfField::<T>::new(l, 0);
                let sp = stream_collide(&src, &mut pull, &segs, &p);
                let sa = aa_step(&mut aa, steps, &segs, &p);
                assert_eq!(sp, sa);
                for s in &segs {
                    for i in s.start..s.start + s.len {
                        let cell = aa.post_cell(&after, i);
                        for q in 0..Q {
                            assert_eq!(pull.get(q, i).bits(), cell[q].bits(), "steps {steps}, q {q}");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn aa_step_is_bitwise_pull_step() {
        aa_equals_pull::<f64>();
        aa_equals_pull::<f32>();
    }

    #[test]
    fn segment_split_does_not_change_bits() {
        // vector lanes vs scalar remainder: split every row at odd positions
        let l = Layout::new::<f64>([11, 3, 3]);
        let p = TrtParams {
            tau: 0.6,
            magic: 0.25,
            force: [1e-5, 0.0, 0.0],
        };
        let src = random_field::<f64>(l, 3);
        let whole = full_segments(&l);
        let mut pieces = Vec::new();
        for s in &whole {
            pieces.push(Segment { start: s.start, len: 3 });
            pieces.push(Segment {
                start: s.start + 3,
                len: s.len - 3,
            });
        }
        let mut a = PdfField::<f64>::new(l, 0);
        let mut b = PdfField::<f64>::new(l, 0);
        stream_collide(&src, &mut a, &whole, &p);
        stream_collide(&src, &mut b, &pieces, &p);
        assert!(a.data().iter().zip(b.data()).all(|(x, y)| x.to_bits() == y.to_bits()));
    }

    /// Every run length from 1 to 2L + 1 at every start within a vector: the sweep this CPU dispatches
    /// (a vector tail step where AVX2 is found) writes the same bits as the one-lane path with the same
    /// fused multiply-adds, with the same statistics, and no element outside the runs changes.
    fn tails_equal_one_lane<T: Real>() {
        #[cfg(target_arch = "x86_64")]
        let fma = std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma");
        #[cfg(not(target_arch = "x86_64"))]
        let fma = false;
        let lanes = T::LANES;
        let l = Layout::new::<T>([3 * lanes + 4, 3, 3]);
        let p = TrtParams {
            tau: 0.7,
            magic: 3.0 / 16.0,
            force: [1e-5, -2e-5, 3e-5],
        };
        for mode in [Mode::Fused, Mode::Collide, Mode::AaEven, Mode::AaOdd] {
            for len in 1..=2 * lanes + 1 {
                for first in 1..=lanes {
                    let segs: Vec<Segment> = (1..=3)
                        .flat_map(|z| (1..=3).map(move |y| (y, z)))
                        .map(|(y, z)| Segment {
                            start: l.idx(first, y, z),
                            len,
                        })
                        .collect();
                    let src = random_field::<T>(l, 5 + len as u64);
                    let mut a = random_field::<T>(l, 9 + first as u64);
                    let mut b = random_field::<T>(l, 9 + first as u64);
                    let args = |dst: &mut PdfField<T>| RawArgs {
                        src: src.data().as_ptr() as *const u8,
                        dst: dst.data_mut().as_mut_ptr() as *mut u8,
                        stride: l.stride,
                        offs: offsets(&l),
                        segs: &segs,
                        p,
                        mode,
                    };
                    let sa = dispatch::<T>(args(&mut a));
                    // SAFETY: the same arguments the dispatcher was given; one lane needs no CPU feature.
                    let sb = unsafe {
                        match (T::BYTES, fma) {
                            (8, true) => args(&mut b).run::<f64, true, true>(),
                            (8, false) => args(&mut b).run::<f64, true, false>(),
                            (_, true) => args(&mut b).run::<f32, true, true>(),
                            (_, false) => args(&mut b).run::<f32, true, false>(),
                        }
                    };
                    assert_eq!(sa, sb, "len {len}, first {first}");
                    let same = a.data().iter().zip(b.data()).all(|(x, y)| x.bits() == y.bits());
                    assert!(same, "len {len}, first {first}");
                }
            }
        }
    }

    #[test]
    fn vector_tails_equal_the_one_lane_path() {
        tails_equal_one_lane::<f64>();
        tails_equal_one_lane::<f32>();
    }

    #[test]
    fn uniform_equilibrium_is_stationary_and_stats() {
        let l = Layout::new::<f64>([8, 4, 4]);
        let feq = equilibrium(0.0, [0.1, 0.0, 0.0]);
        let mut src = PdfField::<f64>::new(l, 0);
        for z in 0..6 {
            for y in 0..6 {
                for x in 0..10 {
                    src.set_cell(l.idx(x, y, z), &feq);
                }
            }
        }
        let mut dst = PdfField::<f64>::new(l, 0);
        let p = TrtParams {
            tau: 1.0,
            magic: 3.0 / 16.0,
            force: [0.0; 3],
        };
        let st = stream_collide(&src, &mut dst, &full_segments(&l), &p);
        assert!((st.max_u2 - 0.01).abs() < 1e-15);
        assert!(!st.nonfinite);
        let i = l.idx(3, 2, 2);
        for q in 0..Q {
            assert!((dst.get(q, i) - feq[q]).abs() < 1e-17);
        }
        src.set(5, l.idx(3, 2, 1), f64::NAN);
        let st = stream_collide(&src, &mut dst, &full_segments(&l), &p);
        assert!(st.nonfinite);
    }
}
