//! The per-block stages of one fluid time step (DESIGN.md, "One time step as a task graph"): ghost
//! exchange, boundary, stream + collide. Each is a function of one block (and, for the exchange, the
//! sending block's data), so the scheduler can run them as tasks.
//!
//! State convention: between steps a block holds *post-collision* PDFs. A step is
//! exchange (fill ghost layers from the neighbours) → boundary (write bounce-back values into wall cells)
//! → pull-stream + collide into the other field → swap. This is Algorithm 1's collide → communicate →
//! boundary → stream with the cycle cut after the collision.

use crate::block::{ghost_ranges, source_ranges, Block};
use crate::config::KernelChoice;
use blockflow_kernels::d3q19::Q;
use blockflow_kernels::sweep::{self, SweepStats};
use blockflow_kernels::{Real, TrtParams};

/// Packs the PDFs the receiver's ghost region at offset `off` needs from `sender` (directions `dirs`,
/// interior layer next to the shared face/edge) into `buf`, row by row. Inside a process the same data
/// could be copied directly; a packed message is what crosses processes (and an MPI backend would send).
pub fn pack<T: Real>(sender: &Block<T>, off: [i32; 3], dirs: &[usize], buf: &mut Vec<T>) {
    buf.clear();
    let l = &sender.layout;
    let f = sender.src.data();
    let [rx, ry, rz] = source_ranges(l, off);
    let n = rx.end() - rx.start() + 1;
    for &q in dirs {
        let base = q * l.stride;
        for z in rz.clone() {
            for y in ry.clone() {
                let i = base + l.idx(*rx.start(), y, z);
                buf.extend_from_slice(&f[i..i + n]);
            }
        }
    }
}

/// Unpacks a message from [`pack`] into the ghost region at offset `off` of `receiver`.
pub fn unpack<T: Real>(receiver: &mut Block<T>, off: [i32; 3], dirs: &[usize], buf: &[T]) {
    let l = receiver.layout;
    let f = receiver.src.data_mut();
    let [rx, ry, rz] = ghost_ranges(&l, off);
    let n = rx.end() - rx.start() + 1;
    let mut k = 0;
    for &q in dirs {
        let base = q * l.stride;
        for z in rz.clone() {
            for y in ry.clone() {
                let i = base + l.idx(*rx.start(), y, z);
                f[i..i + n].copy_from_slice(&buf[k..k + n]);
                k += n;
            }
        }
    }
    assert_eq!(k, buf.len(), "message size does not match the ghost region");
}

/// Boundary pass (eq. 6 with δ_q = 1/2): writes the bounce-back values of all links into the wall cells.
pub fn boundary<T: Real>(b: &mut Block<T>) {
    b.links.apply(&mut b.src);
}

/// Pull-stream (eq. 4) and collide (eq. 2) every fluid cell of the block into the other field, then swap
/// the fields. Fused and split kernels give identical bits.
pub fn stream_collide<T: Real>(
    b: &mut Block<T>,
    p: &TrtParams,
    kernel: KernelChoice,
) -> SweepStats {
    let st = match kernel {
        KernelChoice::Fused => sweep::stream_collide(&b.src, &mut b.dst, &b.segments, p),
        KernelChoice::Split => {
            sweep::stream(&b.src, &mut b.dst, &b.segments);
            sweep::collide(&mut b.dst, &b.segments, p)
        }
    };
    std::mem::swap(&mut b.src, &mut b.dst);
    st
}

/// δρ and u of the stored (post-collision) state of element `i` of a block.
pub fn cell_moments<T: Real>(b: &Block<T>, i: usize, force: [f64; 3]) -> (f64, [f64; 3]) {
    let f: [T; Q] = b.src.cell(i);
    blockflow_kernels::trt::moments(&f, force)
}

/// The first fluid cell (x fastest) whose density or velocity is non-finite or whose |u| exceeds `limit`:
/// (global cell, δρ, u). Used only after a sweep reported trouble.
pub fn find_bad_cell<T: Real>(
    b: &Block<T>,
    limit: f64,
    force: [f64; 3],
) -> Option<([usize; 3], f64, [f64; 3])> {
    let mut found = None;
    b.for_each_fluid(|g, i| {
        if found.is_some() {
            return;
        }
        let (r, u) = cell_moments(b, i, force);
        let u2 = u[0] * u[0] + u[1] * u[1] + u[2] * u[2];
        if !r.is_finite() || u2.is_nan() || u2 > limit * limit {
            found = Some((g, r, u));
        }
    });
    found
}
