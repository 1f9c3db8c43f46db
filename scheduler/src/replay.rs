//! Modeled time and load imbalance.
//!
//! The load imbalance of the paper's eq. (18), `LI = max_p m(p) / mean_p m(p) - 1`, over per-process
//! workloads, and a *modeled* time to solution: the task graph replayed with measured task durations on
//! `P × T` dedicated cores by event-driven list scheduling. The modeled time is meaningful even when
//! `P × T` exceeds the machine's cores, which is how large process counts are studied on a small node.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use crate::graph::{TaskGraph, TaskId};

/// Load imbalance of eq. (18): `max_p load / mean_p load - 1`; 0 for an empty or all-zero input (and for an
/// input whose mean is not a positive finite number).
pub fn load_imbalance(loads: &[f64]) -> f64 {
    if loads.is_empty() {
        return 0.0;
    }
    let mean = loads.iter().sum::<f64>() / loads.len() as f64;
    if !(mean.is_finite() && mean > 0.0) {
        return 0.0;
    }
    let max = loads.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    max / mean - 1.0
}

/// Per-process workload: the loads of `(owner, load)` items summed by owner process (`len = processes`),
/// e.g. task durations by the task's owner or block weights by the block's owner. An owner `>= processes`
/// counts for process `owner % processes`. Empty for `processes == 0`.
///
/// The items are added in iteration order, one `+=` per item onto its process's running sum starting from
/// `0.0`: the iteration order is the summation order, so the same items in the same order give bitwise
/// the same sums (callers rely on this for reproducible results).
pub fn process_loads(items: impl IntoIterator<Item = (u32, f64)>, processes: usize) -> Vec<f64> {
    let mut loads = vec![0.0; processes];
    if processes == 0 {
        return loads;
    }
    for (owner, load) in items {
        loads[owner as usize % processes] += load;
    }
    loads
}

/// Dependency-respecting list-scheduling replay; returns the makespan in ns, the modeled time on
/// `processes × threads_per_process` dedicated cores.
///
/// Every task `t` takes `durations_ns[t]` (0 if missing). A task may start once all its predecessors have
/// finished and a core is free: with `global = false` only one of the `threads_per_process` cores of its
/// owner process (owner `>= processes` maps to `owner % processes`), with `global = true` any of the
/// `P × T` cores. Among the ready tasks of a pool of cores, the earliest ready time goes first, ties by
/// task id, so the result is deterministic. `processes` and `threads_per_process` of 0 count as 1.
/// Event-driven with binary heaps: O((n + e) log n) for n tasks and e edges.
pub fn replay_makespan(
    graph: &TaskGraph,
    durations_ns: &[u64],
    processes: usize,
    threads_per_process: usize,
    global: bool,
) -> u64 {
    replay_mapped(
        graph,
        durations_ns,
        |t| graph.spec(t).owner,
        processes,
        threads_per_process,
        global,
        |_, _| 0,
    )
}

/// [`replay_makespan`] with the owner of every task given by `owner_of` (a counterfactual assignment of
/// the same graph) and a delay on every edge: successor `s` of `t` may start no earlier than `t`'s finish
/// plus `delay(t, s)` ns (a message between processes). Returns the makespan in ns.
pub fn replay_mapped(
    graph: &TaskGraph,
    durations_ns: &[u64],
    owner_of: impl Fn(TaskId) -> u32,
    processes: usize,
    threads_per_process: usize,
    global: bool,
    delay: impl Fn(TaskId, TaskId) -> u64,
) -> u64 {
    let processes = processes.max(1);
    let threads = threads_per_process.max(1);
    let (pools, cores_per_pool) = if global {
        (1, processes.saturating_mul(threads))
    } else {
        (processes, threads)
    };
    let pool_of = |t: TaskId| {
        if global {
            0
        } else {
            owner_of(t) as usize % processes
        }
    };
    let duration = |t: TaskId| durations_ns.get(t as usize).copied().unwrap_or(0);

    let mut remaining: Vec<u32> = graph.indegrees().to_vec();
    let mut ready_at: Vec<u64> = vec![0; graph.len()];
    let mut free: Vec<usize> = vec![cores_per_pool; pools];
    // Ready tasks per pool, smallest (ready time, id) first.
    let mut ready: Vec<BinaryHeap<Reverse<(u64, TaskId)>>> = vec![BinaryHeap::new(); pools];
    // Tasks whose predecessors are done but whose messages are still in flight, earliest arrival first.
    let mut pending: BinaryHeap<Reverse<(u64, TaskId)>> = BinaryHeap::new();
    // Running tasks, smallest (finish time, id) first.
    let mut running: BinaryHeap<Reverse<(u64, TaskId)>> = BinaryHeap::new();
    let mut dirty: Vec<usize> = Vec::new();
    let mut is_dirty = vec![false; pools];
    let mark = |pool: usize, dirty: &mut Vec<usize>, is_dirty: &mut [bool]| {
        if !is_dirty[pool] {
            is_dirty[pool] = true;
            dirty.push(pool);
        }
    };

    for &t in graph.roots() {
        let pool = pool_of(t);
        ready[pool].push(Reverse((0, t)));
        mark(pool, &mut dirty, &mut is_dirty);
    }
    let mut now = 0u64;
    let mut makespan = 0u64;
    loop {
        // Start whatever can start now, pool by pool.
        for pool in dirty.drain(..) {
            is_dirty[pool] = false;
            while free[pool] > 0 {
                let Some(Reverse((_, t))) = ready[pool].pop() else {
                    break;
                };
                free[pool] -= 1;
                running.push(Reverse((now.saturating_add(duration(t)), t)));
            }
        }
        // Advance to the next event: a task finishing or a message arriving.
        let next_finish = running.peek().map(|r| r.0 .0);
        let next_arrival = pending.peek().map(|r| r.0 .0);
        now = match (next_finish, next_arrival) {
            (None, None) => break,
            (Some(a), None) | (None, Some(a)) => a,
            (Some(a), Some(b)) => a.min(b),
        };
        while let Some(&Reverse((time, t))) = pending.peek() {
            if time != now {
                break;
            }
            pending.pop();
            let sp = pool_of(t);
            ready[sp].push(Reverse((now, t)));
            mark(sp, &mut dirty, &mut is_dirty);
        }
        while let Some(&Reverse((time, t))) = running.peek() {
            if time != now {
                break;
            }
            makespan = makespan.max(now);
            running.pop();
            let pool = pool_of(t);
            free[pool] += 1;
            mark(pool, &mut dirty, &mut is_dirty);
            for &s in graph.successors(t) {
                let arrive = now.saturating_add(delay(t, s));
                let ra = &mut ready_at[s as usize];
                *ra = (*ra).max(arrive);
                let r = &mut remaining[s as usize];
                *r -= 1;
                if *r == 0 {
                    if *ra > now {
                        pending.push(Reverse((*ra, s)));
                    } else {
                        let sp = pool_of(s);
                        ready[sp].push(Reverse((now, s)));
                        mark(sp, &mut dirty, &mut is_dirty);
                    }
                }
            }
        }
    }
    makespan
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::graph::{GraphBuilder, TaskSpec};

    fn spec(owner: u32) -> TaskSpec {
        TaskSpec::for_owner(owner)
    }

    /// Tasks with the given owners and edges.
    fn graph(owners: &[u32], edges: &[(TaskId, TaskId)]) -> TaskGraph {
        TaskGraph::from_edges(owners, edges).unwrap()
    }

    #[test]
    fn load_imbalance_cases() {
        assert_eq!(load_imbalance(&[1.0, 1.0, 1.0, 1.0]), 0.0);
        assert_eq!(load_imbalance(&[2.0, 1.0, 1.0, 0.0]), 1.0);
        assert_eq!(load_imbalance(&[3.0, 1.0]), 0.5);
        assert_eq!(load_imbalance(&[5.0]), 0.0);
        assert_eq!(load_imbalance(&[]), 0.0);
        assert_eq!(load_imbalance(&[0.0, 0.0]), 0.0);
        assert_eq!(load_imbalance(&[f64::NAN, 1.0]), 0.0);
    }

    /// Task durations by the task's owner.
    fn task_loads<'a>(g: &'a TaskGraph, durations_ns: &'a [u64]) -> impl Iterator<Item = (u32, f64)> + 'a {
        g.specs().iter().zip(durations_ns).map(|(s, &d)| (s.owner, d as f64))
    }

    #[test]
    fn loads_by_owner() {
        let g = graph(&[0, 1, 1, 2, 0], &[(0, 1)]);
        let d = [1, 2, 3, 4, 5];
        assert_eq!(process_loads(task_loads(&g, &d), 3), vec![6.0, 5.0, 4.0]);
        // Owner 2 folds onto process 0 when only 2 processes are asked for; missing durations count 0.
        assert_eq!(process_loads(task_loads(&g, &d[..4]), 2), vec![5.0, 5.0]);
        assert!(process_loads(task_loads(&g, &d), 0).is_empty());
        // Any (owner, load) items, e.g. block weights by owner; an empty input gives zeros.
        let weights = [0.5, 0.25, 1.0];
        let owners = [1u32, 0, 1];
        assert_eq!(process_loads(owners.iter().copied().zip(weights), 2), vec![0.25, 1.5]);
        assert_eq!(process_loads(std::iter::empty(), 2), vec![0.0, 0.0]);
    }

    #[test]
    fn loads_are_summed_in_iteration_order() {
        // 1e16 + 1 + 1 rounds to 1e16 left to right, but 1 + 1 + 1e16 is 1e16 + 2.
        let forward = [(0, 1e16), (0, 1.0), (0, 1.0)];
        let backward = [(0, 1.0), (0, 1.0), (0, 1e16)];
        assert_eq!(process_loads(forward, 1), vec![1e16]);
        assert_eq!(process_loads(backward, 1), vec![1e16 + 2.0]);
        assert_ne!(process_loads(forward, 1), process_loads(backward, 1));
    }

    #[test]
    fn mapped_owners_and_edge_delays() {
        // Chain 0 -> 1 -> 2, durations 1, 2, 3: a delay of 5 on the middle edge adds exactly 5.
        let g = graph(&[0, 0, 0], &[(0, 1), (1, 2)]);
        let d = [1, 2, 3];
        assert_eq!(replay_mapped(&g, &d, |_| 0, 1, 1, false, |_, _| 0), 6);
        assert_eq!(
            replay_mapped(&g, &d, |_| 0, 1, 1, false, |a, _| if a == 1 { 5 } else { 0 }),
            11
        );
        // Two independent tasks remapped onto two processes run side by side.
        let g = graph(&[0, 0], &[]);
        assert_eq!(replay_mapped(&g, &[4, 4], |_| 0, 2, 1, false, |_, _| 0), 8);
        assert_eq!(replay_mapped(&g, &[4, 4], |t| t, 2, 1, false, |_, _| 0), 4);
        // While a message is in flight the core runs other ready work: 0 (1) then 2 (4) on process 0,
        // 1 waits for 0's message (arrives at 1 + 3 = 4) on process 1 and ends at 6.
        let g = graph(&[0, 1, 0], &[(0, 1)]);
        assert_eq!(
            replay_mapped(&g, &[1, 2, 4], |t| g.spec(t).owner, 2, 1, false, |_, _| 3),
            6
        );
    }

    #[test]
    fn chain_is_the_sum() {
        let g = graph(&[0, 1, 0, 1], &[(0, 1), (1, 2), (2, 3)]);
        let d = [1, 2, 3, 4];
        for (p, t) in [(1, 1), (1, 4), (2, 1), (2, 3)] {
            assert_eq!(replay_makespan(&g, &d, p, t, false), 10);
            assert_eq!(replay_makespan(&g, &d, p, t, true), 10);
        }
    }

    #[test]
    fn independent_tasks_on_one_process() {
        let g = graph(&[0, 0, 0, 0], &[]);
        let d = [3, 3, 2, 2];
        assert_eq!(replay_makespan(&g, &d, 1, 1, false), 10);
        // 0 and 1 on [0, 3), then 2 and 3 on [3, 5).
        assert_eq!(replay_makespan(&g, &d, 1, 2, false), 5);
        // 0, 1, 2 at 0; 3 starts when 2 ends at 2 and ends at 4.
        assert_eq!(replay_makespan(&g, &d, 1, 3, false), 4);
        assert_eq!(replay_makespan(&g, &d, 1, 4, false), 3);
        assert_eq!(replay_makespan(&g, &d, 1, 9, false), 3);
    }

    #[test]
    fn processes_with_their_own_tasks_and_global_stealing() {
        // Process 0: two tasks of 4; process 1: four tasks of 1.
        let g = graph(&[0, 0, 1, 1, 1, 1], &[]);
        let d = [4, 4, 1, 1, 1, 1];
        assert_eq!(replay_makespan(&g, &d, 2, 1, false), 8);
        // Global: 0 and 1 on [0, 4), then 2..5 two at a time: 6 (strictly better than 8).
        assert_eq!(replay_makespan(&g, &d, 2, 1, true), 6);
        assert_eq!(replay_makespan(&g, &d, 2, 2, false), 4);
        assert_eq!(replay_makespan(&g, &d, 2, 2, true), 4);
        // Process 1 alone with 2 threads: 2.
        let g1 = graph(&[1, 1, 1, 1], &[]);
        assert_eq!(replay_makespan(&g1, &[1, 1, 1, 1], 2, 2, false), 2);
    }

    #[test]
    fn diamond() {
        // a(1) -> b(2), c(5) -> d(1)
        let edges = [(0, 1), (0, 2), (1, 3), (2, 3)];
        let d = [1, 2, 5, 1];
        let g = graph(&[0, 0, 0, 0], &edges);
        assert_eq!(replay_makespan(&g, &d, 1, 2, false), 7);
        // One core: a [0,1), b [1,3), c [3,8), d [8,9).
        assert_eq!(replay_makespan(&g, &d, 1, 1, false), 9);
        // b and c on different processes run side by side.
        let g = graph(&[0, 0, 1, 1], &edges);
        assert_eq!(replay_makespan(&g, &d, 2, 1, false), 7);
        // But with b and c both on process 0 (one thread), process 1 idles: global fixes it.
        let g = graph(&[0, 0, 0, 1], &edges);
        assert_eq!(replay_makespan(&g, &d, 2, 1, false), 9);
        assert_eq!(replay_makespan(&g, &d, 2, 1, true), 7);
    }

    #[test]
    fn degenerate_inputs() {
        let g = graph(&[], &[]);
        assert_eq!(replay_makespan(&g, &[], 4, 4, false), 0);
        let g = graph(&[0, 3, 1], &[(0, 1), (1, 2)]);
        assert_eq!(replay_makespan(&g, &[0, 0, 0], 2, 2, false), 0);
        // Owner 3 with 2 processes, missing durations, zero counts: no panic.
        assert_eq!(replay_makespan(&g, &[5], 2, 1, false), 5);
        assert_eq!(replay_makespan(&g, &[5, 6, 7], 0, 0, false), 18);
    }

    struct Lcg(u64);
    impl Lcg {
        fn next(&mut self, n: u64) -> u64 {
            self.0 = self
                .0
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (self.0 >> 33) % n
        }
    }

    /// Random DAG: every task gets up to 3 edges to later tasks nearby; owners and durations random.
    fn random(n: usize, processes: u32, seed: u64) -> (TaskGraph, Vec<u64>) {
        let mut rng = Lcg(seed);
        let mut g = GraphBuilder::new();
        for _ in 0..n {
            g.add(spec(rng.next(processes as u64) as u32));
        }
        for i in 0..n {
            for _ in 0..rng.next(4) {
                let j = i + 1 + rng.next(50) as usize;
                if j < n {
                    g.edge(i as TaskId, j as TaskId);
                }
            }
        }
        let d = (0..n).map(|_| rng.next(1000)).collect();
        (g.build().unwrap(), d)
    }

    /// Straightforward O(n^2) version of the same policy (retire everything finishing at `now`, then start
    /// what can start), for cross-checking.
    fn reference(g: &TaskGraph, d: &[u64], p: usize, t: usize, global: bool) -> u64 {
        let n = g.len();
        let mut preds = vec![Vec::new(); n];
        for a in 0..n {
            for &b in g.successors(a as TaskId) {
                preds[b as usize].push(a);
            }
        }
        let pool = |i: usize| {
            if global {
                0
            } else {
                g.spec(i as TaskId).owner as usize % p
            }
        };
        let cores = if global { p * t } else { t };
        let mut finish: Vec<Option<u64>> = vec![None; n];
        let mut retired = vec![false; n];
        let mut now = 0;
        loop {
            for q in 0..if global { 1 } else { p } {
                while (0..n)
                    .filter(|&i| finish[i].is_some() && !retired[i] && pool(i) == q)
                    .count()
                    < cores
                {
                    let best = (0..n)
                        .filter(|&i| finish[i].is_none() && pool(i) == q && preds[i].iter().all(|&a| retired[a]))
                        .map(|i| (preds[i].iter().map(|&a| finish[a].unwrap()).max().unwrap_or(0), i))
                        .min();
                    let Some((_, i)) = best else { break };
                    finish[i] = Some(now + d[i]);
                }
            }
            let Some(next) = (0..n).filter(|&i| !retired[i]).filter_map(|i| finish[i]).min() else {
                break;
            };
            now = next;
            for i in 0..n {
                if finish[i] == Some(now) {
                    retired[i] = true;
                }
            }
        }
        finish.iter().map(|f| f.unwrap()).max().unwrap_or(0)
    }

    #[test]
    fn matches_reference_on_random_graphs() {
        for seed in 0..20 {
            let (g, mut d) = random(120, 3, seed);
            if seed % 4 == 0 {
                // Many zero-duration tasks and ties.
                d.iter_mut().for_each(|x| *x %= 3);
            }
            for (p, t, global) in [(3, 1, false), (3, 2, false), (2, 2, false), (3, 1, true), (1, 3, true)] {
                assert_eq!(
                    replay_makespan(&g, &d, p, t, global),
                    reference(&g, &d, p, t, global),
                    "seed {seed}, P={p} T={t} global={global}"
                );
            }
        }
    }

    #[test]
    fn large_graph_is_fast_and_bounded() {
        let n = 100_000;
        let (g, d) = random(n, 16, 7);
        let t0 = std::time::Instant::now();
        let local = replay_makespan(&g, &d, 16, 4, false);
        let elapsed = t0.elapsed();
        let global = replay_makespan(&g, &d, 16, 4, true);
        let total: u64 = d.iter().sum();
        // Critical path: a lower bound for both.
        let mut path = vec![0u64; n];
        let mut longest = 0;
        for i in 0..n {
            path[i] += d[i];
            longest = longest.max(path[i]);
            for &s in g.successors(i as TaskId) {
                path[s as usize] = path[s as usize].max(path[i]);
            }
        }
        for m in [local, global] {
            assert!(
                m >= longest && m >= total / 64 && m <= total,
                "{m} vs path {longest}, total {total}"
            );
        }
        if !cfg!(debug_assertions) {
            assert!(elapsed.as_secs_f64() < 0.5, "replay of {n} tasks took {elapsed:?}");
        }
    }
}
