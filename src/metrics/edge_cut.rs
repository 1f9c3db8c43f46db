//! The edge cut of eq. (17): neighbouring blocks on different processes weighted by how they touch (face
//! b², edge b, corner 1; the shared face area and edge length for non-cubic blocks).

use crate::physics::domain::{DomainSpec, NEIGHBOURS};

/// How two neighbouring blocks touch.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Touch {
    /// A shared face.
    Face,
    /// A shared edge only.
    Edge,
    /// A shared corner only.
    Corner,
}

/// How a block and its neighbour at offset `off` touch, and the eq. (17) weight of that contact for
/// blocks of `block_size` cells.
pub fn touch(block_size: [usize; 3], off: [i32; 3]) -> (Touch, f64) {
    let s = block_size;
    let zeros: Vec<usize> = (0..3).filter(|&a| off[a] == 0).collect();
    match zeros.len() {
        2 => (Touch::Face, (s[zeros[0]] * s[zeros[1]]) as f64),
        1 => (Touch::Edge, s[zeros[0]] as f64),
        _ => (Touch::Corner, 1.0),
    }
}

/// Edge cut eq. (17) of an assignment: the weight of every contact between blocks of different
/// processes, each block pair once per offset that joins them, divided by `processes` (the mean per
/// process the paper reports).
pub fn edge_cut_mean(d: &DomainSpec, owners: &[u32], processes: usize) -> f64 {
    let mut cut = 0.0;
    for id in 0..d.num_blocks() {
        for off in NEIGHBOURS {
            if let Some(n) = d.neighbour(id, off) {
                if n > id && owners[n] != owners[id] {
                    cut += touch(d.block_size, off).1;
                }
            }
        }
    }
    cut / processes.max(1) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn two_blocks_on_two_processes_cut_one_face() {
        let d = DomainSpec {
            blocks: [2, 1, 1],
            block_size: [4, 5, 6],
            periodic: [false; 3],
        };
        assert_eq!(edge_cut_mean(&d, &[0, 1], 2), 30.0 / 2.0);
        assert_eq!(edge_cut_mean(&d, &[0, 0], 2), 0.0);
        assert_eq!(touch([4, 5, 6], [1, 1, 0]), (Touch::Edge, 6.0));
        assert_eq!(touch([4, 5, 6], [1, 1, -1]), (Touch::Corner, 1.0));
    }
}
