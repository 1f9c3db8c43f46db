//! Load distribution strategies behind one trait (waLBerla's `blockforest/loadbalancing` policy classes are
//! the model): the block graph with the eq. (17) contact weights, and [`Distribute`] implementations for the
//! static assignment, curve splits ([`CurveSplit`]), diffusive balancing ([`super::diffusive::Diffusive`])
//! and METIS graph partitioning ([`super::graph_partition::Metis`]).

use super::curves::Curve;
use crate::config::{BalanceConfig, SplitKind, Strategy};

/// How two blocks touch (eq. 17 weights: face b², edge b, corner 1; shared face area / edge length for
/// non-cubic blocks).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Contact {
    /// A shared face.
    Face,
    /// A shared edge only.
    Edge,
    /// A shared corner only.
    Corner,
}

/// One neighbour of a block in the [`BlockGraph`].
#[derive(Clone, Copy, Debug)]
pub struct Adjacent {
    /// The neighbour's block id.
    pub block: usize,
    /// The strongest contact between the two blocks.
    pub contact: Contact,
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
    pub fn from_domain(d: &crate::domain::DomainSpec) -> Self {
        let n = d.num_blocks();
        let s = d.block_size;
        let mut adj = Vec::with_capacity(n);
        let mut coords = Vec::with_capacity(n);
        for id in 0..n {
            coords.push(d.coords(id));
            let mut list: Vec<Adjacent> = Vec::new();
            for off in crate::domain::NEIGHBOURS {
                let Some(nb) = d.neighbour(id, off) else { continue };
                if nb == id {
                    continue;
                }
                let zeros: Vec<usize> = (0..3).filter(|&a| off[a] == 0).collect();
                let (contact, weight) = match zeros.len() {
                    2 => (Contact::Face, (s[zeros[0]] * s[zeros[1]]) as f64),
                    1 => (Contact::Edge, s[zeros[0]] as f64),
                    _ => (Contact::Corner, 1.0),
                };
                match list.iter_mut().find(|a| a.block == nb) {
                    Some(a) => {
                        a.contact = a.contact.min(contact);
                        a.weight += weight;
                    }
                    None => list.push(Adjacent {
                        block: nb,
                        contact,
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

    /// Edge cut eq. (17) per process: the weights of all block pairs on different processes, each pair once,
    /// divided by `processes` (equals [`super::edge_cut_mean`]).
    pub fn edge_cut_mean(&self, owners: &[u32], processes: usize) -> f64 {
        let mut cut = 0.0;
        for (id, list) in self.adj.iter().enumerate() {
            for a in list {
                if a.block > id && owners[a.block] != owners[id] {
                    cut += a.weight;
                }
            }
        }
        cut / processes.max(1) as f64
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

/// Result of one distribution.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Distribution {
    /// The new owner process of every block.
    pub owners: Vec<u32>,
    /// Blocks that would move without METIS relabelling (None for other strategies).
    pub migrated_unrelabelled: Option<usize>,
}

/// A load distribution strategy: given the block graph, block weights, current owners and P, return new
/// owners. Deterministic: the same inputs give the same output (no thread or time dependence).
pub trait Distribute: Send {
    /// The strategy's name (`balance.strategy`).
    fn name(&self) -> &'static str;
    /// The new owner of every block.
    fn distribute(&mut self, g: &BlockGraph, weights: &[f64], owners: &[u32], processes: usize) -> Distribution;
}

/// `none`: every block stays where it is.
pub struct Static;

impl Distribute for Static {
    fn name(&self) -> &'static str {
        "none"
    }

    fn distribute(&mut self, _g: &BlockGraph, _weights: &[f64], owners: &[u32], _processes: usize) -> Distribution {
        Distribution {
            owners: owners.to_vec(),
            migrated_unrelabelled: None,
        }
    }
}

/// `hilbert` / `morton`: blocks in curve order, cut by `split` (see [`super::assign_with`]); the current
/// owners play no part.
pub struct CurveSplit {
    /// The curve.
    pub curve: Curve,
    /// How the curve order is cut.
    pub split: SplitKind,
}

impl Distribute for CurveSplit {
    fn name(&self) -> &'static str {
        match self.curve {
            Curve::Hilbert => "hilbert",
            Curve::Morton => "morton",
        }
    }

    fn distribute(&mut self, g: &BlockGraph, weights: &[f64], _owners: &[u32], processes: usize) -> Distribution {
        Distribution {
            owners: super::assign_with(g.grid, weights, processes, self.curve, self.split),
            migrated_unrelabelled: None,
        }
    }
}

/// The strategy of `cfg` (`none` returns the owners unchanged).
pub fn strategy(cfg: &BalanceConfig) -> Box<dyn Distribute> {
    let name = match cfg.strategy {
        Strategy::None => "none",
        Strategy::Hilbert => "hilbert",
        Strategy::Morton => "morton",
        Strategy::Diffusive => "diffusive",
        Strategy::Metis => "metis",
    };
    by_name(name, cfg).expect("every Strategy has a name")
}

/// Strategy by name: "none", "hilbert", "morton", "diffusive", "metis" (others → None), with the other
/// settings from `cfg`.
pub fn by_name(name: &str, cfg: &BalanceConfig) -> Option<Box<dyn Distribute>> {
    Some(match name {
        "none" => Box::new(Static),
        "hilbert" => Box::new(CurveSplit {
            curve: Curve::Hilbert,
            split: cfg.split,
        }),
        "morton" => Box::new(CurveSplit {
            curve: Curve::Morton,
            split: cfg.split,
        }),
        "diffusive" => Box::new(super::diffusive::Diffusive::new(
            cfg.diffusive_iterations,
            cfg.flow_iterations,
            cfg.diffusive_mode,
        )),
        "metis" => Box::new(super::graph_partition::Metis::new(cfg.metis_imbalance)),
        _ => return None,
    })
}

/// Per-process loads of an assignment.
pub fn process_loads(weights: &[f64], owners: &[u32], processes: usize) -> Vec<f64> {
    let mut load = vec![0.0; processes];
    for (w, &o) in weights.iter().zip(owners) {
        load[o as usize] += w;
    }
    load
}

/// Deterministic pseudo-random numbers for tests and benchmarks (splitmix64).
pub struct SplitMix(pub u64);

impl SplitMix {
    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// A uniform number in [lo, hi).
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// The cases of the balancing benchmark (`benches/balance.rs`, [`scale_table`]): (name, grid, P, strategy
/// name, split).
pub const SCALE_CASES: [(&str, [usize; 3], usize, &str, SplitKind); 4] = [
    (
        "hilbert keys + greedy split",
        [50, 50, 40],
        32,
        "hilbert",
        SplitKind::Greedy,
    ),
    (
        "hilbert keys + optimal split",
        [50, 50, 40],
        32,
        "hilbert",
        SplitKind::Optimal,
    ),
    ("diffusive (push)", [6, 6, 8], 32, "diffusive", SplitKind::Greedy),
    ("metis k-way + relabel", [6, 6, 8], 32, "metis", SplitKind::Greedy),
];

/// The inputs of one benchmark case: graph, weights in [0.5, 1.5) (fixed seed) and the Hilbert owners.
pub fn bench_case(grid: [usize; 3], processes: usize) -> (BlockGraph, Vec<f64>, Vec<u32>) {
    let d = crate::domain::DomainSpec {
        blocks: grid,
        block_size: [16, 16, 16],
        periodic: [false; 3],
    };
    let g = BlockGraph::from_domain(&d);
    let mut rng = SplitMix(42);
    let w: Vec<f64> = (0..g.len()).map(|_| rng.uniform(0.5, 1.5)).collect();
    let owners = super::assign(grid, &vec![1.0; g.len()], processes, Curve::Hilbert);
    (g, w, owners)
}

/// Times the balancing cases (curve keys + greedy / optimal split for 100 000 blocks, diffusive and METIS
/// for 288 blocks, P = 32) with `std::time::Instant`, median of 7 repeats, as a markdown table.
pub fn scale_table() -> String {
    let mut out = String::from("| case | blocks | P | milliseconds |\n|---|---:|---:|---:|\n");
    for (name, grid, p, strat, split) in SCALE_CASES {
        let (g, w, owners) = bench_case(grid, p);
        let cfg = BalanceConfig {
            split,
            ..BalanceConfig::default()
        };
        let mut times = Vec::new();
        for _ in 0..7 {
            let mut s = by_name(strat, &cfg).expect("known strategy");
            let t0 = std::time::Instant::now();
            let d = s.distribute(&g, &w, &owners, p);
            times.push(t0.elapsed().as_secs_f64() * 1e3);
            std::hint::black_box(d);
        }
        times.sort_by(f64::total_cmp);
        out.push_str(&format!(
            "| {name} | {} | {p} | {:.3} |\n",
            g.len(),
            times[times.len() / 2]
        ));
    }
    out
}

/// The block graph of a closed grid of 8³ blocks (for tests).
#[cfg(test)]
pub(crate) fn closed_grid(blocks: [usize; 3]) -> BlockGraph {
    BlockGraph::from_domain(&crate::domain::DomainSpec {
        blocks,
        block_size: [8, 8, 8],
        periodic: [false; 3],
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::domain::DomainSpec;

    fn random_owners(n: usize, p: usize, seed: u64) -> Vec<u32> {
        let mut r = SplitMix(seed);
        (0..n).map(|_| (r.next_u64() % p as u64) as u32).collect()
    }

    #[test]
    fn graph_edge_cut_equals_balance_edge_cut() {
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
                let a = g.edge_cut_mean(&o, 4);
                let b = super::super::edge_cut_mean(&d, &o, 4);
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
        let c: Vec<Contact> = g.adj[0].iter().map(|a| a.contact).collect();
        assert_eq!(c.iter().filter(|&&x| x == Contact::Face).count(), 3);
        assert_eq!(c.iter().filter(|&&x| x == Contact::Edge).count(), 3);
        assert_eq!(c.iter().filter(|&&x| x == Contact::Corner).count(), 1);
        for (id, list) in g.adj.iter().enumerate() {
            assert!(list.windows(2).all(|w| w[0].block < w[1].block));
            for a in list {
                assert_ne!(a.block, id);
                assert!(g.adj[a.block].iter().any(|b| b.block == id && b.weight == a.weight));
            }
        }
    }

    #[test]
    fn static_and_curve_strategies() {
        let d = DomainSpec {
            blocks: [4, 4, 2],
            block_size: [4, 4, 4],
            periodic: [false; 3],
        };
        let g = BlockGraph::from_domain(&d);
        let w: Vec<f64> = (0..g.len()).map(|i| 1.0 + (i % 3) as f64).collect();
        let owners = random_owners(g.len(), 4, 9);
        let cfg = BalanceConfig::default();
        assert_eq!(
            by_name("none", &cfg).unwrap().distribute(&g, &w, &owners, 4).owners,
            owners
        );
        let h = by_name("hilbert", &cfg).unwrap().distribute(&g, &w, &owners, 4);
        assert_eq!(h.owners, super::super::assign(d.blocks, &w, 4, Curve::Hilbert));
        assert!(h.migrated_unrelabelled.is_none());
        assert!(by_name("bogus", &cfg).is_none());
        for s in [
            Strategy::None,
            Strategy::Hilbert,
            Strategy::Morton,
            Strategy::Diffusive,
            Strategy::Metis,
        ] {
            let c = BalanceConfig {
                strategy: s,
                ..BalanceConfig::default()
            };
            assert_eq!(format!("{s:?}").to_lowercase(), strategy(&c).name());
        }
    }

    /// Every strategy gives the same owners for the same inputs, twice and from fresh instances.
    #[test]
    fn every_strategy_is_deterministic() {
        let d = DomainSpec {
            blocks: [6, 6, 8],
            block_size: [8, 8, 8],
            periodic: [true, false, false],
        };
        let g = BlockGraph::from_domain(&d);
        let mut r = SplitMix(7);
        let w: Vec<f64> = (0..g.len()).map(|_| r.uniform(0.2, 3.0)).collect();
        let owners = super::super::assign(d.blocks, &vec![1.0; g.len()], 8, Curve::Hilbert);
        for name in ["none", "hilbert", "morton", "diffusive", "metis"] {
            for mode in [crate::config::DiffusiveMode::Push, crate::config::DiffusiveMode::Pull] {
                let cfg = BalanceConfig {
                    diffusive_mode: mode,
                    ..BalanceConfig::default()
                };
                let mut s = by_name(name, &cfg).unwrap();
                let a = s.distribute(&g, &w, &owners, 8);
                let b = s.distribute(&g, &w, &owners, 8);
                let c = by_name(name, &cfg).unwrap().distribute(&g, &w, &owners, 8);
                assert_eq!(a, b, "{name}");
                assert_eq!(a, c, "{name}");
                assert_eq!(a.owners.len(), g.len());
                assert!(a.owners.iter().all(|&o| o < 8));
            }
        }
    }

    /// `cargo test --release --lib print_scale_table -- --ignored --nocapture`
    #[test]
    #[ignore = "timing table; run in release"]
    fn print_scale_table() {
        let t = scale_table();
        println!("{t}");
        assert_eq!(t.lines().count(), 2 + SCALE_CASES.len());
    }

    #[test]
    fn scale_table_lists_every_case() {
        // Only the format here (timings are for `blockflow bench balance` in release builds).
        let (g, w, o) = bench_case([6, 6, 8], 32);
        assert_eq!((g.len(), w.len(), o.len()), (288, 288, 288));
        assert!(w.iter().all(|&x| (0.5..1.5).contains(&x)));
    }
}
