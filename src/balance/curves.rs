//! Space-filling curves over integer block coordinates: real 3D Hilbert (Skilling's transpose
//! algorithm) and Morton (bit interleaving) keys, and block orders for any block counts (the keys are
//! taken on the enclosing power-of-two cube; blocks are sorted by key).
//!
//! Note for comparisons with the paper: waLBerla's "Hilbert" order on a uniform block grid is a zig-zag
//! order and its "Morton" order plain x-fastest; these are the true curves.

/// Bits per axis needed for coordinates below `n`.
pub fn bits_for(n: usize) -> u32 {
    (usize::BITS - (n.max(2) - 1).leading_zeros()).max(1)
}

/// Morton (Z-order) key: bits interleaved as … z1 y1 x1 z0 y0 x0.
pub fn morton_key(c: [u32; 3], bits: u32) -> u64 {
    let mut k = 0u64;
    for b in (0..bits).rev() {
        for a in (0..3).rev() {
            k = (k << 1) | ((c[a] >> b) & 1) as u64;
        }
    }
    k
}

/// Hilbert key of a point in a 2^bits cube (J. Skilling, "Programming the Hilbert curve", 2004):
/// axes → transposed Hilbert index → interleaved key. Consecutive keys are face neighbours.
pub fn hilbert_key(c: [u32; 3], bits: u32) -> u64 {
    let mut x = [c[2], c[1], c[0]]; // most significant axis first
    let m = 1u32 << (bits - 1);
    // inverse undo
    let mut q = m;
    while q > 1 {
        let p = q - 1;
        for i in 0..3 {
            if x[i] & q != 0 {
                x[0] ^= p;
            } else {
                let t = (x[0] ^ x[i]) & p;
                x[0] ^= t;
                x[i] ^= t;
            }
        }
        q >>= 1;
    }
    // Gray encode
    for i in 1..3 {
        x[i] ^= x[i - 1];
    }
    let mut t = 0;
    let mut q = m;
    while q > 1 {
        if x[2] & q != 0 {
            t ^= q - 1;
        }
        q >>= 1;
    }
    for v in x.iter_mut() {
        *v ^= t;
    }
    let mut k = 0u64;
    for b in (0..bits).rev() {
        for v in x {
            k = (k << 1) | ((v >> b) & 1) as u64;
        }
    }
    k
}

/// Which curve orders the blocks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Curve {
    /// 3D Hilbert curve.
    Hilbert,
    /// Morton (Z-order) curve.
    Morton,
}

/// Block ids of a grid of `blocks` (ids x fastest) in curve order.
///
/// Keys are unique, so the order is a bucket fill when the key space (8^bits) is at most 8 × the block
/// count, else a sort of key·2³² + id (a sort of (key, id) pairs beyond 2³² blocks or 10 bits per axis).
pub fn curve_order(blocks: [usize; 3], curve: Curve) -> Vec<usize> {
    let bits = bits_for(*blocks.iter().max().unwrap_or(&1));
    let n: usize = blocks.iter().product();
    let key = |x: usize, y: usize, z: usize| {
        let c = [x as u32, y as u32, z as u32];
        match curve {
            Curve::Hilbert => hilbert_key(c, bits),
            Curve::Morton => morton_key(c, bits),
        }
    };
    let space = 1u128 << (3 * bits);
    if space <= 8 * n as u128 {
        let mut slot = vec![u32::MAX; space as usize];
        let mut id = 0;
        for z in 0..blocks[2] {
            for y in 0..blocks[1] {
                for x in 0..blocks[0] {
                    slot[key(x, y, z) as usize] = id as u32;
                    id += 1;
                }
            }
        }
        return slot
            .into_iter()
            .filter(|&s| s != u32::MAX)
            .map(|s| s as usize)
            .collect();
    }
    if bits <= 10 && n < 1 << 32 {
        let mut v: Vec<u64> = Vec::with_capacity(n);
        for z in 0..blocks[2] {
            for y in 0..blocks[1] {
                for x in 0..blocks[0] {
                    v.push(key(x, y, z) << 32 | (x + blocks[0] * (y + blocks[1] * z)) as u64);
                }
            }
        }
        v.sort_unstable();
        return v.into_iter().map(|k| (k & 0xffff_ffff) as usize).collect();
    }
    let mut v: Vec<(u64, usize)> = Vec::with_capacity(n);
    for z in 0..blocks[2] {
        for y in 0..blocks[1] {
            for x in 0..blocks[0] {
                v.push((key(x, y, z), x + blocks[0] * (y + blocks[1] * z)));
            }
        }
    }
    v.sort_unstable();
    v.into_iter().map(|(_, id)| id).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn coords(id: usize, b: [usize; 3]) -> [i64; 3] {
        [
            (id % b[0]) as i64,
            ((id / b[0]) % b[1]) as i64,
            (id / (b[0] * b[1])) as i64,
        ]
    }

    #[test]
    fn morton_small_order() {
        // 2x2x2: x fastest, then y, then z — exactly the id order.
        assert_eq!(curve_order([2, 2, 2], Curve::Morton), vec![0, 1, 2, 3, 4, 5, 6, 7]);
        // 4x2x1: Z pattern over 2x2 tiles.
        assert_eq!(curve_order([4, 2, 1], Curve::Morton), vec![0, 1, 4, 5, 2, 3, 6, 7]);
    }

    #[test]
    fn hilbert_small_order_is_a_gray_path() {
        // 2x2x2 corner tour: each step changes exactly one coordinate.
        let o = curve_order([2, 2, 2], Curve::Hilbert);
        assert_eq!(o, vec![0, 1, 3, 2, 6, 7, 5, 4]);
    }

    #[test]
    fn hilbert_keys_are_a_permutation_and_steps_are_face_neighbours() {
        for bits in 1..=4u32 {
            let n = 1usize << bits;
            let o = curve_order([n, n, n], Curve::Hilbert);
            let mut seen = o.clone();
            seen.sort_unstable();
            assert_eq!(seen, (0..n * n * n).collect::<Vec<_>>());
            for w in o.windows(2) {
                let (a, b) = (coords(w[0], [n; 3]), coords(w[1], [n; 3]));
                let d: i64 = (0..3).map(|i| (a[i] - b[i]).abs()).sum();
                assert_eq!(d, 1, "hilbert step {a:?} -> {b:?} at {n}^3");
            }
        }
    }

    #[test]
    fn non_power_of_two_grids_cover_every_block_once() {
        // bucket fill ([6, 6, 8], [3, 2, 5]), packed sort ([1, 1, 7], [40, 2, 1]), pair sort ([2000, 1, 1])
        for b in [[3, 2, 5], [6, 6, 8], [1, 1, 7], [40, 2, 1], [2000, 1, 1]] {
            for c in [Curve::Hilbert, Curve::Morton] {
                let mut o = curve_order(b, c);
                o.sort_unstable();
                assert_eq!(o, (0..b.iter().product()).collect::<Vec<_>>());
            }
        }
    }

    /// All three ordering paths agree with a plain sort by key.
    #[test]
    fn curve_order_matches_sorting_by_key() {
        for b in [[5, 3, 4], [1, 1, 7], [40, 2, 1], [2000, 1, 1], [9, 9, 9]] {
            for c in [Curve::Hilbert, Curve::Morton] {
                let bits = bits_for(*b.iter().max().unwrap());
                let mut ids: Vec<usize> = (0..b.iter().product()).collect();
                ids.sort_by_key(|&id| {
                    let p = coords(id, b);
                    let p = [p[0] as u32, p[1] as u32, p[2] as u32];
                    match c {
                        Curve::Hilbert => hilbert_key(p, bits),
                        Curve::Morton => morton_key(p, bits),
                    }
                });
                assert_eq!(curve_order(b, c), ids, "{b:?} {c:?}");
            }
        }
    }
}
