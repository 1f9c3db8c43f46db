//! Diffusive load balancing (`balance.strategy = "diffusive"`), modelled on waLBerla's
//! `DynamicDiffusionBalance` (blockforest/loadbalancing/DynamicDiffusive.h; Schornbaum & Rüde 2018) with
//! the block graph of eq. (17) standing in for the block forest.
//!
//! A process knows only its neighbour processes (those owning a block adjacent to one of its blocks) plus
//! two global numbers, the average process load and the largest block weight. One *main iteration*:
//!
//! 1. Process loads; the process load limit is max(average load, largest block weight) (waLBerla's
//!    `defineProcessWeightLimitByMultipleOfMaxBlockWeight(false)`; its default, the smallest multiple of
//!    the largest block weight ≥ the average, tolerates up to one block weight above the average, about
//!    15 % with the ~10 blocks per process here, and stops far too early). When no process is above the
//!    limit (by more than a relative 10⁻¹²: early abort) nothing moves and the balancing step ends.
//! 2. `flow_iterations` Jacobi diffusion sweeps over the process graph with
//!    α_ij = min(1/(deg_i+1), 1/(deg_j+1)): f = α_ij (l_i − l_j) is added to the flow of edge i→j and
//!    taken from l_i, from the loads of the previous sweep.
//! 3. *push*: every process scales its positive edge flows so that they sum to
//!    max(load − limit + inflow, 0) (at most its load; waLBerla's `adaptOutflowWithGlobalInformation`),
//!    then repeatedly picks the neighbour with the largest remaining flow and sends it one block whose
//!    weight is at most the remaining total outflow; when no block qualifies the edge is closed.
//!    *pull*: every process with inflow scales its negative edge flows to sum to
//!    max(limit − load + outflow, 0) and takes single blocks from the neighbour with the largest remaining
//!    inflow the same way.
//!
//! The block chosen on an edge: among the blocks that touch the receiving process (any contact) the one
//! whose weight is closest to the remaining edge flow, ties to the stronger contact (face, edge, corner),
//! then to more contacts with the receiver, then to the lower id; only when none of those qualifies, a block
//! on the process boundary, and last an inner block (waLBerla orders the candidates the same way but uses
//! the order only to break ties of the weight match; preferring touching blocks keeps the processes' block
//! sets compact). A process never gives away its last block, and a block only moves when the receiver
//! stays lighter than the sender (l_r + w < l_s with the loads as they stand, the moves of the main
//! iteration applied in process order; not in waLBerla): every move lowers Σ l², so blocks cannot oscillate.
//! A block moves at most once (one hop) per main iteration, and all contacts and candidate sets are those
//! at the start of the main iteration, so the moves of all processes are simultaneous as with MPI.
//! Processes and blocks are visited in id order and ties go to the lower id: the result is deterministic.
//! `diffusive_iterations` main iterations make one balancing step. A process without blocks has no
//! neighbours and receives nothing.

use super::block_graph::BlockGraph;
use super::distribute::{Distribute, Distribution};
use crate::config::DiffusiveMode;
use crate::metrics::edge_cut::Touch;
use crate::metrics::load::process_loads;

/// The diffusive strategy.
pub struct Diffusive {
    /// Main iterations per balancing step.
    pub iterations: usize,
    /// Diffusion sweeps per main iteration.
    pub flow_iterations: usize,
    /// Who picks the blocks.
    pub mode: DiffusiveMode,
}

/// Relative tolerance of the weight comparisons.
const EPS: f64 = 1e-12;

/// Where a candidate block stands relative to the receiving process (smaller is better).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Tier {
    /// Touches the receiver: best contact, and more contacts first (stored negated).
    Touching(Touch, i64),
    /// Touches some other process.
    Boundary,
    /// Only touches blocks of its own process.
    Inner,
}

impl Diffusive {
    /// A diffusive strategy with `iterations` main iterations of `flow_iterations` diffusion sweeps.
    pub fn new(iterations: usize, flow_iterations: usize, mode: DiffusiveMode) -> Self {
        Diffusive {
            iterations,
            flow_iterations,
            mode,
        }
    }

    /// The process load limit, max(average load, largest block weight); `None` when no process is above
    /// it (nothing to do).
    pub fn limit(loads: &[f64], weights: &[f64]) -> Option<f64> {
        let max_block = weights.iter().copied().fold(0.0, f64::max);
        if loads.is_empty() || max_block <= 0.0 {
            return None;
        }
        let avg = loads.iter().sum::<f64>() / loads.len() as f64;
        let limit = avg.max(max_block);
        loads.iter().any(|&l| l > limit * (1.0 + EPS)).then_some(limit)
    }

    /// The accumulated diffusion flow on every process edge (`flow[i][k]` from process i to `nb[i][k]`).
    fn flows(&self, loads: &[f64], nb: &[Vec<usize>]) -> Vec<Vec<f64>> {
        let alpha: Vec<Vec<f64>> = nb
            .iter()
            .map(|list| {
                let di = 1.0 / (list.len() as f64 + 1.0);
                list.iter().map(|&j| di.min(1.0 / (nb[j].len() as f64 + 1.0))).collect()
            })
            .collect();
        let mut flow: Vec<Vec<f64>> = nb.iter().map(|l| vec![0.0; l.len()]).collect();
        let mut local = loads.to_vec();
        for _ in 0..self.flow_iterations {
            let prev = local.clone();
            for (i, list) in nb.iter().enumerate() {
                for (k, &j) in list.iter().enumerate() {
                    let f = alpha[i][k] * (prev[i] - prev[j]);
                    flow[i][k] += f;
                    local[i] -= f;
                }
            }
        }
        flow
    }

    /// One main iteration on `owners` (changed in place); returns the number of blocks moved.
    pub fn step(&self, g: &BlockGraph, weights: &[f64], owners: &mut [u32], processes: usize) -> usize {
        let loads = process_loads(weights, owners, processes);
        let Some(limit) = Self::limit(&loads, weights) else {
            return 0;
        };
        let old = owners.to_vec();
        let nb = g.process_neighbours(&old, processes);
        let mut flow = self.flows(&loads, &nb);
        let mut blocks: Vec<Vec<usize>> = vec![Vec::new(); processes];
        for (b, &o) in old.iter().enumerate() {
            blocks[o as usize].push(b);
        }
        let mut left: Vec<usize> = blocks.iter().map(Vec::len).collect();
        let mut now = loads.clone();
        let mut moved = 0;
        for i in 0..processes {
            let out: f64 = flow[i].iter().map(|&f| f.max(0.0)).sum();
            let inn: f64 = flow[i].iter().map(|&f| f.min(0.0)).sum();
            match self.mode {
                DiffusiveMode::Push => {
                    let corrected = (loads[i] - limit - inn).max(0.0);
                    let scale = if out > 0.0 { corrected / out } else { 0.0 };
                    flow[i].iter_mut().filter(|f| **f > 0.0).for_each(|f| *f *= scale);
                    let mut outflow = corrected.min(loads[i]);
                    while outflow > 0.0 {
                        let Some((k, edge)) = best_edge(&flow[i], 1.0) else {
                            break;
                        };
                        let j = nb[i][k];
                        // the receiver must stay lighter than the sender
                        let budget = (outflow * (1.0 + EPS)).min((now[i] - now[j]) * (1.0 - EPS));
                        let pick = (left[i] > 1)
                            .then(|| choose(g, weights, &old, owners, &blocks[i], j, edge, budget))
                            .flatten();
                        match pick {
                            Some(b) => {
                                owners[b] = j as u32;
                                now[i] -= weights[b];
                                now[j] += weights[b];
                                flow[i][k] -= weights[b];
                                outflow -= weights[b];
                                left[i] -= 1;
                                moved += 1;
                            }
                            None => flow[i][k] = 0.0,
                        }
                    }
                }
                DiffusiveMode::Pull => {
                    let corrected = (limit - loads[i] + out).max(0.0);
                    let scale = if inn < 0.0 { corrected / -inn } else { 0.0 };
                    flow[i].iter_mut().filter(|f| **f < 0.0).for_each(|f| *f *= scale);
                    let mut inflow = corrected;
                    while inflow > 0.0 {
                        let Some((k, edge)) = best_edge(&flow[i], -1.0) else {
                            break;
                        };
                        let j = nb[i][k];
                        let budget = (inflow * (1.0 + EPS)).min((now[j] - now[i]) * (1.0 - EPS));
                        let pick = (left[j] > 1)
                            .then(|| choose(g, weights, &old, owners, &blocks[j], i, edge, budget))
                            .flatten();
                        match pick {
                            Some(b) => {
                                owners[b] = i as u32;
                                now[j] -= weights[b];
                                now[i] += weights[b];
                                flow[i][k] += weights[b];
                                inflow -= weights[b];
                                left[j] -= 1;
                                moved += 1;
                            }
                            None => flow[i][k] = 0.0,
                        }
                    }
                }
            }
        }
        moved
    }
}

/// The edge with the largest `sign * flow` (first on ties) and that amount, if positive.
fn best_edge(flow: &[f64], sign: f64) -> Option<(usize, f64)> {
    let mut best: Option<(usize, f64)> = None;
    for (k, &f) in flow.iter().enumerate() {
        let v = sign * f;
        if v > 0.0 && best.is_none_or(|(_, b)| v > b) {
            best = Some((k, v));
        }
    }
    best
}

/// The block of `own` (blocks of one process at the start of the main iteration, `old` owners) to move to
/// process `to`: not moved yet this iteration, weight ≤ `budget` (> 0); see the module doc for the order.
#[allow(clippy::too_many_arguments)]
fn choose(
    g: &BlockGraph,
    weights: &[f64],
    old: &[u32],
    now: &[u32],
    own: &[usize],
    to: usize,
    edge: f64,
    budget: f64,
) -> Option<usize> {
    let mut best: Option<(Tier, f64, usize)> = None;
    for &b in own {
        let w = weights[b];
        if now[b] != old[b] || w > budget || budget <= 0.0 {
            continue;
        }
        let from = old[b];
        let (mut contact, mut count, mut boundary) = (None::<Touch>, 0i64, false);
        for a in &g.adj[b] {
            let o = old[a.block];
            if o as usize == to {
                contact = Some(contact.map_or(a.touch, |c| c.min(a.touch)));
                count += 1;
            } else if o != from {
                boundary = true;
            }
        }
        let tier = match contact {
            Some(c) => Tier::Touching(c, -count),
            None if boundary => Tier::Boundary,
            None => Tier::Inner,
        };
        let class = |t: Tier| match t {
            Tier::Touching(..) => 0,
            Tier::Boundary => 1,
            Tier::Inner => 2,
        };
        let diff = (edge - w).abs();
        let better = match best {
            None => true,
            Some((bt, bd, _)) => (class(tier), diff, tier) < (class(bt), bd, bt),
        };
        if better {
            best = Some((tier, diff, b));
        }
    }
    best.map(|(_, _, b)| b)
}

impl Distribute for Diffusive {
    fn name(&self) -> &'static str {
        "diffusive"
    }

    fn distribute(&mut self, g: &BlockGraph, weights: &[f64], owners: &[u32], processes: usize) -> Distribution {
        let mut o = owners.to_vec();
        for _ in 0..self.iterations {
            if self.step(g, weights, &mut o, processes) == 0 {
                break;
            }
        }
        Distribution {
            owners: o,
            migrated_unrelabelled: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn graph(blocks: [usize; 3]) -> BlockGraph {
        super::super::block_graph::closed_grid(blocks)
    }

    fn max_load(w: &[f64], o: &[u32], p: usize) -> f64 {
        process_loads(w, o, p).into_iter().fold(0.0, f64::max)
    }

    /// 16 blocks in a row, 4 processes of 4 blocks; process 0's blocks weigh 3.
    fn chain() -> (BlockGraph, Vec<f64>, Vec<u32>) {
        let g = graph([16, 1, 1]);
        let w: Vec<f64> = (0..16).map(|b| if b < 4 { 3.0 } else { 1.0 }).collect();
        let o: Vec<u32> = (0..16).map(|b| (b / 4) as u32).collect();
        (g, w, o)
    }

    /// 8x8 blocks in 2x2 tiles of a 4x4 process grid; process 0's blocks weigh 4.
    fn grid2d() -> (BlockGraph, Vec<f64>, Vec<u32>) {
        let g = graph([8, 8, 1]);
        let o: Vec<u32> = g.coords.iter().map(|c| ((c[0] / 2) + 4 * (c[1] / 2)) as u32).collect();
        let w: Vec<f64> = o.iter().map(|&p| if p == 0 { 4.0 } else { 1.0 }).collect();
        (g, w, o)
    }

    #[test]
    fn blocks_move_only_between_neighbour_processes() {
        for mode in [DiffusiveMode::Push, DiffusiveMode::Pull] {
            for (g, w, o, p) in [
                {
                    let (g, w, o) = chain();
                    (g, w, o, 4)
                },
                {
                    let (g, w, o) = grid2d();
                    (g, w, o, 16)
                },
            ] {
                let mut cur = o;
                let mut total = 0;
                for _ in 0..10 {
                    let nb = g.process_neighbours(&cur, p);
                    let next = Diffusive::new(1, 15, mode).distribute(&g, &w, &cur, p).owners;
                    for b in 0..g.len() {
                        if next[b] != cur[b] {
                            total += 1;
                            assert!(
                                nb[cur[b] as usize].contains(&(next[b] as usize)),
                                "{mode:?}: block {b} {} -> {}",
                                cur[b],
                                next[b]
                            );
                        }
                    }
                    // nobody is emptied
                    assert!((0..p as u32).all(|q| next.contains(&q)));
                    cur = next;
                }
                assert!(total > 0, "{mode:?}: something moved");
            }
        }
    }

    #[test]
    fn chain_of_processes_reduces_the_heaviest_load() {
        for mode in [DiffusiveMode::Push, DiffusiveMode::Pull] {
            let (g, w, o) = chain();
            let before = max_load(&w, &o, 4);
            assert_eq!(before, 12.0);
            let after = Diffusive::new(20, 15, mode).distribute(&g, &w, &o, 4).owners;
            let m = max_load(&w, &after, 4);
            // average 6, largest block 3: the limit is 6
            assert!(m < before && m <= 9.0, "{mode:?}: {m}");
        }
    }

    #[test]
    fn grid_of_processes_reduces_the_heaviest_load() {
        for mode in [DiffusiveMode::Push, DiffusiveMode::Pull] {
            let (g, w, o) = grid2d();
            let before = max_load(&w, &o, 16);
            assert_eq!(before, 16.0);
            let after = Diffusive::new(20, 15, mode).distribute(&g, &w, &o, 16).owners;
            let m = max_load(&w, &after, 16);
            // pull never fills a receiver beyond the limit (average 4.75) by more than its own outflow, so
            // the blocks of weight 4 mostly stay; push spreads them to the neighbours
            let bound = if mode == DiffusiveMode::Push { 8.0 } else { 12.0 };
            assert!(m <= bound, "{mode:?}: {m}");
        }
    }

    #[test]
    fn balanced_loads_move_nothing() {
        let g = graph([16, 1, 1]);
        let w = vec![1.0; 16];
        let o: Vec<u32> = (0..16).map(|b| (b / 4) as u32).collect();
        for mode in [DiffusiveMode::Push, DiffusiveMode::Pull] {
            assert_eq!(Diffusive::new(20, 15, mode).distribute(&g, &w, &o, 4).owners, o);
        }
        // equal loads from unequal blocks: nothing moves
        let w: Vec<f64> = (0..16).map(|b| if b % 4 == 0 { 1.5 } else { 0.5 }).collect();
        assert_eq!(Diffusive::limit(&process_loads(&w, &o, 4), &w), None);
        assert_eq!(
            Diffusive::new(20, 15, DiffusiveMode::Push)
                .distribute(&g, &w, &o, 4)
                .owners,
            o
        );
    }

    #[test]
    fn limit_is_the_average_or_the_largest_block() {
        assert_eq!(Diffusive::limit(&[12.0, 4.0, 4.0, 4.0], &[3.0, 1.0]), Some(6.0));
        assert_eq!(Diffusive::limit(&[7.0, 5.0], &[2.0]), Some(6.0));
        assert_eq!(Diffusive::limit(&[7.0, 1.0], &[7.0, 1.0]), None);
        assert_eq!(Diffusive::limit(&[6.0, 6.0], &[2.0]), None);
        assert_eq!(Diffusive::limit(&[0.0, 0.0], &[0.0]), None);
    }
}
