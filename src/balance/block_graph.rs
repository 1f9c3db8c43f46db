//! The block graph the distribution strategies work on: blocks, their coordinates and their neighbours
//! with the eq. (17) weight of each contact.

use crate::metrics::edge_cut::{touch, Touch};
use crate::physics::domain::{DomainSpec, NEIGHBOURS};

/// One neighbour of a block in the [`BlockGraph`].
#[derive(Clone, Copy, Debug)]
pub struct Adjacent {
    /// The neighbour's block id.
    pub block: usize,
    /// The strongest contact between the two blocks.
    pub touch: Touch,
    /// Eq. (17) weight of the pair: summed over every offset that reaches the neighbour (on a periodic axis
    /// of one or two blocks a neighbour is reached through more than one offset).
    pub weight: f64,
}

/// The block graph: blocks (ids x fastest over `grid`), their coordinates and neighbours (26-neighbourhood,
/// periodic axes wrap, no self edges, each neighbour once, sorted by block id).
pub struct BlockGraph {
    /// Blocks per axis.
    pub grid: [usize; 3],
    /// Block coordinates by block id.
    pub coords: Vec<[usize; 3]>,
    /// Neighbours by block id.
    pub adj: Vec<Vec<Adjacent>>,
}

impl BlockGraph {
    /// The block graph of a domain.
    pub fn from_domain(d: &DomainSpec) -> Self {
        let n = d.num_blocks();
        let s = d.block_size;
        let mut adj = Vec::with_capacity(n);
        let mut coords = Vec::with_capacity(n);
        for id in 0..n {
            coords.push(d.coords(id));
            let mut list: Vec<Adjacent> = Vec::new();
            for off in NEIGHBOURS {
                let Some(nb) = d.neighbour(id, off) else { continue };
                if nb == id {
                    continue;
                }
                let (touch, weight) = touch(s, off);
                match list.iter_mut().find(|a| a.block == nb) {
                    Some(a) => {
                        a.touch = a.touch.min(touch);
                        a.weight += weight;
                    }
                    None => list.push(Adjacent {
                        block: nb,
                        touch,
                        weight,
                    }),
                }
            }
            list.sort_by_key(|a| a.block);
            adj.push(list);
        }
        BlockGraph {
            grid: d.blocks,
            coords,
            adj,
        }
    }

    /// Number of blocks.
    pub fn len(&self) -> usize {
        self.adj.len()
    }

    /// Whether the graph has no block.
    pub fn is_empty(&self) -> bool {
        self.adj.is_empty()
    }

    /// The neighbour processes of every process: those owning a block adjacent to one of its blocks (sorted,
    /// without the process itself).
    pub fn process_neighbours(&self, owners: &[u32], processes: usize) -> Vec<Vec<usize>> {
        let mut nb: Vec<Vec<usize>> = vec![Vec::new(); processes];
        for (id, list) in self.adj.iter().enumerate() {
            let p = owners[id] as usize;
            for a in list {
                let q = owners[a.block] as usize;
                if q != p {
                    nb[p].push(q);
                }
            }
        }
        for v in nb.iter_mut() {
            v.sort_unstable();
            v.dedup();
        }
        nb
    }
}

/// A closed grid of blocks of 8³ cells (for tests).
#[cfg(test)]
pub(crate) fn closed_domain(blocks: [usize; 3]) -> DomainSpec {
    DomainSpec {
        blocks,
        block_size: [8, 8, 8],
        periodic: [false; 3],
    }
}

/// The block graph of [`closed_domain`] (for tests).
#[cfg(test)]
pub(crate) fn closed_grid(blocks: [usize; 3]) -> BlockGraph {
    BlockGraph::from_domain(&closed_domain(blocks))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::util::hash::SplitMix;

    fn random_owners(n: usize, p: usize, seed: u64) -> Vec<u32> {
        let mut r = SplitMix(seed);
        (0..n).map(|_| (r.next_u64() % p as u64) as u32).collect()
    }

    #[test]
    fn graph_weights_sum_to_the_edge_cut() {
        for d in [
            DomainSpec {
                blocks: [4, 3, 5],
                block_size: [8, 6, 4],
                periodic: [true, false, true],
            },
            DomainSpec {
                blocks: [5, 4, 3],
                block_size: [10, 10, 10],
                periodic: [false; 3],
            },
            // two blocks on a periodic axis: neighbours through two offsets
            DomainSpec {
                blocks: [2, 3, 1],
                block_size: [4, 4, 4],
                periodic: [true, true, true],
            },
        ] {
            let g = BlockGraph::from_domain(&d);
            assert_eq!(g.len(), d.num_blocks());
            for seed in 0..5 {
                let o = random_owners(g.len(), 4, seed);
                let mut a = 0.0;
                for (id, list) in g.adj.iter().enumerate() {
                    for x in list.iter().filter(|x| x.block > id && o[x.block] != o[id]) {
                        a += x.weight;
                    }
                }
                let a = a / 4.0;
                let b = crate::metrics::edge_cut::edge_cut_mean(&d, &o, 4);
                assert!((a - b).abs() <= 1e-9 * b.max(1.0), "{d:?}: {a} vs {b}");
                assert!(a > 0.0);
            }
        }
    }

    #[test]
    fn graph_neighbours_are_sorted_unique_and_symmetric() {
        let d = DomainSpec {
            blocks: [3, 3, 3],
            block_size: [4, 4, 4],
            periodic: [false; 3],
        };
        let g = BlockGraph::from_domain(&d);
        // centre block touches all 26
        assert_eq!(g.adj[13].len(), 26);
        // corner block: 3 faces, 3 edges, 1 corner
        let c: Vec<Touch> = g.adj[0].iter().map(|a| a.touch).collect();
        assert_eq!(c.iter().filter(|&&x| x == Touch::Face).count(), 3);
        assert_eq!(c.iter().filter(|&&x| x == Touch::Edge).count(), 3);
        assert_eq!(c.iter().filter(|&&x| x == Touch::Corner).count(), 1);
        for (id, list) in g.adj.iter().enumerate() {
            assert!(list.windows(2).all(|w| w[0].block < w[1].block));
            for a in list {
                assert_ne!(a.block, id);
                assert!(g.adj[a.block].iter().any(|b| b.block == id && b.weight == a.weight));
            }
        }
    }
}
