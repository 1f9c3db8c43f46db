//! Error statistics of section 3.4: the relative error E_X = (WL_X − m_X)/m_tot of every part and of the
//! total per sample, summarised by median and MAD (median absolute deviation, a robust dispersion), and
//! the share of samples with |E_tot| < 10 % (the paper: "over 85 %").

use std::collections::BTreeMap;

use super::{Coefficients, Sample, PARTS};

/// Median and MAD of one error distribution (section 3.4, Figure 8).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PartStats {
    /// Median of E_X.
    pub median: f64,
    /// Median absolute deviation of E_X from its median (unscaled, no 1.4826 factor).
    pub mad: f64,
}

/// Quality of a set of coefficients on a set of samples (section 3.4).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Evaluation {
    /// Median and MAD of E_X = (WL_X − m_X)/m_tot per part, keyed by the names of [`PARTS`].
    pub per_part: BTreeMap<String, PartStats>,
    /// Median and MAD of E_tot = (WL_tot − m_tot)/m_tot (eqs. 15 and 16).
    pub total: PartStats,
    /// Share of the samples with |E_tot| < 0.1 (0 … 1).
    pub share_within_10pct: f64,
    /// Number of samples evaluated (those with a finite m_tot > 0).
    pub samples: usize,
}

pub use crate::util::stats::{mad, median};

fn part_stats(v: &[f64]) -> PartStats {
    PartStats {
        median: median(v),
        mad: mad(v),
    }
}

/// Relative errors of one sample: E_X = (WL_X − m_X)/m_tot for the five parts (WL_X from
/// [`Coefficients::predict`], floor included) and E_tot = (WL_tot − m_tot)/m_tot; `None` for a sample
/// whose measured m_tot (eq. 16) is not a finite number > 0.
pub(crate) fn errors(c: &Coefficients, s: &Sample) -> Option<([f64; 5], f64)> {
    let m_tot = s.m.total();
    if !(m_tot.is_finite() && m_tot > 0.0) {
        return None;
    }
    let wl = c.predict(&s.q);
    let (p, m) = (wl.as_array(), s.m.as_array());
    let e = std::array::from_fn(|i| (p[i] - m[i]) / m_tot);
    Some((e, (wl.total() - m_tot) / m_tot))
}

/// Section 3.4: E_X = (WL_X − m_X)/m_tot per sample and part, E_tot = (WL_tot − m_tot)/m_tot; median and
/// MAD per part and of E_tot, and the share of samples with |E_tot| < 0.1. The error is relative to m_tot
/// rather than m_X, as in the paper, to avoid dividing by the near-zero times of Coup1 and RB. Samples
/// whose m_tot is not a finite number > 0 are skipped (and not counted in `samples`); with no sample
/// left the medians are NaN and the share is 0.
pub fn evaluate(c: &Coefficients, samples: &[Sample]) -> Evaluation {
    let mut per: [Vec<f64>; 5] = Default::default();
    let mut tot = Vec::with_capacity(samples.len());
    for s in samples {
        if let Some((e, et)) = errors(c, s) {
            for (v, x) in per.iter_mut().zip(e) {
                v.push(x);
            }
            tot.push(et);
        }
    }
    let n = tot.len();
    let within = tot.iter().filter(|e| e.abs() < 0.1).count();
    Evaluation {
        per_part: PARTS
            .iter()
            .zip(&per)
            .map(|(name, v)| (name.to_string(), part_stats(v)))
            .collect(),
        total: part_stats(&tot),
        share_within_10pct: if n == 0 { 0.0 } else { within as f64 / n as f64 },
        samples: n,
    }
}

#[cfg(test)]
mod tests {
    use super::super::{PartTimes, Provenance, Quantities};
    use super::*;

    #[test]
    fn median_of_odd_and_even_lengths() {
        assert_eq!(median(&[3.0]), 3.0);
        assert_eq!(median(&[5.0, 1.0, 3.0]), 3.0);
        assert_eq!(median(&[4.0, 1.0, 3.0, 2.0]), 2.5);
        assert_eq!(median(&[-1.0, 10.0]), 4.5);
        assert_eq!(median(&[7.0, 7.0, 1.0, 100.0, 7.0]), 7.0);
        assert!(median(&[]).is_nan());
    }

    #[test]
    fn mad_of_odd_and_even_lengths() {
        // {1,1,2,2,4,6,9}: median 2, deviations {1,1,0,0,2,4,7}, MAD 1.
        assert_eq!(mad(&[1.0, 1.0, 2.0, 2.0, 4.0, 6.0, 9.0]), 1.0);
        // {1,2,3,4}: median 2.5, deviations {1.5,0.5,0.5,1.5}, MAD 1.
        assert_eq!(mad(&[4.0, 1.0, 3.0, 2.0]), 1.0);
        // {0,0,0,10}: median 0, deviations {0,0,0,10}, MAD 0 — robust to the outlier.
        assert_eq!(mad(&[0.0, 10.0, 0.0, 0.0]), 0.0);
        assert_eq!(mad(&[2.0]), 0.0);
        assert!(mad(&[]).is_nan());
    }

    /// Coefficients that predict exactly `lbm = F·1e-3` and nothing else, and samples measured around it.
    fn hand_case() -> (Coefficients, Vec<Sample>) {
        let c = Coefficients {
            lbm: [0.0, 1e-3, 0.0],
            bh: [0.0; 3],
            coup1: [0.0; 5],
            coup2: [0.0; 5],
            rb: [0.0; 5],
            floor: 0.0,
            provenance: Provenance::default(),
        };
        // Predicted WL_lbm = 1.0 for F = 1000; measured lbm = 1.0, bh = b, so m_tot = 1 + b and
        // E_tot = −b/(1+b), E_lbm = 0, E_bh = −b/(1+b).
        let q = Quantities {
            c: 1000.0,
            f: 1000.0,
            ..Default::default()
        };
        let bhs = [0.0, 0.05, 0.25, 1.0];
        let samples = bhs
            .iter()
            .enumerate()
            .map(|(i, &b)| Sample {
                run: 0,
                step: i as u64,
                block: 0,
                q,
                m: PartTimes {
                    lbm: 1.0,
                    bh: b,
                    ..Default::default()
                },
            })
            .collect();
        (c, samples)
    }

    #[test]
    fn evaluate_hand_case() {
        let (c, mut samples) = hand_case();
        // A sample with m_tot = 0 is skipped.
        samples.push(Sample {
            run: 0,
            step: 9,
            block: 1,
            q: Quantities::default(),
            m: PartTimes::default(),
        });
        let ev = evaluate(&c, &samples);
        assert_eq!(ev.samples, 4);
        // E_tot = {0, −0.05/1.05, −0.2, −0.5}: |E| < 0.1 for two of four.
        assert_eq!(ev.share_within_10pct, 0.5);
        let e = [0.0, -0.05 / 1.05, -0.25 / 1.25, -0.5];
        let med = 0.5 * (e[1] + e[2]);
        assert!((ev.total.median - med).abs() < 1e-15);
        let dev = [e[0] - med, e[1] - med, e[2] - med, e[3] - med].map(f64::abs);
        assert!((ev.total.mad - median(&dev)).abs() < 1e-15);
        assert_eq!(ev.per_part["lbm"], PartStats { median: 0.0, mad: 0.0 });
        // E_bh = −b/(1+b) = E_tot up to rounding.
        assert!((ev.per_part["bh"].median - ev.total.median).abs() < 1e-15);
        assert!((ev.per_part["bh"].mad - ev.total.mad).abs() < 1e-15);
        assert_eq!(ev.per_part["rb"], PartStats { median: 0.0, mad: 0.0 });
        assert_eq!(ev.per_part.keys().cloned().collect::<Vec<_>>().len(), 5);
        // The per-part errors add up to the total error.
        for s in &samples[..4] {
            let (e, et) = errors(&c, s).unwrap();
            assert!((e.iter().sum::<f64>() - et).abs() < 1e-15);
        }
    }

    #[test]
    fn share_is_strictly_below_ten_percent() {
        let (c, _) = hand_case();
        let q = Quantities {
            c: 1000.0,
            f: 1000.0,
            ..Default::default()
        };
        // Measured 1/0.9 …: WL = 1; choose m_tot so that E_tot is just inside / just outside 0.1.
        let mk = |m: f64| Sample {
            run: 0,
            step: 0,
            block: 0,
            q,
            m: PartTimes {
                lbm: m,
                ..Default::default()
            },
        };
        let ev = evaluate(&c, &[mk(1.0 / 1.0999), mk(1.0 / 0.9001), mk(1.0 / 1.2), mk(1.0)]);
        assert_eq!(ev.samples, 4);
        assert_eq!(ev.share_within_10pct, 0.75);
        let empty = evaluate(&c, &[]);
        assert_eq!(empty.samples, 0);
        assert_eq!(empty.share_within_10pct, 0.0);
        assert!(empty.total.median.is_nan());
    }
}
