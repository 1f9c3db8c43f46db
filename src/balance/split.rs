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
