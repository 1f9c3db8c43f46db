//! Calibration (section 3.3–3.4): the coefficients of eqs. (10)–(14) by linear least squares, one
//! problem per part, and leave-one-run-out validation.
//!
//! Every workload function is linear in its coefficients, so each part is an ordinary least-squares
//! problem min ‖X a − m_X‖₂ over the samples, X's rows being the part's regressors (eq. 14: S·(P_L+P_S)²,
//! S·P_L, S·P_S, S·K, S). The paper used SciPy's curve fitting; here nalgebra's SVD solves it. The columns
//! of X are scaled to unit norm first (C ~ 10⁵ next to an intercept column of ones), and singular values
//! below 10⁻¹² of the largest are dropped, so a column that never varies in the data (P_S always 0, a
//! single block size making C collinear with the intercept) gives the minimum-norm solution instead of
//! garbage.

use nalgebra::{DMatrix, DVector};

use super::stats::errors;
use super::{evaluate, row, Coefficients, Provenance, Sample, PARTS};

/// Relative threshold on singular values (of the column-scaled matrix) below which directions are dropped.
const RCOND: f64 = 1e-12;

/// Least-squares coefficients of part `part` (index into [`PARTS`]) over `samples`.
fn fit_part(samples: &[Sample], part: usize) -> Vec<f64> {
    let k = row(part, &Default::default()).len();
    let n = samples.len();
    if n == 0 {
        return vec![0.0; k];
    }
    let mut x = DMatrix::<f64>::zeros(n, k);
    let mut y = DVector::<f64>::zeros(n);
    for (i, s) in samples.iter().enumerate() {
        for (j, v) in row(part, &s.q).into_iter().enumerate() {
            x[(i, j)] = v;
        }
        y[i] = s.m.as_array()[part];
    }
    let scale: Vec<f64> = (0..k)
        .map(|j| {
            let norm = x.column(j).norm();
            if norm > 0.0 && norm.is_finite() {
                norm
            } else {
                1.0
            }
        })
        .collect();
    for (j, sc) in scale.iter().enumerate() {
        x.column_mut(j).unscale_mut(*sc);
    }
    let svd = x.svd(true, true);
    let smax = svd.singular_values.max();
    if !(smax > 0.0 && smax.is_finite()) {
        return vec![0.0; k];
    }
    let a = svd
        .solve(&y, RCOND * smax)
        .expect("U and Vᵀ were computed and the threshold is ≥ 0");
    (0..k).map(|j| a[j] / scale[j]).collect()
}

/// Fits eqs. (10)–(14) to `samples` by linear least squares per part (regressors as in the module
/// documentation; eq. 14's factor S multiplied into every RB regressor, so runs with different S share
/// one set of coefficients). Returns the coefficients with `floor` 0 and `provenance` completed:
/// `samples` set to the number of samples, and `fit_quality` extended with the in-sample statistics of
/// [`evaluate`] (`median_<part>`, `mad_<part>`, `median_tot`, `mad_tot`,
/// `share_within_10pct`; non-finite values left out). With no samples every coefficient is 0.
pub fn fit(samples: &[Sample], provenance: Provenance) -> Coefficients {
    let a: Vec<Vec<f64>> = (0..PARTS.len()).map(|p| fit_part(samples, p)).collect();
    let three = |v: &Vec<f64>| -> [f64; 3] { [v[0], v[1], v[2]] };
    let five = |v: &Vec<f64>| -> [f64; 5] { [v[0], v[1], v[2], v[3], v[4]] };
    let mut c = Coefficients {
        lbm: three(&a[0]),
        bh: three(&a[1]),
        coup1: five(&a[2]),
        coup2: five(&a[3]),
        rb: five(&a[4]),
        floor: 0.0,
        provenance,
    };
    c.provenance.samples = samples.len();
    let ev = evaluate(&c, samples);
    let mut q = Vec::new();
    for (name, st) in &ev.per_part {
        q.push((format!("median_{name}"), st.median));
        q.push((format!("mad_{name}"), st.mad));
    }
    q.push(("median_tot".into(), ev.total.median));
    q.push(("mad_tot".into(), ev.total.mad));
    if ev.samples > 0 {
        q.push(("share_within_10pct".into(), ev.share_within_10pct));
    }
    for (k, v) in q {
        if v.is_finite() {
            c.provenance.fit_quality.insert(k, v);
        }
    }
    c
}

/// Leave-one-run-out validation: for each distinct `run`, fits on all other runs and evaluates E_tot
/// (section 3.4) on the left-out run. Returns the share of all held-out samples (with m_tot > 0) with
/// |E_tot| < 0.1 — how well the estimator predicts a block size/diameter it was not fitted to. NaN with
/// fewer than two distinct runs (nothing to hold out against) or no evaluable held-out sample.
pub fn held_out(samples: &[Sample], provenance: Provenance) -> f64 {
    let mut runs: Vec<usize> = samples.iter().map(|s| s.run).collect();
    runs.sort_unstable();
    runs.dedup();
    if runs.len() < 2 {
        return f64::NAN;
    }
    let (mut within, mut total) = (0usize, 0usize);
    for r in runs {
        let train: Vec<Sample> = samples.iter().filter(|s| s.run != r).copied().collect();
        let c = fit(&train, provenance.clone());
        for s in samples.iter().filter(|s| s.run == r) {
            if let Some((_, e)) = errors(&c, s) {
                total += 1;
                within += usize::from(e.abs() < 0.1);
            }
        }
    }
    if total == 0 {
        f64::NAN
    } else {
        within as f64 / total as f64
    }
}

#[cfg(test)]
mod tests {
    use super::super::median;
    use super::super::testutil::{exact, synthetic, truth};
    use super::super::{PartTimes, Quantities};
    use super::*;

    fn arrays(c: &Coefficients) -> [(&'static str, Vec<f64>); 5] {
        [
            ("lbm", c.lbm.to_vec()),
            ("bh", c.bh.to_vec()),
            ("coup1", c.coup1.to_vec()),
            ("coup2", c.coup2.to_vec()),
            ("rb", c.rb.to_vec()),
        ]
    }

    /// Largest relative error of any coefficient of `got` against `want`.
    fn worst(got: &Coefficients, want: &Coefficients) -> (f64, String) {
        let mut w = (0.0, String::new());
        for ((name, g), (_, t)) in arrays(got).into_iter().zip(arrays(want)) {
            for (i, (g, t)) in g.iter().zip(&t).enumerate() {
                let r = (g - t).abs() / t.abs();
                if r > w.0 {
                    w = (r, format!("{name}.a{}: {g:e} vs {t:e}", i + 1));
                }
            }
        }
        w
    }

    #[test]
    fn fit_recovers_known_coefficients_exactly_without_noise() {
        let t = truth();
        let samples = synthetic(&t, 2000, 8, 0.0, 42);
        // Different S in the data: eq. (14)'s factor is needed to fit exactly.
        let mut ss: Vec<f64> = samples.iter().map(|s| s.q.s).collect();
        ss.sort_by(f64::total_cmp);
        ss.dedup();
        assert_eq!(ss, vec![1.0, 5.0, 10.0, 20.0]);
        let c = fit(
            &samples,
            Provenance {
                machine: "synthetic".into(),
                ..Default::default()
            },
        );
        let (w, which) = worst(&c, &t);
        assert!(w < 1e-9, "worst relative coefficient error {w:e} ({which})");
        assert_eq!(c.provenance.samples, 2000);
        assert_eq!(c.provenance.machine, "synthetic");
        assert_eq!(c.provenance.fit_quality["share_within_10pct"], 1.0);
        assert!(c.provenance.fit_quality["mad_tot"] < 1e-12);
        let ev = evaluate(&c, &samples);
        assert_eq!(ev.share_within_10pct, 1.0);
        assert!(ev.total.median.abs() < 1e-12 && ev.total.mad < 1e-12);
    }

    #[test]
    fn fit_within_tolerance_with_noise() {
        // 1 % multiplicative Gaussian-like noise on every measured part, 20 000 samples. What the data
        // determine is the prediction: the standard error of a least-squares prediction is about
        // σ·√(k/n) ≈ 1 %·√(5/20 000) ≈ 0.02 % of the part for a typical sample, larger at the edges of
        // the data (F ≈ 0, few particles): we require the fitted part to be within 0.05 % of the
        // noise-free truth in the median over the samples and within 1 % on every sample. The coefficients themselves are only as well
        // determined as their term's share of the part: the dominant ones (C and F for LBM, NB for BH,
        // the P_L/P_S/K terms and S for RB) within 2 %, and every coefficient's contribution
        // |Δa_j|·max|x_j| within 0.5 % of the part's largest value (small terms such as the Coup
        // intercepts, a few µs next to ms, can be off by several % of themselves).
        let t = truth();
        let samples = synthetic(&t, 20_000, 8, 0.01, 7);
        let c = fit(&samples, Provenance::default());
        let mut dev: [Vec<f64>; 5] = Default::default();
        for s in &samples {
            let (p, e) = (c.predict(&s.q).as_array(), exact(&t, &s.q).as_array());
            for i in 0..5 {
                dev[i].push((p[i] - e[i]).abs() / e[i]);
            }
        }
        for (i, d) in dev.iter().enumerate() {
            let (med, max) = (median(d), d.iter().cloned().fold(0.0, f64::max));
            assert!(med < 5e-4 && max < 1e-2, "{}: median {med:e}, max {max:e}", PARTS[i]);
        }
        let rel = |g: f64, w: f64| (g - w).abs() / w.abs();
        for (g, w) in [(c.lbm[0], t.lbm[0]), (c.lbm[1], t.lbm[1]), (c.bh[1], t.bh[1])] {
            assert!(rel(g, w) < 0.02, "{g:e} vs {w:e}");
        }
        for (g, w) in c.rb.iter().zip(&t.rb).skip(1) {
            assert!(rel(*g, *w) < 0.02, "{g:e} vs {w:e}");
        }
        for (p, (g, w)) in arrays(&c).into_iter().zip(arrays(&t)).enumerate() {
            let xmax: Vec<f64> = (0..w.1.len())
                .map(|j| samples.iter().map(|s| row(p, &s.q)[j].abs()).fold(0.0, f64::max))
                .collect();
            let mmax = samples
                .iter()
                .map(|s| exact(&t, &s.q).as_array()[p])
                .fold(0.0, f64::max);
            for (j, ((gj, wj), xj)) in g.1.iter().zip(&w.1).zip(&xmax).enumerate() {
                let contrib = (gj - wj).abs() * xj / mmax;
                assert!(contrib < 5e-3, "{}.a{}: contribution error {contrib:e}", g.0, j + 1);
            }
        }
        let ev = evaluate(&c, &samples);
        assert!(ev.total.median.abs() < 1e-3, "{ev:?}");
        assert!(ev.total.mad < 0.01, "{ev:?}");
        assert_eq!(ev.share_within_10pct, 1.0);
    }

    #[test]
    fn rb_fit_needs_and_finds_the_s_factor_of_eq14() {
        // Only rigid-body time, S varying 1…20: the fit recovers a_RB and predictions scale with S.
        let t = truth();
        let samples = synthetic(&t, 3000, 4, 0.0, 99);
        let c = fit(&samples, Provenance::default());
        for (g, w) in c.rb.iter().zip(&t.rb) {
            assert!((g - w).abs() <= 1e-9 * w.abs(), "{g:e} vs {w:e}");
        }
        let q = Quantities {
            pl: 5.0,
            ps: 7.0,
            k: 9.0,
            s: 1.0,
            ..Default::default()
        };
        let p1 = c.predict(&q).rb;
        let p20 = c.predict(&Quantities { s: 20.0, ..q }).rb;
        assert!((p20 - 20.0 * p1).abs() <= 1e-12 * p20);
        // Without the factor S (S forced to 1 in the regressors) the same data cannot be fitted exactly.
        let flat: Vec<Sample> = samples
            .iter()
            .map(|s| Sample {
                q: Quantities { s: 1.0, ..s.q },
                ..*s
            })
            .collect();
        let cf = fit(&flat, Provenance::default());
        let err = samples
            .iter()
            .map(|s| (cf.predict(&Quantities { s: 1.0, ..s.q }).rb - s.m.rb).abs() / s.m.rb);
        assert!(err.fold(0.0, f64::max) > 0.1);
    }

    #[test]
    fn constant_columns_give_a_finite_minimum_norm_fit() {
        // One block size, no shadow particles: C is collinear with the intercept and P_S is all zero.
        let t = truth();
        let samples: Vec<Sample> = synthetic(&t, 500, 1, 0.0, 3)
            .into_iter()
            .map(|s| {
                let q = Quantities { ps: 0.0, ..s.q };
                Sample {
                    q,
                    m: exact(&t, &q),
                    ..s
                }
            })
            .collect();
        let c = fit(&samples, Provenance::default());
        for (_, a) in arrays(&c) {
            assert!(a.iter().all(|v| v.is_finite()));
        }
        // Still predicts the data exactly: the dropped directions are ones the data cannot see.
        for s in &samples {
            let p = c.predict(&s.q);
            assert!((p.total() - s.m.total()).abs() <= 1e-9 * s.m.total());
        }
        // The P_S coefficient, never seen, is (numerically) zero.
        assert!(c.coup1[3].abs() < 1e-9 * t.coup1[3], "{:e}", c.coup1[3]);
        // No samples at all: zeros.
        let z = fit(&[], Provenance::default());
        assert_eq!(z.lbm, [0.0; 3]);
        assert_eq!(z.provenance.samples, 0);
        assert!(z.provenance.fit_quality.is_empty());
    }

    #[test]
    fn held_out_leaves_each_run_out() {
        let t = truth();
        let samples = synthetic(&t, 4000, 8, 0.01, 11);
        let share = held_out(&samples, Provenance::default());
        assert!(share > 0.99, "{share}");
        // One run only: nothing to hold out against.
        let one: Vec<Sample> = samples.iter().filter(|s| s.run == 0).copied().collect();
        assert!(held_out(&one, Provenance::default()).is_nan());
        // A run whose blocks behave differently (LBM 3× slower) is predicted badly when held out.
        let mut odd = samples.clone();
        for s in odd.iter_mut().filter(|s| s.run == 3) {
            s.m = PartTimes {
                lbm: 3.0 * s.m.lbm,
                ..s.m
            };
        }
        let share_odd = held_out(&odd, Provenance::default());
        let run3 = odd.iter().filter(|s| s.run == 3).count() as f64 / odd.len() as f64;
        assert!(share_odd <= 1.0 - 0.9 * run3, "{share_odd}");
    }
}
