//! Structure-of-arrays PDF storage for one block with one ghost layer.
//!
//! Each of the 19 directions is a contiguous array over the padded cell grid. Rows (x) are padded so the
//! first interior cell of every row is 32-byte aligned, and the per-direction stride is skewed by three
//! cache lines per direction so the 19 arrays do not alias on 4 KiB boundaries (aliasing costs 9-19 % in
//! the TRT kernel on this machine). Values are stored *zero-centred*: `f_q - w_q` (ρ0 = 1), which keeps
//! f32 accurate and makes the rest state all zeros.

use crate::d3q19::{C, OPP, Q};
use crate::real::Real;
use std::alloc::{alloc_zeroed, dealloc, Layout as AllocLayout};

/// Bytes between the starts of consecutive direction arrays modulo 4096.
const DIRECTION_SKEW_BYTES: usize = 192;
/// Allocation alignment (one page), so the skew is what decides 4 KiB aliasing.
const PAGE: usize = 4096;

/// Index arithmetic of one block's padded grid. Coordinates are ghost-inclusive: `0` and `n + 1` are the
/// ghost layers, `1..=n` the interior.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Layout {
    /// Interior size (cells) along x, y, z.
    pub size: [usize; 3],
    /// Elements between consecutive rows (y + 1), a multiple of the lane count.
    pub sx: usize,
    /// Elements between consecutive planes (z + 1).
    pub sxy: usize,
    /// Element index of ghost cell x = 0 within its row.
    pub x0: usize,
    /// Elements per direction array ([`Layout::slots`] rounded up to pages, plus skew).
    pub stride: usize,
}

impl Layout {
    /// Layout for an interior of `size` cells stored as `T`.
    pub fn new<T: Real>(size: [usize; 3]) -> Self {
        let lanes = T::LANES;
        // x = 1 (first interior) sits at a multiple of `lanes`: x0 = lanes - 1.
        let x0 = lanes - 1;
        // A row's x = 0 … n + 1 need not fit inside its own `sx` elements: they only must not reach the
        // next row's x = 0, so the pitch is the ghost-inclusive row rounded up to the lanes. The right
        // ghost then lies among the next row's leading elements, which no cell of that row uses. On
        // 12³ blocks in f64 that is 16 elements per row instead of 20.
        let sx = (size[0] + 2).div_ceil(lanes) * lanes;
        let sxy = sx * (size[1] + 2);
        let mut l = Layout {
            size,
            sx,
            sxy,
            x0,
            stride: 0,
        };
        let page_elems = PAGE / T::BYTES;
        l.stride = l.slots().div_ceil(page_elems) * page_elems + DIRECTION_SKEW_BYTES / T::BYTES;
        l
    }

    /// Elements an array indexed by [`Layout::idx`] over the ghost-inclusive grid needs (one past the
    /// index of the last ghost cell).
    pub fn slots(&self) -> usize {
        self.idx(self.size[0] + 1, self.size[1] + 1, self.size[2] + 1) + 1
    }

    /// Element index of ghost-inclusive cell (x, y, z) within a direction array.
    #[inline(always)]
    pub fn idx(&self, x: usize, y: usize, z: usize) -> usize {
        self.x0 + x + self.sx * y + self.sxy * z
    }

    /// Inverse of [`Layout::idx`] for an index of a real cell.
    pub fn coords(&self, i: usize) -> [usize; 3] {
        // idx − x0 = x + sx·y + sxy·z with x < sx and y < ny + 2: a mixed-radix number.
        let r = i - self.x0;
        [r % self.sx, (r % self.sxy) / self.sx, r / self.sxy]
    }

    /// Signed element offset of neighbour direction c: idx(x + c) - idx(x).
    #[inline(always)]
    pub fn offset(&self, c: [i32; 3]) -> isize {
        c[0] as isize + c[1] as isize * self.sx as isize + c[2] as isize * self.sxy as isize
    }

    /// Total elements of one field (all 19 directions).
    pub fn len(&self) -> usize {
        self.stride * Q
    }

    /// Whether the interior is empty (never true for a valid block).
    pub fn is_empty(&self) -> bool {
        self.size.contains(&0)
    }

    /// Interior cell count.
    pub fn interior_cells(&self) -> usize {
        self.size.iter().product()
    }

    /// Ghost-inclusive extent along each axis.
    pub fn full(&self) -> [usize; 3] {
        [self.size[0] + 2, self.size[1] + 2, self.size[2] + 2]
    }
}

/// How populations stream between steps.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Pattern {
    /// Two fields: each step pulls f_q(x − c_q) from one field and writes the post-collision state of x
    /// into the other (eq. 4 then eq. 2).
    Pull,
    /// One field updated in place (AA pattern, Bailey et al. 2009). A step that starts after an even
    /// number of steps reads (x, q) and writes the post-collision f*_q(x) to (x, q̄); a step after an odd
    /// number reads (x − c_q, q̄) and writes f*_q(x) to (x + c_q, q). Same collision, same arithmetic.
    #[default]
    Aa,
}

impl Pattern {
    /// PDF fields a block holds under this pattern.
    pub fn fields(self) -> usize {
        match self {
            Pattern::Pull => 2,
            Pattern::Aa => 1,
        }
    }

    /// The field (0 or 1) that holds the state after a number of steps of parity `parity`.
    #[inline(always)]
    pub fn field_of(self, parity: usize) -> usize {
        match self {
            Pattern::Pull => parity,
            Pattern::Aa => 0,
        }
    }
}

/// Where the post-collision populations of the state after a number of steps of a given parity are
/// stored: f*_q(x) of the cell at element index i lies at element `base[q] + i` of its field
/// (direction-major). Pull: (x, q). AA after an even number of steps: (x + c_q, q) (the next step reads
/// its incoming populations in place); after an odd number: (x, q̄). Every (q, x) has its own element,
/// so exchange, boundary, coupling, output and checkpoints address the same physical state under either
/// pattern through this map.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Slots {
    base: [isize; Q],
}

impl Slots {
    /// The map of `pattern` for the state after a number of steps of parity `parity` (0 or 1).
    pub fn new(pattern: Pattern, layout: &Layout, parity: usize) -> Self {
        let s = layout.stride as isize;
        Slots {
            base: std::array::from_fn(|q| match (pattern, parity) {
                (Pattern::Pull, _) => q as isize * s,
                (Pattern::Aa, 0) => q as isize * s + layout.offset(C[q]),
                (Pattern::Aa, _) => OPP[q] as isize * s,
            }),
        }
    }

    /// Element (direction-major, `q * stride + idx` form) holding f*_q of the cell at index `i`.
    #[inline(always)]
    pub fn at(&self, q: usize, i: usize) -> usize {
        (self.base[q] + i as isize) as usize
    }
}

/// A page-aligned, zero-initialised buffer, obtained with `alloc_zeroed`. The standard allocator zeroes
/// an allocation aligned past its minimum with a memset, so every page is first touched (and placed on a
/// NUMA node) by the thread that creates the buffer.
pub struct AlignedBuf<T: Real> {
    ptr: *mut T,
    len: usize,
    alloc_len: usize,
    offset: usize,
}

// SAFETY: AlignedBuf owns its memory exclusively, like Vec<T>.
unsafe impl<T: Real> Send for AlignedBuf<T> {}
unsafe impl<T: Real> Sync for AlignedBuf<T> {}

impl<T: Real> AlignedBuf<T> {
    /// A zeroed buffer of `len` elements whose first element is `skew_bytes` past a page boundary.
    pub fn zeroed(len: usize, skew_bytes: usize) -> Self {
        let offset = skew_bytes / T::BYTES;
        let alloc_len = (len + offset).max(1);
        let layout = AllocLayout::from_size_align(alloc_len * T::BYTES, PAGE).expect("block too large");
        // SAFETY: layout has non-zero size; an all-zero bit pattern is 0.0 for f32 and f64.
        let ptr = unsafe { alloc_zeroed(layout) } as *mut T;
        if ptr.is_null() {
            std::alloc::handle_alloc_error(layout);
        }
        AlignedBuf {
            ptr,
            len,
            alloc_len,
            offset,
        }
    }

    /// The elements as a slice.
    #[inline(always)]
    pub fn as_slice(&self) -> &[T] {
        // SAFETY: ptr + offset .. + len lies inside the allocation and is initialised (zeroed).
        unsafe { std::slice::from_raw_parts(self.ptr.add(self.offset), self.len) }
    }

    /// Raw pointer to the first element, for tasks that write disjoint cell regions of one field
    /// concurrently (ghost layers, wall cells) while others read other regions.
    #[inline(always)]
    pub fn as_ptr(&self) -> *mut T {
        // SAFETY: offset lies inside the allocation.
        unsafe { self.ptr.add(self.offset) }
    }

    /// Asks the kernel to back the whole 2 MiB-aligned pages of the buffer with transparent huge pages
    /// (`madvise(MADV_HUGEPAGE)`; effective for pages not touched yet). Returns whether the call was made
    /// and succeeded (false on other systems, for buffers smaller than one huge page, or when refused).
    pub fn advise_huge_pages(&mut self) -> bool {
        const HUGE: usize = 2 << 20;
        let start = self.ptr as usize;
        let end = start + self.alloc_len * T::BYTES;
        let (lo, hi) = (start.next_multiple_of(HUGE), end / HUGE * HUGE);
        if hi <= lo {
            return false;
        }
        #[cfg(target_os = "linux")]
        {
            // SAFETY: [lo, hi) lies inside this allocation; the advice changes no contents.
            unsafe { libc::madvise(lo as *mut libc::c_void, hi - lo, libc::MADV_HUGEPAGE) == 0 }
        }
        #[cfg(not(target_os = "linux"))]
        {
            false
        }
    }

    /// The elements as a mutable slice.
    #[inline(always)]
    pub fn as_mut_slice(&mut self) -> &mut [T] {
        // SAFETY: as above, and &mut self guarantees exclusivity.
        unsafe { std::slice::from_raw_parts_mut(self.ptr.add(self.offset), self.len) }
    }
}

impl<T: Real> Drop for AlignedBuf<T> {
    fn drop(&mut self) {
        let layout = AllocLayout::from_size_align(self.alloc_len * T::BYTES, PAGE).unwrap();
        // SAFETY: allocated in `zeroed` with this layout.
        unsafe { dealloc(self.ptr as *mut u8, layout) }
    }
}

/// The 19 PDF arrays of one block (zero-centred values `f_q - w_q`).
pub struct PdfField<T: Real> {
    /// Index arithmetic shared by both fields of a block.
    pub layout: Layout,
    buf: AlignedBuf<T>,
}

impl<T: Real> PdfField<T> {
    /// A field at rest (ρ = 1, u = 0). `skew_bytes` shifts the whole field against page boundaries so the
    /// source and destination fields of a block do not alias each other either.
    pub fn new(layout: Layout, skew_bytes: usize) -> Self {
        PdfField {
            layout,
            buf: AlignedBuf::zeroed(layout.len(), skew_bytes),
        }
    }

    /// A field of `layout` without storage: the stand-in of a block whose data another rank holds. It
    /// has no values ([`PdfField::is_allocated`] is false); replace it by a real field before use.
    pub fn unallocated(layout: Layout) -> Self {
        PdfField {
            layout,
            buf: AlignedBuf::zeroed(0, 0),
        }
    }

    /// Whether the field has storage (every field but an [`PdfField::unallocated`] one).
    pub fn is_allocated(&self) -> bool {
        self.buf.len > 0
    }

    /// Advises the field's memory to transparent huge pages ([`AlignedBuf::advise_huge_pages`]); call
    /// before the first write.
    pub fn advise_huge_pages(&mut self) -> bool {
        self.buf.advise_huge_pages()
    }

    /// All values, direction-major: `data()[q * stride + idx]`.
    #[inline(always)]
    pub fn data(&self) -> &[T] {
        self.buf.as_slice()
    }

    /// All values, mutable.
    #[inline(always)]
    pub fn data_mut(&mut self) -> &mut [T] {
        self.buf.as_mut_slice()
    }

    /// Raw pointer to element 0 of direction 0 (`ptr.add(q * stride + idx)` addresses a value). Writing
    /// through it is allowed while no slice of this field is alive that covers the written elements.
    #[inline(always)]
    pub fn raw(&self) -> *mut T {
        self.buf.as_ptr()
    }

    /// Value of direction q at element index i.
    #[inline(always)]
    pub fn get(&self, q: usize, i: usize) -> T {
        self.data()[q * self.layout.stride + i]
    }

    /// Sets direction q at element index i.
    #[inline(always)]
    pub fn set(&mut self, q: usize, i: usize, v: T) {
        let s = self.layout.stride;
        self.data_mut()[q * s + i] = v;
    }

    /// The 19 values of cell i.
    pub fn cell(&self, i: usize) -> [T; Q] {
        std::array::from_fn(|q| self.get(q, i))
    }

    /// Overwrites the 19 values of cell i.
    pub fn set_cell(&mut self, i: usize, f: &[T; Q]) {
        for (q, &v) in f.iter().enumerate() {
            self.set(q, i, v);
        }
    }

    /// The post-collision populations f*_q of cell i, read through the pattern's map `slots`.
    #[inline]
    pub fn post_cell(&self, slots: &Slots, i: usize) -> [T; Q] {
        let d = self.data();
        std::array::from_fn(|q| d[slots.at(q, i)])
    }

    /// Overwrites the post-collision populations of cell i through the map `slots`.
    #[inline]
    pub fn set_post_cell(&mut self, slots: &Slots, i: usize, f: &[T; Q]) {
        let d = self.data_mut();
        for (q, &v) in f.iter().enumerate() {
            d[slots.at(q, i)] = v;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layout_alignment_and_skew() {
        let l = Layout::new::<f64>([128, 128, 128]);
        assert_eq!(l.idx(1, 0, 0) % 4, 0);
        assert_eq!(l.sx % 4, 0);
        assert!(l.idx(129, 129, 129) < l.stride);
        let starts: Vec<usize> = (0..Q).map(|q| (q * l.stride * 8) % 4096).collect();
        for a in 0..Q {
            for b in 0..a {
                assert!(starts[a].abs_diff(starts[b]) >= 64, "arrays {a},{b} alias");
            }
        }
        let l32 = Layout::new::<f32>([17, 5, 3]);
        assert_eq!(l32.idx(1, 2, 3) % 8, 0);
        assert_eq!(l32.coords(l32.idx(18, 6, 4)), [18, 6, 4]);
    }

    /// Every ghost-inclusive cell has its own element below `slots()` (rows may share a pitch's
    /// padding, never an element), `coords` inverts `idx`, and x = 1 is aligned, for every row width.
    #[test]
    fn rows_never_share_an_element() {
        fn check<T: Real>(size: [usize; 3]) {
            let l = Layout::new::<T>(size);
            let [fx, fy, fz] = l.full();
            let mut seen = vec![false; l.slots()];
            for z in 0..fz {
                for y in 0..fy {
                    assert_eq!(l.idx(1, y, z) % T::LANES, 0, "{size:?}");
                    for x in 0..fx {
                        let i = l.idx(x, y, z);
                        assert!(!seen[i], "{size:?}: ({x}, {y}, {z}) shares element {i}");
                        seen[i] = true;
                        assert_eq!(l.coords(i), [x, y, z]);
                    }
                }
            }
            assert!(l.slots() <= l.stride);
        }
        for n in 1..=20 {
            check::<f64>([n, 3, 2]);
            check::<f32>([n, 2, 3]);
        }
        // The pitch is the ghost-inclusive row rounded up to the lanes: 16 for 12 cells in f64.
        assert_eq!(Layout::new::<f64>([12, 12, 12]).sx, 16);
        assert_eq!(Layout::new::<f32>([12, 12, 12]).sx, 16);
    }
}
