//! Contiguous splits of a curve order into P parts (the paper's section 4.1).

/// The paper's greedy prefix split: for each process in turn, target = remaining weight / remaining
/// processes; take blocks while that brings the process closer to its target (at least one block each
/// while blocks remain, and leave at least one block for every later process). Returns the owner of each
/// position of `order`'s weights (`weights[i]` is the weight of the i-th block of the order).
pub fn greedy_split(weights: &[f64], processes: usize) -> Vec<u32> {
    let n = weights.len();
    let mut owner = vec![0u32; n];
    let mut remaining: f64 = weights.iter().sum();
    let mut i = 0;
    for p in 0..processes {
        let left_procs = processes - p;
        let target = remaining / left_procs as f64;
        let mut load = 0.0;
        let mut taken = 0;
        while i < n {
            // one block for each later process, as long as there are enough blocks for everyone
            let must_leave = if n >= processes { left_procs - 1 } else { 0 };
            if n - i <= must_leave {
                break;
            }
            let w = weights[i];
            let closer = (load + w - target).abs() < (load - target).abs();
            if taken > 0 && !closer && p + 1 < processes {
                break;
            }
            owner[i] = p as u32;
            load += w;
            taken += 1;
            i += 1;
        }
        remaining -= load;
    }
    owner
}

/// The contiguous split of the same order that minimises the heaviest process (`balance.split =
/// "optimal"`): bisection on the bottleneck B (a split with every part ≤ B exists iff packing blocks
/// greedily into parts of capacity B needs at most `processes` parts), then that packing, cutting early
/// only so that every later process still gets a block. Never heavier than [`greedy_split`].
pub fn optimal_split(weights: &[f64], processes: usize) -> Vec<u32> {
    let n = weights.len();
    if n == 0 || processes <= 1 {
        return vec![0; n];
    }
    // Parts needed at capacity `cap` when packing in order (a block heavier than `cap` alone in a part), as
    // the final packing below does it; stops as soon as it exceeds `processes`.
    let parts_needed = |cap: f64| {
        let (mut parts, mut load) = (1usize, 0.0);
        for &w in weights {
            if load + w > cap && load > 0.0 {
                parts += 1;
                if parts > processes {
                    break;
                }
                load = 0.0;
            }
            load += w;
        }
        parts
    };
    // The same count from prefix sums, P binary searches per test (exact up to rounding).
    let mut prefix = Vec::with_capacity(n + 1);
    let mut acc = 0.0;
    prefix.push(0.0);
    for &w in weights {
        acc += w;
        prefix.push(acc);
    }
    let fast_parts = |cap: f64| {
        let (mut parts, mut i) = (0usize, 0usize);
        while i < n && parts <= processes {
            parts += 1;
            let end = prefix.partition_point(|&x| x <= prefix[i] + cap) - 1;
            i = end.max(i + 1);
        }
        parts
    };
    let (mut lo, mut hi) = (weights.iter().copied().fold(0.0, f64::max), acc);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi {
            break;
        }
        if fast_parts(mid) <= processes {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    // Rounding may separate the two counts: raise the capacity until the sequential packing fits.
    let mut step = hi * f64::EPSILON;
    while parts_needed(hi) > processes && hi < acc {
        hi = (hi + step).min(acc);
        step *= 2.0;
    }
    let cap = hi;
    let mut owner = vec![0u32; n];
    let (mut p, mut load, mut taken) = (0usize, 0.0, 0usize);
    for (i, &w) in weights.iter().enumerate() {
        let left_blocks = n - i;
        let left_procs = processes - p;
        // Cut when the part is full, or when every later process needs one of the remaining blocks.
        let must_cut = left_blocks < left_procs;
        if p + 1 < processes && taken > 0 && (load + w > cap || must_cut) {
            p += 1;
            load = 0.0;
            taken = 0;
        }
        owner[i] = p as u32;
        load += w;
        taken += 1;
    }
    owner
}

/// The heaviest part of a split.
pub fn bottleneck(weights: &[f64], owner: &[u32], processes: usize) -> f64 {
    let mut load = vec![0.0; processes.max(1)];
    for (w, &o) in weights.iter().zip(owner) {
        load[o as usize] += w;
    }
    load.into_iter().fold(0.0, f64::max)
}

#[cfg(test)]
mod optimal_tests {
    use super::*;

    #[test]
    fn optimal_split_hand_cases() {
        // greedy puts 6 alone then 3 on one side; optimal balances [6 | 1 1 1 1 1 1]
        let w = [6.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0];
        assert_eq!(optimal_split(&w, 2), vec![0, 1, 1, 1, 1, 1, 1]);
        // [1 1 1 | 5]: the bottleneck is the heavy block itself
        let w = [1.0, 1.0, 1.0, 5.0];
        assert_eq!(bottleneck(&w, &optimal_split(&w, 2), 2), 5.0);
        // uniform: equal parts
        assert_eq!(optimal_split(&[1.0; 6], 3), vec![0, 0, 1, 1, 2, 2]);
        // greedy's known weakness: [3 3 2 2 2] into 2 → greedy 3+3 | 2+2+2 is optimal too (6/6)
        let w = [3.0, 3.0, 2.0, 2.0, 2.0];
        assert_eq!(bottleneck(&w, &optimal_split(&w, 2), 2), 6.0);
    }

    /// On 2000 pseudo-random cases the optimal split is never heavier than greedy, uses only contiguous
    /// runs of owners 0..P in order, and gives every process a block when there are enough blocks.
    #[test]
    fn optimal_never_worse_than_greedy() {
        let mut rng = crate::util::hash::SplitMix(0x1234_5678);
        let mut next = || rng.next_u64();
        for _ in 0..2000 {
            let n = 1 + (next() % 60) as usize;
            let p = 1 + (next() % 12) as usize;
            let w: Vec<f64> = (0..n)
                .map(|_| (next() % 1000) as f64 / 100.0 + if next() % 7 == 0 { 20.0 } else { 0.0 })
                .collect();
            let g = greedy_split(&w, p);
            let o = optimal_split(&w, p);
            assert!(bottleneck(&w, &o, p) <= bottleneck(&w, &g, p) + 1e-9, "{w:?} P={p}");
            assert!(
                o.windows(2).all(|x| x[1] == x[0] || x[1] == x[0] + 1),
                "contiguous, in order: {o:?}"
            );
            if n >= p {
                assert_eq!(*o.last().unwrap() as usize, p - 1, "every process gets a block: {o:?}");
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn greedy_split_hand_cases() {
        assert_eq!(greedy_split(&[1.0; 6], 3), vec![0, 0, 1, 1, 2, 2]);
        // heavy first block: process 0 takes it alone, the rest share
        assert_eq!(
            greedy_split(&[6.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0], 2),
            vec![0, 1, 1, 1, 1, 1, 1]
        );
        // more processes than blocks: the extra processes stay empty
        assert_eq!(greedy_split(&[1.0, 1.0], 3), vec![0, 1]);
        // zero weights still get an owner each
        assert_eq!(greedy_split(&[0.0, 0.0, 0.0, 0.0], 2).len(), 4);
        // the last process takes whatever is left
        assert_eq!(greedy_split(&[1.0, 1.0, 1.0, 5.0], 2), vec![0, 0, 0, 1]);
    }
}
