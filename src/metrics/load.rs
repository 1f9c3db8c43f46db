//! Per-process loads of an assignment and the load imbalance of eq. (18).

pub use blockflow_scheduler::replay::load_imbalance;

/// Per-process load: the value of every block added to its owner's total in block-id order (the order
/// that makes a counterfactual reproduce the live run bit for bit).
pub fn process_loads(block_values: &[f64], owners: &[u32], processes: usize) -> Vec<f64> {
    blockflow_scheduler::replay::process_loads(
        owners.iter().copied().zip(block_values.iter().copied()),
        processes.max(1),
    )
}

/// The load imbalance eq. (18) that block `weights` predict for `owners` (NaN when the weights do not
/// cover the blocks, e.g. an assignment that was not made from weights).
pub fn predicted_imbalance(weights: &[f64], owners: &[u32], processes: usize) -> f64 {
    if weights.len() != owners.len() {
        return f64::NAN;
    }
    load_imbalance(&process_loads(weights, owners, processes))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn loads_sum_by_owner_and_imbalance_is_max_over_mean_minus_one() {
        let l = process_loads(&[1.0, 2.0, 3.0, 4.0], &[0, 1, 1, 0], 2);
        assert_eq!(l, vec![5.0, 5.0]);
        assert_eq!(predicted_imbalance(&[3.0, 1.0], &[0, 1], 2), 0.5);
        assert!(predicted_imbalance(&[], &[0, 1], 2).is_nan());
    }
}
