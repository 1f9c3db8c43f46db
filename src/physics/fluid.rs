//! The per-block stages of one fluid time step (DESIGN.md, "One time step as a task graph"): ghost
//! exchange, boundary, stream + collide. Each is a function of one block (and, for the exchange, the
//! sending block's data), so the scheduler can run them as tasks.
//!
//! State convention: between steps a block holds *post-collision* PDFs, each population f*_q(x) at the
//! element its streaming pattern and the step's parity name ([`Block::slots`]). A step is exchange (fill
//! ghost cells' populations from the neighbours) → boundary (write bounce-back values for the wall cells)
//! → stream + collide (pull: into the other field; AA: in place). This is Algorithm 1's collide →
//! communicate → boundary → stream with the cycle cut after the collision. Every stage below reads and
//! writes populations through the slot map only, so pull and AA do the same arithmetic on the same
//! physical state.

use crate::config::KernelChoice;
use crate::physics::block::{ghost_ranges, source_ranges, Block, GhostRecv};
use blockflow_kernels::d3q19::Q;
use blockflow_kernels::sweep::{self, SweepStats};
use blockflow_kernels::{Pattern, Real, TrtParams};

/// Packs the PDFs the receiver's ghost region at offset `off` needs from field `p` of `sender`
/// (directions `dirs`, interior layer next to the shared face/edge) into `buf`, row by row: the message
/// that crosses processes (and that an MPI backend would send).
pub fn pack<T: Real>(sender: &Block<T>, p: usize, off: [i32; 3], dirs: &[usize], buf: &mut Vec<T>) {
    buf.clear();
    let l = &sender.layout;
    let f = sender.field(p).raw();
    let sl = sender.slots(p);
    let [rx, ry, rz] = source_ranges(l, off);
    let n = rx.end() - rx.start() + 1;
    for &q in dirs {
        for z in rz.clone() {
            for y in ry.clone() {
                let i = sl.at(q, l.idx(*rx.start(), y, z));
                // SAFETY: populations of the sender's interior cells; no task writes them concurrently
                // (graph).
                unsafe {
                    if n == 1 {
                        buf.push(*f.add(i)); // x faces: one strided element per row, no memcpy call
                    } else {
                        buf.extend_from_slice(std::slice::from_raw_parts(f.add(i), n));
                    }
                }
            }
        }
    }
}

/// Unpacks a message from [`pack`] into the ghost region at offset `off` of field `p` of `receiver`.
pub fn unpack<T: Real>(receiver: &Block<T>, p: usize, off: [i32; 3], dirs: &[usize], buf: &[T]) {
    let l = receiver.layout;
    let f = receiver.field(p).raw();
    let sl = receiver.slots(p);
    let [rx, ry, rz] = ghost_ranges(&l, off);
    let n = rx.end() - rx.start() + 1;
    let mut k = 0;
    for &q in dirs {
        for z in rz.clone() {
            for y in ry.clone() {
                let i = sl.at(q, l.idx(*rx.start(), y, z));
                assert!(k + n <= buf.len(), "message shorter than the ghost region");
                // SAFETY: populations of the receiver's ghost cells, written only by this task (graph).
                unsafe { copy_run(buf.as_ptr().add(k), f.add(i), n) };
                k += n;
            }
        }
    }
    assert_eq!(k, buf.len(), "message size does not match the ghost region");
}

/// Appends the PDFs of [`pack`] as little-endian bytes (the exact bits) to `out`: the ghost message
/// that crosses ranks.
pub fn pack_bytes<T: Real>(sender: &Block<T>, p: usize, off: [i32; 3], dirs: &[usize], out: &mut Vec<u8>) {
    let l = &sender.layout;
    let f = sender.field(p).raw();
    let sl = sender.slots(p);
    let [rx, ry, rz] = source_ranges(l, off);
    out.reserve(region_values(l, off, dirs) * T::BYTES);
    for &q in dirs {
        for z in rz.clone() {
            for y in ry.clone() {
                let i = sl.at(q, l.idx(*rx.start(), y, z));
                let n = rx.end() - rx.start() + 1;
                // SAFETY: populations of the sender's interior cells; no task writes them concurrently
                // (graph).
                let row = unsafe { std::slice::from_raw_parts(f.add(i), n) };
                if cfg!(target_endian = "little") {
                    // SAFETY: the row's values as their bytes (little endian in memory already).
                    out.extend_from_slice(unsafe {
                        std::slice::from_raw_parts(row.as_ptr() as *const u8, n * T::BYTES)
                    });
                } else {
                    for v in row {
                        out.extend_from_slice(&v.bits().to_le_bytes()[..T::BYTES]);
                    }
                }
            }
        }
    }
}

/// Unpacks the bytes of [`pack_bytes`] into the ghost region at offset `off` of field `p` of `receiver`.
/// Panics if their length is not the region's.
pub fn unpack_bytes<T: Real>(receiver: &Block<T>, p: usize, off: [i32; 3], dirs: &[usize], bytes: &[u8]) {
    let l = receiver.layout;
    assert_eq!(
        bytes.len(),
        region_values(&l, off, dirs) * T::BYTES,
        "message size does not match the ghost region"
    );
    let f = receiver.field(p).raw();
    let sl = receiver.slots(p);
    let [rx, ry, rz] = ghost_ranges(&l, off);
    let n = rx.end() - rx.start() + 1;
    let mut rows = bytes.chunks_exact(n * T::BYTES);
    for &q in dirs {
        for z in rz.clone() {
            for y in ry.clone() {
                let i = sl.at(q, l.idx(*rx.start(), y, z));
                let row = rows.next().expect("length checked above");
                if cfg!(target_endian = "little") {
                    // SAFETY: populations of the receiver's ghost cells, written only by this task
                    // (graph); the bytes are the values' little-endian bits, copied whatever their
                    // alignment.
                    unsafe { std::ptr::copy_nonoverlapping(row.as_ptr(), f.add(i) as *mut u8, n * T::BYTES) };
                } else {
                    for (x, c) in row.chunks_exact(T::BYTES).enumerate() {
                        let mut b = [0u8; 8];
                        b[..T::BYTES].copy_from_slice(c);
                        // SAFETY: as above.
                        unsafe { *f.add(i + x) = T::from_bits(u64::from_le_bytes(b)) };
                    }
                }
            }
        }
    }
}

/// PDF values of the ghost region at offset `off` with directions `dirs`.
pub fn region_values(l: &blockflow_kernels::Layout, off: [i32; 3], dirs: &[usize]) -> usize {
    let cells: usize = (0..3).map(|a| if off[a] == 0 { l.size[a] } else { 1 }).product();
    cells * dirs.len()
}

/// Direct copy inside a process by the region's plan ([`GhostRecv::runs`]): the sender's interior cells
/// straight into the receiver's ghost cells that feed its fluid (field `p` of both; the two may be the
/// same block on a periodic axis: the regions are disjoint).
pub fn copy_ghost<T: Real>(sender: &Block<T>, receiver: &Block<T>, p: usize, g: &GhostRecv) {
    let src = sender.field(p).raw();
    let dst = receiver.field(p).raw();
    let (ss, ds) = (sender.slots(p), receiver.slots(p));
    for (k, &q) in g.directions.iter().enumerate() {
        let runs = &g.runs[g.run_starts[k] as usize..g.run_starts[k + 1] as usize];
        for r in runs {
            // SAFETY: the populations of interior source cells and of ghost destination cells never share
            // an element; the graph orders this copy after the sender's sweep and before anything else
            // touches these elements.
            unsafe {
                copy_run(
                    src.add(ss.at(q, r.src as usize)),
                    dst.add(ds.at(q, r.dst as usize)),
                    r.len as usize,
                )
            };
        }
    }
}

/// Direct copy of the whole ghost region at offset `off` (every cell, directions `dirs`), inside a
/// process: what [`copy_ghost`] does with the plan switched off (`run.no_skip`).
pub fn copy_ghost_region<T: Real>(sender: &Block<T>, receiver: &Block<T>, p: usize, off: [i32; 3], dirs: &[usize]) {
    let l = receiver.layout;
    let src = sender.field(p).raw();
    let dst = receiver.field(p).raw();
    let (ss, ds) = (sender.slots(p), receiver.slots(p));
    let [sx, sy, sz] = source_ranges(&l, off);
    let [gx, gy, gz] = ghost_ranges(&l, off);
    let n = sx.end() - sx.start() + 1;
    for &q in dirs {
        for (zs, zg) in sz.clone().zip(gz.clone()) {
            for (ys, yg) in sy.clone().zip(gy.clone()) {
                let i = ss.at(q, l.idx(*sx.start(), ys, zs));
                let j = ds.at(q, l.idx(*gx.start(), yg, zg));
                // SAFETY: as in `copy_ghost`.
                unsafe { copy_run(src.add(i), dst.add(j), n) };
            }
        }
    }
}

/// Copies a run of `n` values; a single value (the rows of an x face) is a plain load and store instead of
/// a `memcpy` call, which made x-face exchanges several times slower than y and z faces.
///
/// # Safety
/// Both ranges valid and non-overlapping.
#[inline(always)]
unsafe fn copy_run<T: Real>(src: *const T, dst: *mut T, n: usize) {
    if n == 1 {
        *dst = *src;
    } else {
        std::ptr::copy_nonoverlapping(src, dst, n);
    }
}

/// Boundary pass (eq. 6 with δ_q = 1/2) on the state of parity `p`: writes the bounce-back values of all
/// links, the wall cells' populations.
pub fn boundary<T: Real>(b: &Block<T>, p: usize) {
    let f = b.field(p);
    // SAFETY: writes wall cells' populations and reads fluid cells' populations of this block's state p;
    // the graph runs no conflicting task on them concurrently.
    unsafe { b.links.apply_raw(f.raw(), f.layout.len(), p) }
}

/// Stream (eq. 4) and collide (eq. 2) every fluid cell of the block from the state of parity `p` to the
/// next: under pull from field `p` into field `1 - p` (fused and split kernels give identical bits), under
/// AA in place (`kernel` does not apply: the AA step is fused).
///
/// # Safety
/// No other task may access this block's fields while this runs, except reading the state of parity `p`
/// under pull (the graph orders them).
pub unsafe fn stream_collide<T: Real>(b: &Block<T>, p: usize, params: &TrtParams, kernel: KernelChoice) -> SweepStats {
    sweep_runs(b, p, b.fluid_segments(), params, kernel)
}

/// The sweep of [`stream_collide`] over the runs `segs`.
///
/// # Safety
/// As for [`stream_collide`].
unsafe fn sweep_runs<T: Real>(
    b: &Block<T>,
    p: usize,
    segs: &[blockflow_kernels::Segment],
    params: &TrtParams,
    kernel: KernelChoice,
) -> SweepStats {
    match b.pattern {
        Pattern::Aa => sweep::aa_step(b.field_mut(p), p as u64, segs, params),
        Pattern::Pull => {
            let src = b.field(p);
            let dst = b.field_mut(1 - p);
            match kernel {
                KernelChoice::Fused => sweep::stream_collide(src, dst, segs, params),
                KernelChoice::Split => {
                    sweep::stream(src, dst, segs);
                    sweep::collide(dst, segs, params)
                }
            }
        }
    }
}

/// The general path of [`boundary`] (`run.no_skip`): visits every interior cell to find the cells next to
/// a wall, one by one, then applies the block's links (a block without boundary cells finds none and
/// applies nothing). Same bits as [`boundary`].
pub fn boundary_general<T: Real>(b: &Block<T>, p: usize) {
    let near = b.scan_near_boundary();
    assert_eq!(
        near, b.near_boundary_cells,
        "block {}: near-boundary cells found by the scan differ from the mapped ones",
        b.id
    );
    boundary(b, p);
}

/// The general path of [`stream_collide`] (`run.no_skip`): the fluid runs are found by visiting every
/// interior cell's flag (and particle owner) instead of the runs mapped once, and under pull the unfused
/// kernels run (pull-stream, then collide in place) instead of the fused one. A block without fluid
/// visits its cells and sweeps nothing. Same bits as [`stream_collide`] (the kernels' sweeps do not depend
/// on where a run starts, and the fused kernel equals stream followed by collide bit for bit).
///
/// # Safety
/// As for [`stream_collide`].
pub unsafe fn stream_collide_general<T: Real>(b: &Block<T>, p: usize, params: &TrtParams) -> SweepStats {
    let mut runs = Vec::new();
    b.scan_fluid_runs(&mut runs);
    sweep_runs(b, p, &runs, params, KernelChoice::Split)
}

/// The post-collision populations of the cell at element `i` in the state of parity `p`.
pub fn post_cell<T: Real>(b: &Block<T>, p: usize, i: usize) -> [T; Q] {
    b.field(p).post_cell(b.slots(p), i)
}

/// δρ and u of the stored (post-collision) state of the cell at element `i` in the state of parity `p`.
pub fn cell_moments<T: Real>(b: &Block<T>, p: usize, i: usize, force: [f64; 3]) -> (f64, [f64; 3]) {
    blockflow_kernels::trt::moments(&post_cell(b, p, i), force)
}

/// Calls `visit(global cell, δρ, u)` for every interior fluid cell of the block in the state of parity
/// `p`, in x-fastest order: the moments of [`cell_moments`], bit for bit, computed a run of cells at a
/// time ([`blockflow_kernels::trt::moments_run`]).
pub fn for_each_fluid_moments<T: Real>(
    b: &Block<T>,
    p: usize,
    force: [f64; 3],
    mut visit: impl FnMut([usize; 3], f64, [f64; 3]),
) {
    use blockflow_kernels::trt::{moments_run, RunMoments, MOMENTS_RUN};
    let l = b.layout;
    let data = b.field(p).data();
    let sl = b.slots(p);
    let mut m = RunMoments::default();
    for s in b.fluid_segments() {
        let [x0, y, z] = l.coords(s.start);
        let mut x = x0;
        while x < x0 + s.len {
            let n = (x0 + s.len - x).min(MOMENTS_RUN);
            let i = l.idx(x, y, z);
            let start: [usize; Q] = std::array::from_fn(|q| sl.at(q, i));
            moments_run(data, &start, n, force, &mut m);
            for k in 0..n {
                visit(
                    [b.origin[0] + x + k - 1, b.origin[1] + y - 1, b.origin[2] + z - 1],
                    m.rho[k],
                    [m.u[0][k], m.u[1][k], m.u[2][k]],
                );
            }
            x += n;
        }
    }
}

/// The bad cell of field `p` (density or velocity non-finite, or |u| above `limit`) at the centre of the
/// block's bad region: the one with the most bad neighbours among its 18 D3Q19 neighbours, the first in
/// x-fastest order among equals; (global cell, δρ, u). A NaN injected into one cell spreads to its 18
/// neighbours in one step, so one step later this names the injected cell itself. Used only after a sweep
/// reported trouble.
pub fn find_bad_cell<T: Real>(
    b: &Block<T>,
    p: usize,
    limit: f64,
    force: [f64; 3],
) -> Option<([usize; 3], f64, [f64; 3])> {
    let mut bad: Vec<([usize; 3], f64, [f64; 3])> = Vec::new();
    for_each_fluid_moments(b, p, force, |g, r, u| {
        let u2 = u[0] * u[0] + u[1] * u[1] + u[2] * u[2];
        if !r.is_finite() || u2.is_nan() || u2 > limit * limit {
            bad.push((g, r, u));
        }
    });
    let set: std::collections::HashSet<[usize; 3]> = bad.iter().map(|c| c.0).collect();
    let neighbours = |g: [usize; 3]| {
        blockflow_kernels::d3q19::C[1..]
            .iter()
            .filter(|c| {
                let n = [0, 1, 2].map(|a| g[a] as i64 + c[a] as i64);
                n.iter().all(|&x| x >= 0) && set.contains(&n.map(|x| x as usize))
            })
            .count()
    };
    let mut best: Option<usize> = None;
    let mut most = 0;
    for (k, c) in bad.iter().enumerate() {
        let n = neighbours(c.0);
        if best.is_none() || n > most {
            best = Some(k);
            most = n;
        }
    }
    best.map(|k| bad[k])
}
