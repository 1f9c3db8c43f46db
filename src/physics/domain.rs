//! The block grid: a box of `blocks` blocks of `block_size` cells, periodic or walled per axis, with
//! neighbours over all 26 directions (periodic wrap included).

/// The 26 neighbour offsets, in a fixed order (z slowest, x fastest, skipping 0,0,0).
pub const NEIGHBOURS: [[i32; 3]; 26] = {
    let mut out = [[0; 3]; 26];
    let mut n = 0;
    let mut z = -1;
    while z <= 1 {
        let mut y = -1;
        while y <= 1 {
            let mut x = -1;
            while x <= 1 {
                if !(x == 0 && y == 0 && z == 0) {
                    out[n] = [x, y, z];
                    n += 1;
                }
                x += 1;
            }
            y += 1;
        }
        z += 1;
    }
    out
};

/// Shape of the block decomposition.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DomainSpec {
    /// Blocks per axis.
    pub blocks: [usize; 3],
    /// Interior cells per block and axis.
    pub block_size: [usize; 3],
    /// Periodicity per axis.
    pub periodic: [bool; 3],
}

impl DomainSpec {
    /// Cells per axis of the whole domain.
    pub fn cells(&self) -> [usize; 3] {
        [
            self.blocks[0] * self.block_size[0],
            self.blocks[1] * self.block_size[1],
            self.blocks[2] * self.block_size[2],
        ]
    }

    /// Total cell count.
    pub fn total_cells(&self) -> usize {
        self.cells().iter().product()
    }

    /// Number of blocks.
    pub fn num_blocks(&self) -> usize {
        self.blocks.iter().product()
    }

    /// Block coordinates of block `id` (x fastest).
    pub fn coords(&self, id: usize) -> [usize; 3] {
        let [nx, ny, _] = self.blocks;
        [id % nx, (id / nx) % ny, id / (nx * ny)]
    }

    /// Block id of block coordinates.
    pub fn id(&self, c: [usize; 3]) -> usize {
        c[0] + self.blocks[0] * (c[1] + self.blocks[1] * c[2])
    }

    /// Global cell coordinates of the first interior cell of block `id`.
    pub fn origin(&self, id: usize) -> [usize; 3] {
        let c = self.coords(id);
        [
            c[0] * self.block_size[0],
            c[1] * self.block_size[1],
            c[2] * self.block_size[2],
        ]
    }

    /// The neighbour of block `id` at offset `d`, wrapping periodic axes; `None` beyond a wall.
    pub fn neighbour(&self, id: usize, d: [i32; 3]) -> Option<usize> {
        let c = self.coords(id);
        let mut n = [0usize; 3];
        for a in 0..3 {
            let v = c[a] as i64 + d[a] as i64;
            let len = self.blocks[a] as i64;
            n[a] = if (0..len).contains(&v) {
                v as usize
            } else if self.periodic[a] {
                v.rem_euclid(len) as usize
            } else {
                return None;
            };
        }
        Some(self.id(n))
    }

    /// Maps a global cell coordinate into the domain along periodic axes (others unchanged).
    pub fn wrap(&self, g: [i64; 3]) -> [i64; 3] {
        let n = self.cells();
        std::array::from_fn(|a| {
            if self.periodic[a] {
                g[a].rem_euclid(n[a] as i64)
            } else {
                g[a]
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn neighbours_wrap_and_stop() {
        let d = DomainSpec {
            blocks: [3, 2, 1],
            block_size: [4, 4, 4],
            periodic: [true, false, true],
        };
        assert_eq!(NEIGHBOURS.len(), 26);
        let id = d.id([0, 0, 0]);
        assert_eq!(d.neighbour(id, [-1, 0, 0]), Some(d.id([2, 0, 0])));
        assert_eq!(d.neighbour(id, [0, -1, 0]), None);
        assert_eq!(d.neighbour(id, [0, 0, 1]), Some(id)); // one block along z: itself
        assert_eq!(d.neighbour(id, [1, 1, 1]), Some(d.id([1, 1, 0])));
        for i in 0..d.num_blocks() {
            assert_eq!(d.id(d.coords(i)), i);
        }
    }
}
