//! The D3Q19 velocity set: directions, weights and opposite directions.
//!
//! Ordering: 0 is the rest direction; directions 2k-1 and 2k (k = 1..9) are opposite pairs, so
//! `OPP[q] = q + 1` for odd q and `q - 1` for even q > 0. The TRT kernel relies on this pairing.

/// Number of discrete velocities.
pub const Q: usize = 19;

/// Discrete velocities c_q (lattice units).
pub const C: [[i32; 3]; Q] = [
    [0, 0, 0],
    [1, 0, 0],
    [-1, 0, 0],
    [0, 1, 0],
    [0, -1, 0],
    [0, 0, 1],
    [0, 0, -1],
    [1, 1, 0],
    [-1, -1, 0],
    [1, -1, 0],
    [-1, 1, 0],
    [1, 0, 1],
    [-1, 0, -1],
    [1, 0, -1],
    [-1, 0, 1],
    [0, 1, 1],
    [0, -1, -1],
    [0, 1, -1],
    [0, -1, 1],
];

/// Lattice weights w_q of eq. (3): 1/3 at rest, 1/18 along the axes, 1/36 along the face diagonals.
pub const W: [f64; Q] = [
    1.0 / 3.0,
    1.0 / 18.0,
    1.0 / 18.0,
    1.0 / 18.0,
    1.0 / 18.0,
    1.0 / 18.0,
    1.0 / 18.0,
    1.0 / 36.0,
    1.0 / 36.0,
    1.0 / 36.0,
    1.0 / 36.0,
    1.0 / 36.0,
    1.0 / 36.0,
    1.0 / 36.0,
    1.0 / 36.0,
    1.0 / 36.0,
    1.0 / 36.0,
    1.0 / 36.0,
    1.0 / 36.0,
];

/// Index of the opposite direction: c_OPP[q] = -c_q.
pub const OPP: [usize; Q] = [0, 2, 1, 4, 3, 6, 5, 8, 7, 10, 9, 12, 11, 14, 13, 16, 15, 18, 17];

/// Speed of sound squared, c_s^2 = 1/3 (lattice units).
pub const CS2: f64 = 1.0 / 3.0;

/// The directions q that carry data from a ghost cell at offset `d` (each component in {-1, 0, 1}, not all
/// zero) into the block: those with c_q,a = -d_a on every axis a where d_a != 0. Five for a face, one for an
/// edge, none for a corner. These are the only PDFs a ghost exchange has to copy.
pub fn crossing_directions(d: [i32; 3]) -> Vec<usize> {
    (1..Q)
        .filter(|&q| (0..3).all(|a| d[a] == 0 || C[q][a] == -d[a]))
        .collect()
}

#[cfg(test)]
// Direction and axis indices name lattice vectors here, as in the equations.
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::*;

    #[test]
    fn weights_and_moments() {
        let s: f64 = W.iter().sum();
        assert!((s - 1.0).abs() < 1e-15);
        // second moment: sum w c_a c_b = c_s^2 delta_ab; odd moments vanish.
        for a in 0..3 {
            let m1: f64 = (0..Q).map(|q| W[q] * C[q][a] as f64).sum();
            assert!(m1.abs() < 1e-16);
            for b in 0..3 {
                let m2: f64 = (0..Q).map(|q| W[q] * (C[q][a] * C[q][b]) as f64).sum();
                let want = if a == b { CS2 } else { 0.0 };
                assert!((m2 - want).abs() < 1e-15);
            }
        }
        for q in 0..Q {
            for a in 0..3 {
                assert_eq!(C[OPP[q]][a], -C[q][a]);
            }
        }
    }

    #[test]
    fn crossing_counts() {
        assert_eq!(crossing_directions([1, 0, 0]).len(), 5);
        assert_eq!(crossing_directions([0, -1, 0]).len(), 5);
        assert_eq!(crossing_directions([1, -1, 0]), vec![10]); // c = (-1, 1, 0)
        assert_eq!(crossing_directions([1, 1, 1]).len(), 0);
    }
}
