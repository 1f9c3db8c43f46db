//! Bounce-back walls: simple bounce-back (no-slip) and moving-wall bounce-back.
//!
//! A link joins a fluid cell x to a wall cell w = x - c_q. Before the next stream, the boundary pass sets
//! the wall cell's post-collision population that x will receive: f*_q(w) = f*_q̄(x) + 6 w_q ρ0 (c_q · u_w),
//! i.e. the population that left x towards the wall comes back reflected, carrying the wall's momentum
//! (Ladd 1994; eq. 6 with δ_q = 1/2). Each (w, q) is written by exactly one link, so the pass has no write
//! conflicts. Under pull streaming f*_q(w) lies at (w, q) and f*_q̄(x) at (x, q̄); under the AA pattern
//! ([`crate::field::Slots`]) at (w, q̄) and (x, q) after an odd number of steps and, after an even number,
//! at (x, q) and (w, q̄): the same two elements with the roles swapped.

use crate::d3q19::{C, OPP, W};
use crate::field::{Layout, Pattern, PdfField};
use crate::real::Real;

/// The bounce-back links of one block, as flat element offsets into a field (`q * stride + idx`).
#[derive(Clone, Debug, Default)]
pub struct Links<T> {
    /// The element pair of each resting-wall link: `[f*_q(w), f*_q̄(x)]` for pull, `[(w, q̄), (x, q)]` for AA.
    pub noslip: Vec<[usize; 2]>,
    /// The element pair plus the moving-wall term 6 w_q (c_q · u_w).
    pub moving: Vec<([usize; 2], T)>,
    /// The streaming pattern the pairs are laid out for.
    pub pattern: Pattern,
}

impl<T: Real> Links<T> {
    /// An empty link list for fields streamed by `pattern`.
    pub fn new(pattern: Pattern) -> Self {
        Links {
            noslip: Vec::new(),
            moving: Vec::new(),
            pattern,
        }
    }

    /// Adds the link from fluid cell `fluid` (element index) to the wall cell in direction -c_q, with wall
    /// velocity `u_w` (zero for a resting wall).
    pub fn push(&mut self, layout: &Layout, fluid: usize, q: usize, u_w: [f64; 3]) {
        let wall = (fluid as isize - layout.offset(C[q])) as usize;
        let (dst, src) = match self.pattern {
            Pattern::Pull => (q * layout.stride + wall, OPP[q] * layout.stride + fluid),
            Pattern::Aa => (OPP[q] * layout.stride + wall, q * layout.stride + fluid),
        };
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

    /// Distinct 64-byte cache lines the boundary pass reads or writes (both elements of every link): what
    /// the pass costs in memory traffic. Links along a wall that crosses the rows (normal along x) each
    /// touch lines of their own; links along a wall parallel to the rows share them.
    pub fn lines(&self) -> usize {
        let per_line = (64 / T::BYTES).max(1);
        let mut ids: Vec<usize> = (self.noslip.iter().copied())
            .chain(self.moving.iter().map(|(pair, _)| *pair))
            .flatten()
            .map(|e| e / per_line)
            .collect();
        ids.sort_unstable();
        ids.dedup();
        ids.len()
    }

    /// Whether the block has no links (then it needs no boundary pass).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The boundary pass on the state after a number of steps of parity `parity`: writes every wall
    /// value the next stream will read.
    pub fn apply(&self, f: &mut PdfField<T>, parity: usize) {
        // SAFETY: exclusive access through &mut.
        unsafe { self.apply_raw(f.raw(), f.layout.len(), parity) }
    }

    /// The boundary pass through a raw pointer to a field of `len` elements holding the state after a
    /// number of steps of parity `parity`.
    ///
    /// # Safety
    /// `data` points to a field of this block's layout with `len` elements; during the call no other thread
    /// reads the elements written or writes the elements read (the task graph orders the boundary pass
    /// against the ghost exchange and the sweeps).
    pub unsafe fn apply_raw(&self, data: *mut T, len: usize, parity: usize) {
        // AA after an even number of steps: f*_q(w) is at (x, q), the second element of the pair.
        let (d, s) = if self.pattern == Pattern::Aa && parity == 0 {
            (1, 0)
        } else {
            (0, 1)
        };
        for pair in &self.noslip {
            debug_assert!(pair[0] < len && pair[1] < len);
            *data.add(pair[d]) = *data.add(pair[s]);
        }
        for (pair, t) in &self.moving {
            debug_assert!(pair[0] < len && pair[1] < len);
            *data.add(pair[d]) = *data.add(pair[s]) + *t;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::d3q19::Q;

    /// Links of a block's face cells towards a resting wall: across the rows (normal x, 16³ block),
    /// every element lies in a row of its own, so each link touches two lines; along the rows (normal z,
    /// 14³ block, whose row pitch 16 is the ghost-inclusive row), the 14 rows of a plane lie one after
    /// the other with two ghost elements between them, so in each of the 5 source and 5 destination
    /// arrays they cover one run of elements, (x0 + 1) + 16 · 1 … (x0 + 14) + 16 · 14 shifted by the
    /// link's x and y offset: lines 2 … 30, 29 lines per array, 290 for 980 links.
    #[test]
    fn wall_links_across_the_rows_touch_a_line_per_element_along_them_share_lines() {
        let layout = Layout::new::<f64>([16, 16, 16]);
        let mut across = Links::<f64>::new(Pattern::Aa);
        for a in 1..=16 {
            for b in 1..=16 {
                for q in (1..Q).filter(|&q| C[q][0] == 1) {
                    across.push(&layout, layout.idx(1, a, b), q, [0.0; 3]);
                }
            }
        }
        assert_eq!(across.len(), 16 * 16 * 5);
        assert_eq!(across.lines(), 2 * across.len());
        let layout = Layout::new::<f64>([14, 14, 14]);
        assert_eq!(layout.sx, 16);
        let mut along = Links::<f64>::new(Pattern::Aa);
        for y in 1..=14 {
            for x in 1..=14 {
                for q in (1..Q).filter(|&q| C[q][2] == 1) {
                    along.push(&layout, layout.idx(x, y, 1), q, [0.0; 3]);
                }
            }
        }
        assert_eq!(along.len(), 14 * 14 * 5);
        assert_eq!(along.lines(), 29 * 10);
    }
}
