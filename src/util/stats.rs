//! Robust statistics: median, median absolute deviation and linear-interpolation quantiles.

/// Median of `v` (the mean of the two middle values for an even length); NaN for an empty slice. Values
/// are ordered by `f64::total_cmp`.
pub fn median(v: &[f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let n = s.len();
    if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    }
}

/// Median absolute deviation: median(|v_i − median(v)|), unscaled (no 1.4826 factor); NaN for an empty
/// slice.
pub fn mad(v: &[f64]) -> f64 {
    let m = median(v);
    let d: Vec<f64> = v.iter().map(|x| (x - m).abs()).collect();
    median(&d)
}

/// The finite values of `v`, sorted by `f64::total_cmp`.
pub fn sorted_finite(v: &[f64]) -> Vec<f64> {
    let mut s: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    s.sort_by(f64::total_cmp);
    s
}

/// Median of the finite values of `v` (NaN when there is none).
pub fn median_finite(v: &[f64]) -> f64 {
    median(&sorted_finite(v))
}

/// Quantile `q` ∈ [0, 1] of sorted values by linear interpolation between the neighbouring order
/// statistics; NaN for an empty slice.
pub fn quantile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let pos = q.clamp(0.0, 1.0) * (sorted.len() - 1) as f64;
    let lo = pos.floor() as usize;
    let hi = (lo + 1).min(sorted.len() - 1);
    sorted[lo] + (pos - lo as f64) * (sorted[hi] - sorted[lo])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_mad_and_quantiles_by_hand() {
        assert!(median(&[]).is_nan());
        assert_eq!(median(&[3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&[4.0, 1.0, 2.0, 3.0]), 2.5);
        assert_eq!(mad(&[1.0, 2.0, 3.0, 4.0, 100.0]), 1.0);
        assert_eq!(median_finite(&[1.0, f64::NAN, 3.0, f64::INFINITY]), 2.0);
        let s: Vec<f64> = (0..=100).map(f64::from).collect();
        assert_eq!(quantile(&s, 0.05), 5.0);
        assert_eq!(quantile(&s, 0.5), 50.0);
        assert!(quantile(&[], 0.5).is_nan());
    }
}
