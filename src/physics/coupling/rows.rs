//! Cells of a block as bit rows: bit x of row (y, z) stands for cell (x, y, z) of the ghost-inclusive
//! grid, so that "fluid now", "covered by a body" and "has a covered neighbour in direction q" are a few
//! word operations per row instead of a test per cell. The mapping and the surface boundary pass use
//! them; the overlay keeps them as scratch next to the owner array they mirror.

/// One bit per cell of a block (ghost layer included), row by row.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct CellBits {
    /// Words per row.
    pub words: usize,
    /// Rows along y (the ghost-inclusive count).
    pub fy: usize,
    /// Rows along z.
    pub fz: usize,
    /// The bits, row (y, z) at words `(y + fy z) · words ..`.
    pub bits: Vec<u64>,
}

impl CellBits {
    /// All clear, for a ghost-inclusive grid of `full` cells.
    pub fn new(full: [usize; 3]) -> Self {
        let words = full[0].div_ceil(64);
        CellBits {
            words,
            fy: full[1],
            fz: full[2],
            bits: vec![0; words * full[1] * full[2]],
        }
    }

    /// Whether these bits are sized for a grid of `full` cells.
    pub fn fits(&self, full: [usize; 3]) -> bool {
        self.words == full[0].div_ceil(64) && self.fy == full[1] && self.fz == full[2] && !self.bits.is_empty()
    }

    /// Clears every bit, keeping the size.
    pub fn clear(&mut self) {
        self.bits.iter_mut().for_each(|w| *w = 0);
    }

    /// The words of row (y, z).
    #[inline]
    pub fn row(&self, y: usize, z: usize) -> &[u64] {
        let at = (y + self.fy * z) * self.words;
        &self.bits[at..at + self.words]
    }

    /// The words of row (y, z), to write.
    #[inline]
    pub fn row_mut(&mut self, y: usize, z: usize) -> &mut [u64] {
        let at = (y + self.fy * z) * self.words;
        &mut self.bits[at..at + self.words]
    }

    /// Sets cell (x, y, z).
    #[inline]
    pub fn set(&mut self, x: usize, y: usize, z: usize) {
        let at = (y + self.fy * z) * self.words + x / 64;
        self.bits[at] |= 1 << (x % 64);
    }

    /// Whether any bit is set.
    pub fn any(&self) -> bool {
        self.bits.iter().any(|&w| w != 0)
    }

    /// Word `w` of row (y, z) moved so that bit x holds cell x + dx of the row (`dx` ∈ {-1, 0, 1}; cells
    /// beyond the row's ends read as clear).
    #[inline]
    pub fn shifted(&self, y: usize, z: usize, w: usize, dx: i32) -> u64 {
        let r = self.row(y, z);
        match dx {
            0 => r[w],
            1 => (r[w] >> 1) | r.get(w + 1).map_or(0, |n| n << 63),
            _ => (r[w] << 1) | if w > 0 { r[w - 1] >> 63 } else { 0 },
        }
    }
}

/// The set bits of `word` (word `w` of a row) as cell x coordinates, ascending.
#[inline]
pub fn bit_cells(mut word: u64, w: usize) -> impl Iterator<Item = usize> {
    std::iter::from_fn(move || {
        if word == 0 {
            return None;
        }
        let b = word.trailing_zeros() as usize;
        word &= word - 1;
        Some(w * 64 + b)
    })
}

/// The mask of word `w` of a row that keeps the interior cells x = 1 ..= fx − 2.
#[inline]
pub fn interior_mask(fx: usize, w: usize) -> u64 {
    let lo = w * 64;
    let (a, b) = (1usize.max(lo), (fx - 1).min(lo + 64));
    if a >= b {
        return 0;
    }
    let len = b - a;
    let ones = if len == 64 { u64::MAX } else { (1u64 << len) - 1 };
    ones << (a - lo)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shifts_carry_across_words_and_masks_keep_the_interior() {
        let mut b = CellBits::new([130, 3, 3]);
        b.set(63, 1, 1);
        b.set(64, 1, 1);
        b.set(0, 1, 1);
        // bit x of the shifted word holds cell x + 1
        assert_eq!(b.shifted(1, 1, 0, 1) >> 62 & 0b11, 0b11);
        assert_eq!(b.shifted(1, 1, 1, -1) & 1, 1, "cell 63 seen from cell 64");
        assert_eq!(bit_cells(b.row(1, 1)[1], 1).collect::<Vec<_>>(), vec![64]);
        assert_eq!(interior_mask(130, 0), u64::MAX - 1);
        assert_eq!(interior_mask(130, 2), 0b1);
        assert_eq!(interior_mask(14, 0), ((1u64 << 12) - 1) << 1);
        assert!(b.any() && b.fits([130, 3, 3]) && !b.fits([14, 3, 3]));
    }
}
