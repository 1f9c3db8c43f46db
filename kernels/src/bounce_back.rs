//! Bounce-back walls for pull streaming: simple bounce-back (no-slip) and moving-wall bounce-back.
//!
//! A link joins a fluid cell x to a wall cell w = x - c_q. Before the pull stream, the boundary pass writes
//! into the wall cell the value that x will pull: f_q(w) = f*_q̄(x) + 6 w_q ρ0 (c_q · u_w), i.e. the
//! population that left x towards the wall comes back reflected, carrying the wall's momentum (Ladd 1994;
//! eq. 6 with δ_q = 1/2). Each (w, q) is written by exactly one link, so the pass has no write conflicts.

use crate::d3q19::{C, OPP, W};
use crate::field::{Layout, PdfField};
use crate::real::Real;

/// The bounce-back links of one block, as flat element offsets into a field (`q * stride + idx`).
#[derive(Clone, Debug, Default)]
pub struct Links<T> {
    /// (destination in the wall cell, source in the fluid cell) for resting walls.
    pub noslip: Vec<[usize; 2]>,
    /// (destination, source) plus the moving-wall term 6 w_q (c_q · u_w).
    pub moving: Vec<([usize; 2], T)>,
}

impl<T: Real> Links<T> {
    /// An empty link list.
    pub fn new() -> Self {
        Links {
            noslip: Vec::new(),
            moving: Vec::new(),
        }
    }

    /// Adds the link from fluid cell `fluid` (element index) to the wall cell in direction -c_q, with wall
    /// velocity `u_w` (zero for a resting wall).
    pub fn push(&mut self, layout: &Layout, fluid: usize, q: usize, u_w: [f64; 3]) {
        let wall = (fluid as isize - layout.offset(C[q])) as usize;
        let dst = q * layout.stride + wall;
        let src = OPP[q] * layout.stride + fluid;
        if u_w == [0.0; 3] {
            self.noslip.push([dst, src]);
        } else {
            let cu = C[q][0] as f64 * u_w[0] + C[q][1] as f64 * u_w[1] + C[q][2] as f64 * u_w[2];
            self.moving.push(([dst, src], T::from_f64(6.0 * W[q] * cu)));
        }
    }

    /// Number of links.
    pub fn len(&self) -> usize {
        self.noslip.len() + self.moving.len()
    }

    /// Whether the block has no links (then it needs no boundary pass).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The boundary pass: writes every wall value the next pull stream will read.
    pub fn apply(&self, f: &mut PdfField<T>) {
        // SAFETY: exclusive access through &mut.
        unsafe { self.apply_raw(f.raw(), f.layout.len()) }
    }

    /// The boundary pass through a raw pointer to a field of `len` elements.
    ///
    /// # Safety
    /// `data` points to a field of this block's layout with `len` elements; during the call no other thread
    /// reads the wall elements written or writes the fluid elements read (the task graph orders the
    /// boundary pass against the ghost exchange and the sweeps).
    pub unsafe fn apply_raw(&self, data: *mut T, len: usize) {
        for &[dst, src] in &self.noslip {
            debug_assert!(dst < len && src < len);
            *data.add(dst) = *data.add(src);
        }
        for &([dst, src], t) in &self.moving {
            debug_assert!(dst < len && src < len);
            *data.add(dst) = *data.add(src) + t;
        }
    }
}
