//! Calibration (section 3.3–3.4): the coefficients of the workload functions by least squares, one
//! problem per part (per group of parts, [`Model::fit_groups`]), and leave-one-run-out validation.
//!
//! Every workload function is linear in its coefficients, so each part is a linear least-squares
//! problem over the samples (or over their sums per block and window of steps: sums of rows stay
//! exact for a linear model), X's rows being the part's regressors ([`Model::row`]; eq. 14: S·(P_L+P_S)²,
//! S·P_L, S·P_S, S·K, S). What is minimised is what the statistic of section 3.4 measures: the error
//! relative to the block's m_tot, min Σ ((x·a − m_X)/m_tot)², i.e. rows weighted by 1/m_tot (samples
//! with m_tot ≤ 0 carry nothing and are left out). Where the model's coefficients are costs
//! ([`Model::non_negative`]) the problem is solved with a ≥ 0 by the active-set method of Lawson and
//! Hanson (1974, ch. 23); otherwise unconstrained, as the paper did with SciPy. Each least-squares
//! solve uses nalgebra's SVD on the column-scaled matrix (columns of unit norm: C ~ 10⁵ next to a
//! column of ones), dropping singular values below 10⁻¹² of the largest, so a column that never varies
//! (P_S always 0, one block size making C collinear with the intercept) gives the minimum-norm solution.

use std::collections::BTreeMap;

use nalgebra::{DMatrix, DVector};

use super::stats::{score, Scores};
use super::{evaluate, Coefficients, Model, Provenance, Sample};

/// Relative threshold on singular values (of the column-scaled matrix) below which directions are dropped.
const RCOND: f64 = 1e-12;

/// Minimum-norm least-squares solution of `x a = y` over the columns `cols` of `x` (others 0).
fn solve_columns(x: &DMatrix<f64>, y: &DVector<f64>, cols: &[usize]) -> Vec<f64> {
    let k = x.ncols();
    let mut a = vec![0.0; k];
    if cols.is_empty() {
        return a;
    }
    let sub = x.select_columns(cols);
    let svd = sub.clone().svd(true, true);
    let smax = svd.singular_values.max();
    if !(smax > 0.0 && smax.is_finite()) {
        return a;
    }
    let solve = |rhs: &DVector<f64>| {
        svd.solve(rhs, RCOND * smax)
            .expect("U and Vᵀ were computed and the threshold is ≥ 0")
    };
    // One step of iterative refinement: the SVD's own rounding (its bidiagonalisation of a tall
    // matrix whose rows span orders of magnitude) is removed by solving again for the residual.
    let mut s = solve(y);
    let r = y - &sub * &s;
    s += solve(&r);
    for (j, &c) in cols.iter().enumerate() {
        a[c] = s[j];
    }
    a
}

/// Lawson–Hanson non-negative least squares: min ‖x a − y‖₂ subject to a ≥ 0.
fn nnls(x: &DMatrix<f64>, y: &DVector<f64>) -> Vec<f64> {
    let k = x.ncols();
    let mut a = vec![0.0; k];
    let mut passive = vec![false; k];
    let tol = 1e-12 * x.norm() * y.norm();
    for _outer in 0..3 * k + 3 {
        // Gradient of −½‖x a − y‖²: w = xᵀ(y − x a).
        let r = y - x * DVector::from_column_slice(&a);
        let w = x.transpose() * r;
        let Some(j) = (0..k)
            .filter(|&j| !passive[j] && w[j] > tol)
            .max_by(|&i, &j| w[i].total_cmp(&w[j]))
        else {
            break;
        };
        passive[j] = true;
        for _inner in 0..3 * k + 3 {
            let cols: Vec<usize> = (0..k).filter(|&i| passive[i]).collect();
            let s = solve_columns(x, y, &cols);
            if cols.iter().all(|&i| s[i] > 0.0) {
                a = s;
                break;
            }
            // Step from a towards s as far as feasibility allows, then release the coefficients at 0.
            let alpha = cols
                .iter()
                .filter(|&&i| s[i] <= 0.0)
                .map(|&i| a[i] / (a[i] - s[i]))
                .fold(1.0f64, f64::min);
            for i in 0..k {
                a[i] += alpha * (s[i] - a[i]);
                if passive[i] && a[i] <= 0.0 {
                    a[i] = 0.0;
                    passive[i] = false;
                }
            }
        }
    }
    a
}

/// Weight, in squares, of each part's own residual beside the residual of the group's sum when parts
/// are fitted together ([`Model::fit_groups`]): enough to choose, among the splits that fit the sum
/// about equally well (the regressors of LBM and BH are correlated: NB, links and lines grow with the
/// walls), the one closest to the measured split; too little to move the sum (on a default campaign
/// the interval statistics stay within 0.5 point of the sum fitted alone, while the parts' median
/// errors shrink from about ±12 % to under 5 % of m_tot; with 0.1 the interval statistics lose about
/// a point).
const PART_WEIGHT: f64 = 0.01;

/// Sums over one block's samples in one fitting window: the regressors and m_X of every part of a
/// group, and m_tot.
type Window = (Vec<f64>, Vec<f64>, f64);

/// Coefficients of the parts `parts` (indices into [`super::PARTS`]) of `model` over `samples` summed
/// per block over windows of `window` steps, rows weighted by 1/m_tot of the window: for one part, its
/// least-squares problem; for a group, one problem over the parts' regressors side by side whose rows are
/// the group's summed time and, with weight [`PART_WEIGHT`], each part's own time. Returns one vector
/// per part, in the order of `parts`.
fn fit_parts(samples: &[Sample], model: Model, parts: &[usize], window: u64) -> Vec<Vec<f64>> {
    let lens: Vec<usize> = parts.iter().map(|&p| model.terms(p).len()).collect();
    let starts: Vec<usize> = lens
        .iter()
        .scan(0, |acc, &l| {
            let s = *acc;
            *acc += l;
            Some(s)
        })
        .collect();
    let k: usize = lens.iter().sum();
    // (run, block, window) → (summed regressors, summed m_X per part, summed m_tot).
    let mut groups: BTreeMap<(usize, usize, u64), Window> = BTreeMap::new();
    for s in samples.iter().filter(|s| s.m.total().is_finite() && s.m.total() > 0.0) {
        let key = (s.run, s.block, s.step / window.max(1));
        let g = groups
            .entry(key)
            .or_insert_with(|| (vec![0.0; k], vec![0.0; parts.len()], 0.0));
        for (i, &p) in parts.iter().enumerate() {
            for (j, v) in model.row(p, &s.q).as_slice().iter().enumerate() {
                g.0[starts[i] + j] += v;
            }
            g.1[i] += s.m.as_array()[p];
        }
        g.2 += s.m.total();
    }
    let a = if groups.is_empty() {
        vec![0.0; k]
    } else {
        // Row blocks: the group's sum, then (for a group) every part alone.
        let alone = if parts.len() > 1 { parts.len() } else { 0 };
        let n = groups.len();
        let mut x = DMatrix::<f64>::zeros(n * (1 + alone), k);
        let mut y = DVector::<f64>::zeros(n * (1 + alone));
        let lw = PART_WEIGHT.sqrt();
        for (r, (row, m, tot)) in groups.values().enumerate() {
            let w = 1.0 / tot;
            for (j, v) in row.iter().enumerate() {
                x[(r, j)] = v * w;
            }
            y[r] = m.iter().sum::<f64>() * w;
            for i in 0..alone {
                let rr = n * (1 + i) + r;
                for j in starts[i]..starts[i] + lens[i] {
                    x[(rr, j)] = row[j] * w * lw;
                }
                y[rr] = m[i] * w * lw;
            }
        }
        solve_scaled(x, &y, model.non_negative())
    };
    (0..parts.len())
        .map(|i| a[starts[i]..starts[i] + lens[i]].to_vec())
        .collect()
}

/// The least-squares solution of `x a = y`, columns scaled to unit norm for the solve; non-negative
/// when `non_negative`.
fn solve_scaled(mut x: DMatrix<f64>, y: &DVector<f64>, non_negative: bool) -> Vec<f64> {
    let k = x.ncols();
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
    let a = if non_negative {
        nnls(&x, y)
    } else {
        solve_columns(&x, y, &(0..k).collect::<Vec<_>>())
    };
    (0..k).map(|j| a[j] / scale[j]).collect()
}

/// Fits the five workload functions of `model` to `samples` summed per block over windows of `window`
/// steps (1: every step is a row; the balancing interval: what the balancer's weights are compared
/// with, and what averages the VM's right-skewed per-step noise to its mean; see the module
/// documentation). Returns
/// the coefficients with `floor` 0 and `provenance` completed: `samples` set to the number of samples,
/// and `fit_quality` extended with the in-sample statistics of [`evaluate`] (`median_<part>`,
/// `mad_<part>`, `median_tot`, `mad_tot`, `share_within_10pct`; non-finite values left out). With no
/// samples every coefficient is 0.
pub fn fit(samples: &[Sample], provenance: Provenance, model: Model, window: u64) -> Coefficients {
    let mut c = Coefficients::zeros(model, provenance);
    for parts in model.fit_groups() {
        for (&p, a) in parts.iter().zip(fit_parts(samples, model, parts, window)) {
            c.parts[p] = a;
        }
    }
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

/// Leave-one-run-out validation: for each distinct `run`, fits `model` (windows of `interval` steps) on
/// all other runs and scores the
/// left-out run with [`score`] (per step, per interval of `interval` steps, and predictively); returns
/// the counts summed over the runs. Empty scores with fewer than two distinct runs (nothing to hold out
/// against).
pub fn cross_validate(samples: &[Sample], model: Model, interval: u64) -> Scores {
    let mut total = Scores::default();
    for (_, sc) in cross_validate_by_run(samples, model, interval) {
        total.add(&sc);
    }
    total
}

/// [`cross_validate`] per left-out run: (run, its held-out scores), in ascending run order; empty with
/// fewer than two distinct runs.
pub fn cross_validate_by_run(samples: &[Sample], model: Model, interval: u64) -> Vec<(usize, Scores)> {
    let mut runs: Vec<usize> = samples.iter().map(|s| s.run).collect();
    runs.sort_unstable();
    runs.dedup();
    if runs.len() < 2 {
        return Vec::new();
    }
    runs.into_iter()
        .map(|r| {
            let train: Vec<Sample> = samples.iter().filter(|s| s.run != r).copied().collect();
            let test: Vec<Sample> = samples.iter().filter(|s| s.run == r).copied().collect();
            let c = fit(&train, Provenance::default(), model, interval);
            (r, score(&c, &test, interval))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::super::median;
    use super::super::testutil::{exact, synthetic, truth};
    use super::super::{PartTimes, Quantities, PARTS};
    use super::*;

    fn arrays(c: &Coefficients) -> [(&'static str, Vec<f64>); 5] {
        std::array::from_fn(|p| (PARTS[p], c.parts[p].clone()))
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
            Model::Paper,
            1,
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
        let c = fit(&samples, Provenance::default(), Model::Paper, 1);
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
        for (g, w) in [
            (c.parts[0][0], t.parts[0][0]),
            (c.parts[0][1], t.parts[0][1]),
            (c.parts[1][1], t.parts[1][1]),
        ] {
            assert!(rel(g, w) < 0.02, "{g:e} vs {w:e}");
        }
        for (g, w) in c.parts[4].iter().zip(&t.parts[4]).skip(1) {
            assert!(rel(*g, *w) < 0.02, "{g:e} vs {w:e}");
        }
        for (p, (g, w)) in arrays(&c).into_iter().zip(arrays(&t)).enumerate() {
            let xmax: Vec<f64> = (0..w.1.len())
                .map(|j| {
                    samples
                        .iter()
                        .map(|s| c.model.row(p, &s.q).as_slice()[j].abs())
                        .fold(0.0, f64::max)
                })
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
        let c = fit(&samples, Provenance::default(), Model::Paper, 1);
        for (g, w) in c.parts[4].iter().zip(&t.parts[4]) {
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
        let cf = fit(&flat, Provenance::default(), Model::Paper, 1);
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
        let c = fit(&samples, Provenance::default(), Model::Paper, 1);
        for (_, a) in arrays(&c) {
            assert!(a.iter().all(|v| v.is_finite()));
        }
        // Still predicts the data exactly: the dropped directions are ones the data cannot see.
        for s in &samples {
            let p = c.predict(&s.q);
            assert!((p.total() - s.m.total()).abs() <= 1e-9 * s.m.total());
        }
        // The P_S coefficient, never seen, is (numerically) zero.
        assert!(c.parts[2][3].abs() < 1e-9 * t.parts[2][3], "{:e}", c.parts[2][3]);
        // No samples at all: zeros.
        let z = fit(&[], Provenance::default(), Model::Paper, 1);
        assert_eq!(z.parts[0], [0.0; 3]);
        assert_eq!(z.provenance.samples, 0);
        assert!(z.provenance.fit_quality.is_empty());
    }

    #[test]
    fn cross_validation_leaves_each_run_out() {
        let t = truth();
        let samples = synthetic(&t, 4000, 8, 0.01, 11);
        let sc = cross_validate(&samples, Model::Paper, 10);
        assert!(sc.step.share() > 0.99, "{sc:?}");
        // One run only: nothing to hold out against.
        let one: Vec<Sample> = samples.iter().filter(|s| s.run == 0).copied().collect();
        assert_eq!(cross_validate(&one, Model::Paper, 10).step.total, 0);
        // A run whose blocks behave differently (LBM 3× slower) is predicted badly when held out.
        let mut odd = samples.clone();
        for s in odd.iter_mut().filter(|s| s.run == 3) {
            s.m = PartTimes {
                lbm: 3.0 * s.m.lbm,
                ..s.m
            };
        }
        let share_odd = cross_validate(&odd, Model::Paper, 10).step.share();
        let run3 = odd.iter().filter(|s| s.run == 3).count() as f64 / odd.len() as f64;
        assert!(share_odd <= 1.0 - 0.9 * run3, "{share_odd}");
    }

    /// Blockflow-model samples with wall blocks: F fluid cells and `lines` wall lines per block; LBM
    /// and BH times from `lbm(f, lines)` and `bh(lines)`, one sample per block and step, 4 runs.
    fn wall_samples(lbm: impl Fn(f64, f64) -> f64, bh: impl Fn(f64) -> f64) -> Vec<Sample> {
        let mut g = super::super::testutil::SplitMix64(11);
        (0..4000)
            .map(|i| {
                let f = 500.0 + (3500.0 * g.unit()).floor();
                let lines = (2000.0 * g.unit()).floor();
                let q = Quantities {
                    c: 4096.0,
                    f,
                    wall_links: lines,
                    wall_lines: lines,
                    ..Default::default()
                };
                Sample {
                    run: i % 4,
                    step: (i / 40) as u64,
                    block: i % 40,
                    q,
                    m: PartTimes {
                        lbm: lbm(f, lines),
                        bh: bh(lines),
                        ..Default::default()
                    },
                }
            })
            .collect()
    }

    #[test]
    fn lbm_and_bh_fitted_together_recover_exact_parts_and_a_sum_no_split_explains() {
        let sum_error = |c: &Coefficients, s: &Sample| {
            let p = c.predict(&s.q);
            ((p.lbm + p.bh) - (s.m.lbm + s.m.bh)).abs() / (s.m.lbm + s.m.bh)
        };
        // Each part a non-negative combination of its own regressors: every stacked row is consistent,
        // so the group's fit is exact for both parts.
        let exact = wall_samples(|f, _| 1.3e-8 * f, |l| 4.0e-9 * l);
        let c = fit(&exact, Provenance::default(), Model::Blockflow, 1);
        for s in &exact {
            let p = c.predict(&s.q);
            let tot = s.m.lbm + s.m.bh;
            assert!(
                (p.lbm - s.m.lbm).abs() <= 1e-9 * tot && (p.bh - s.m.bh).abs() <= 1e-9 * tot,
                "{p:?} against {:?}",
                s.m
            );
        }
        // A sweep warmed by its boundary pass: LBM = a·F − b·lines, BH = c·lines (c > b). No split
        // with costs ≥ 0 gives the parts; the sum a·F + (c − b)·lines is one. The point (a on F, c − b
        // on the wall lines) is feasible with sum residual 0 and part residuals ±u, u = b·lines, so
        // at the optimum ‖r_sum‖² + λ(‖r_LBM‖² + ‖r_BH‖²) ≤ 2λ‖u‖², i.e. ‖r_sum‖ ≤ √(2λ)·‖u‖ (rows
        // relative to m_tot, λ = PART_WEIGHT).
        let (a, b, cc) = (1.3e-8, 2.0e-9, 4.0e-9);
        let warmed = wall_samples(|f, l| a * f - b * l, |l| cc * l);
        let c = fit(&warmed, Provenance::default(), Model::Blockflow, 1);
        let rms = |v: Vec<f64>| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
        let r_sum = rms(warmed.iter().map(|s| sum_error(&c, s)).collect());
        let u = rms(warmed.iter().map(|s| b * s.q.wall_lines / (s.m.lbm + s.m.bh)).collect());
        assert!(
            r_sum <= (2.0 * PART_WEIGHT).sqrt() * u,
            "sum residual {r_sum:e}, bound {:e}",
            (2.0 * PART_WEIGHT).sqrt() * u
        );
        // The paper's form fits every part alone (section 3.4).
        assert_eq!(Model::Paper.fit_groups().len(), 5);
        assert_eq!(Model::Blockflow.fit_groups()[0], &[0, 1]);
    }

    /// NNLS against a case solved by hand: y = 2·x1 − 1·x2 with x1, x2 positively correlated; the
    /// constrained optimum drops x2 (its coefficient would be negative) and refits x1 alone:
    /// a1 = (x1·y)/(x1·x1).
    #[test]
    fn nnls_drops_a_negative_direction_and_refits_the_rest() {
        let x1 = [1.0, 2.0, 3.0, 4.0];
        let x2 = [0.5, 0.4, 1.0, 1.5];
        let y: Vec<f64> = (0..4).map(|i| 2.0 * x1[i] - x2[i]).collect();
        let x = DMatrix::from_fn(4, 2, |i, j| if j == 0 { x1[i] } else { x2[i] });
        let yv = DVector::from_vec(y.clone());
        let a = nnls(&x, &yv);
        let want = (0..4).map(|i| x1[i] * y[i]).sum::<f64>() / (0..4).map(|i| x1[i] * x1[i]).sum::<f64>();
        assert_eq!(a[1], 0.0);
        assert!((a[0] - want).abs() < 1e-12 * want, "{a:?} vs {want}");
        // With a feasible optimum NNLS is plain least squares: y = 2·x1 + 3·x2 exactly.
        let y: Vec<f64> = (0..4).map(|i| 2.0 * x1[i] + 3.0 * x2[i]).collect();
        let a = nnls(&x, &DVector::from_vec(y));
        assert!((a[0] - 2.0).abs() < 1e-12 && (a[1] - 3.0).abs() < 1e-12, "{a:?}");
    }

    /// The weights 1/m_tot: with two groups of samples whose best fits disagree, the weighted fit
    /// follows the relative errors, so a small block is predicted as well as a big one.
    #[test]
    fn weighted_fit_minimises_relative_errors() {
        // LBM time = 1e-8·F on small blocks but 1.2e-8·F on big ones; one coefficient (F) per model
        // cannot fit both. Unweighted least squares would sit near the big blocks' 1.2e-8; the
        // relative-error fit minimises Σ((a·F − m)/m)² = Σ(a/α_i − 1)², a = Σ(1/α)/Σ(1/α²) over
        // the samples' α_i.
        let mk = |f: f64, alpha: f64, i: usize| Sample {
            run: 0,
            step: i as u64,
            block: usize::from(f > 1000.0),
            q: Quantities {
                c: f,
                f,
                ..Default::default()
            },
            m: PartTimes {
                lbm: alpha * f,
                ..Default::default()
            },
        };
        let mut samples = Vec::new();
        for i in 0..10 {
            samples.push(mk(100.0, 1e-8, i));
            samples.push(mk(100_000.0, 1.2e-8, i));
        }
        let c = fit(&samples, Provenance::default(), Model::Blockflow, 1);
        let (a1, a2) = (1.0 / 1e-8, 1.0 / 1.2e-8);
        let want = (a1 + a2) / (a1 * a1 + a2 * a2);
        // Blockflow LBM terms: F, runs (0 here), [F > 0]; the constant term is set to 0 by the
        // non-negative fit only if it does not help, so compare predictions, not coefficients.
        let p_small = c.predict(&samples[0].q).lbm / samples[0].m.lbm;
        let p_big = c.predict(&samples[1].q).lbm / samples[1].m.lbm;
        assert!((p_big - want / 1.2e-8).abs() < 0.02, "{p_small} {p_big} {want:e}");
        assert!(c.parts.iter().flatten().all(|&a| a >= 0.0), "{:?}", c.parts);
    }
}
