//! METIS k-way partitioning of the block graph (`balance.strategy = "metis"`), then relabelling of the parts
//! so that as many blocks as possible keep their owner.
//!
//! - Vertex weights: the block weights scaled to integers with
//!   s = min(10⁶ / max weight, 10⁹ / total weight) (the largest block ~10⁶, the sum safely inside METIS'
//!   32-bit integers) and rounded; every block weighs at least 1 (METIS divides by the total, and a block
//!   of weight 0 costs nothing either way). All weights zero → all 1.
//! - Edge weights: eq. (17) (face b², edge b, corner 1; shared face area / edge length), at least 1.
//! - `ufactor = round((metis_imbalance − 1) · 1000)` (1.05 → 50), seed 1: the same input gives the same
//!   parts (METIS' random generator is global state, so the calls of all threads are serialised).
//! - P = 1: every block on process 0; P ≥ blocks: one block per part (no METIS call). If METIS fails the
//!   owners are kept (and a warning printed).
//! - Relabelling: the overlap (shared blocks) of every METIS part with every current owner; pairs are taken
//!   greedily by descending overlap (ties: lower part, then lower owner), each part and owner once; parts left
//!   over get the unused owner labels in increasing order. Greedy is a 1/2-approximation of the optimal
//!   assignment and exact whenever a permutation of the labels reproduces the owners.

use super::block_graph::BlockGraph;
use super::distribute::{Distribute, Distribution};
use metis::Idx;

/// Serialises the METIS calls of all threads.
static METIS_LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// The METIS strategy.
pub struct Metis {
    /// Allowed max/mean part weight.
    pub imbalance: f64,
}

impl Metis {
    /// METIS with the load imbalance tolerance `imbalance` (≥ 1).
    pub fn new(imbalance: f64) -> Self {
        Metis { imbalance }
    }

    /// METIS' ufactor for the tolerance (1.05 → 50).
    pub fn ufactor(&self) -> Idx {
        ((self.imbalance - 1.0).max(0.0) * 1000.0).round() as Idx
    }

    /// Raw METIS parts (labels 0..P, not relabelled); `None` when METIS fails.
    pub fn parts(&self, g: &BlockGraph, weights: &[f64], processes: usize) -> Option<Vec<u32>> {
        let n = g.len();
        if processes <= 1 || n == 0 {
            return Some(vec![0; n]);
        }
        if processes >= n {
            return Some((0..n as u32).collect());
        }
        let vwgt = integer_weights(weights);
        let mut xadj: Vec<Idx> = Vec::with_capacity(n + 1);
        let mut adjncy: Vec<Idx> = Vec::new();
        let mut adjwgt: Vec<Idx> = Vec::new();
        xadj.push(0);
        for list in &g.adj {
            for a in list {
                adjncy.push(a.block as Idx);
                adjwgt.push((a.weight.round() as Idx).max(1));
            }
            xadj.push(adjncy.len() as Idx);
        }
        let mut part: Vec<Idx> = vec![0; n];
        // METIS' random generator (GKlib) is global state: concurrent calls would interleave their
        // random streams and break determinism, so one call at a time.
        let _guard = METIS_LOCK.lock().unwrap_or_else(|e| e.into_inner());
        let res = metis::Graph::new(1, processes as Idx, &xadj, &adjncy)
            .map_err(|e| format!("{e}"))
            .and_then(|gr| {
                gr.set_vwgt(&vwgt)
                    .set_adjwgt(&adjwgt)
                    .set_option(metis::option::UFactor(self.ufactor()))
                    .set_option(metis::option::Seed(1))
                    .part_kway(&mut part)
                    .map_err(|e| format!("{e}"))
            });
        match res {
            Ok(_) => Some(part.into_iter().map(|p| p as u32).collect()),
            Err(e) => {
                eprintln!("warning: METIS partitioning failed ({e}); blocks stay where they are");
                None
            }
        }
    }
}

/// Block weights as METIS integers (see the module doc).
pub fn integer_weights(weights: &[f64]) -> Vec<Idx> {
    let max = weights.iter().copied().fold(0.0, f64::max);
    let sum: f64 = weights.iter().map(|w| w.max(0.0)).sum();
    if max <= 0.0 || !max.is_finite() {
        return vec![1; weights.len()];
    }
    let s = (1e6 / max).min(1e9 / sum);
    weights
        .iter()
        .map(|&w| ((w.max(0.0) * s).round() as Idx).max(1))
        .collect()
}

/// Relabels `parts` (labels 0..P) to the owner labels (0..P) they overlap most, greedily by descending
/// overlap (see the module doc).
pub fn relabel(parts: &[u32], owners: &[u32], processes: usize) -> Vec<u32> {
    let labels = processes.max(parts.iter().chain(owners).map(|&x| x as usize + 1).max().unwrap_or(0));
    let mut pairs: Vec<(u32, u32)> = parts.iter().copied().zip(owners.iter().copied()).collect();
    pairs.sort_unstable();
    let mut counts: Vec<(usize, u32, u32)> = Vec::new();
    for (i, &pr) in pairs.iter().enumerate() {
        if i > 0 && pairs[i - 1] == pr {
            counts.last_mut().expect("previous pair").0 += 1;
        } else {
            counts.push((1, pr.0, pr.1));
        }
    }
    // descending overlap; ties to the lower part, then the lower owner
    counts.sort_unstable_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    let mut map: Vec<Option<u32>> = vec![None; labels];
    let mut used = vec![false; labels];
    for &(_, p, o) in &counts {
        if map[p as usize].is_none() && !used[o as usize] {
            map[p as usize] = Some(o);
            used[o as usize] = true;
        }
    }
    let mut free = (0..labels as u32).filter(|&o| !used[o as usize]);
    for m in map.iter_mut() {
        if m.is_none() {
            *m = free.next();
        }
    }
    parts
        .iter()
        .map(|&p| map[p as usize].expect("a label for every part"))
        .collect()
}

impl Distribute for Metis {
    fn name(&self) -> &'static str {
        "metis"
    }

    fn distribute(&mut self, g: &BlockGraph, weights: &[f64], owners: &[u32], processes: usize) -> Distribution {
        let Some(parts) = self.parts(g, weights, processes) else {
            return Distribution {
                owners: owners.to_vec(),
                migrated_unrelabelled: Some(0),
            };
        };
        let raw = parts.iter().zip(owners).filter(|(a, b)| a != b).count();
        Distribution {
            owners: relabel(&parts, owners, processes),
            migrated_unrelabelled: Some(raw),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::balance::block_graph::closed_domain;
    use crate::metrics::edge_cut::edge_cut_mean;
    use crate::metrics::load::process_loads;
    use crate::util::hash::SplitMix;

    fn graph(blocks: [usize; 3]) -> BlockGraph {
        super::super::block_graph::closed_grid(blocks)
    }

    #[test]
    fn metis_stays_within_its_tolerance() {
        let g = graph([8, 8, 8]);
        let mut r = SplitMix(3);
        let w: Vec<f64> = (0..g.len()).map(|_| r.uniform(0.5, 1.5)).collect();
        let owners = vec![0u32; g.len()];
        let d = Metis::new(1.05).distribute(&g, &w, &owners, 8);
        let loads = process_loads(&w, &d.owners, 8);
        let mean = w.iter().sum::<f64>() / 8.0;
        let wmax = w.iter().copied().fold(0.0, f64::max);
        let max = loads.iter().copied().fold(0.0, f64::max);
        assert!(max <= 1.05 * mean + wmax, "max {max} mean {mean}");
        assert!(loads.iter().all(|&l| l > 0.0), "every process gets blocks: {loads:?}");
        // and a far better edge cut than random owners
        let random: Vec<u32> = (0..g.len()).map(|_| (r.next_u64() % 8) as u32).collect();
        let dom = closed_domain([8, 8, 8]);
        assert!(edge_cut_mean(&dom, &d.owners, 8) < 0.5 * edge_cut_mean(&dom, &random, 8));
    }

    #[test]
    fn relabelling_keeps_blocks_in_place() {
        let g = graph([8, 4, 4]);
        let w = vec![1.0; g.len()];
        let mut m = Metis::new(1.05);
        let parts = m.parts(&g, &w, 4).unwrap();
        // the current owners are the METIS parts under a permutation of the labels
        let perm = [2u32, 0, 3, 1];
        let owners: Vec<u32> = parts.iter().map(|&p| perm[p as usize]).collect();
        let d = m.distribute(&g, &w, &owners, 4);
        assert_eq!(d.owners, owners, "relabelled: nothing moves");
        assert!(d.migrated_unrelabelled.unwrap() > 0);
        assert_eq!(
            d.migrated_unrelabelled.unwrap(),
            parts.iter().zip(&owners).filter(|(a, b)| a != b).count()
        );
    }

    #[test]
    fn relabel_hand_cases() {
        // part 0 mostly on owner 1, part 1 mostly on owner 0
        assert_eq!(
            relabel(&[0, 0, 0, 1, 1, 1], &[1, 1, 0, 0, 0, 1], 2),
            vec![1, 1, 1, 0, 0, 0]
        );
        // more labels than overlaps: unused parts take the unused owners in order
        assert_eq!(relabel(&[0, 1, 2], &[2, 2, 2], 3), vec![2, 0, 1]);
    }

    #[test]
    fn small_and_degenerate_cases() {
        let g = graph([2, 2, 1]);
        let w = vec![1.0, 2.0, 0.0, 1.0];
        let mut m = Metis::new(1.05);
        assert_eq!(m.distribute(&g, &w, &[0, 0, 0, 0], 1).owners, vec![0; 4]);
        // more processes than blocks: every block alone, labels kept where possible
        let d = m.distribute(&g, &w, &[0, 1, 2, 3], 6);
        assert_eq!(d.owners, vec![0, 1, 2, 3]);
        assert_eq!(d.migrated_unrelabelled, Some(0));
        assert_eq!(m.ufactor(), 50);
        assert_eq!(integer_weights(&[0.0, 0.5, 1.0]), vec![1, 500_000, 1_000_000]);
        assert_eq!(integer_weights(&[0.0, 0.0]), vec![1, 1]);
        // large sums are scaled into 32-bit totals
        let big = integer_weights(&vec![1.0; 100_000]);
        assert!(big.iter().map(|&x| x as i64).sum::<i64>() <= 1_000_000_000);
    }
}
