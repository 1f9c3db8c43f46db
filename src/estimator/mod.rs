//! Workload estimator of section 3 of Rettinger & Rüde (2019): block quantities (Table 1), per-part
//! workload functions (eqs. 10–14) and their sum (eq. 15), calibration by linear least squares and the
//! error statistics of section 3.4.
//!
//! - [`Quantities`]: the Table 1 quantities of one block in one step; [`PartTimes`]: the measured (or
//!   predicted) seconds of the five parts, whose sum is eq. (16).
//! - [`Coefficients`] ([`coefficients`]): the coefficients of eqs. (10)–(14), their evaluation
//!   ([`Coefficients::predict`], [`Coefficients::total`]) and the `coefficients.toml` file format.
//! - [`Model`] ([`model`]): the paper's eqs. (10)–(14) or this engine's form of them (regressors that
//!   are the work its tasks do).
//! - [`fit()`] ([`mod@fit`]): one weighted (non-negative where the model asks) least-squares problem
//!   per part, or per group of parts ([`Model::fit_groups`]: LBM and BH under `blockflow`);
//!   [`cross_validate`]: leave-one-run-out validation.
//! - [`evaluate`] and [`score`] ([`stats`]): E_X = (WL_X − m_X)/m_tot per sample, median and MAD per
//!   part and of E_tot, and the shares within 10 % per step (the paper's statistic: over 85 %) and per
//!   balancing interval (what the balancer uses).
//!
//! The coefficients depend on the machine, the implementation and the algorithms (section 3.5): the
//! paper's Table 2 (SuperMUC, waLBerla) is kept as an example in `configs/coefficients-paper-table2.toml`
//! and is never ours; `blockflow calibrate` writes `configs/coefficients.toml` for this machine.

pub mod coefficients;
pub mod fit;
pub mod model;
pub mod quantities;
pub mod stats;
pub mod weights;

pub use coefficients::{Coefficients, Provenance};
pub use fit::{cross_validate, cross_validate_by_run, fit};
pub use model::Model;
pub use quantities::Quantities;
pub use stats::{
    evaluate, mad, median, noise_floor, score, BlockKind, Evaluation, Hits, NoiseFloor, PartStats, Scores,
};
pub use weights::{forecast, measured, Corrector};

use crate::physics::parts::{ByPart, Part};

/// Measured (or predicted) seconds per part of one block in one step: m_LBM, m_BH, m_Coup1, m_Coup2, m_RB
/// of section 3.3 (or WL_LBM … WL_RB of eqs. 10–14).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PartTimes {
    /// LBM collision and stream (Algorithms 2 and 3; eq. 10).
    pub lbm: f64,
    /// Boundary handling (Algorithm 4; eq. 11).
    pub bh: f64,
    /// Particle mapping, Coup1 (Algorithm 5; eq. 12).
    pub coup1: f64,
    /// PDF reconstruction, Coup2 (Algorithm 6; eq. 13).
    pub coup2: f64,
    /// Rigid-body simulation, all S sub-cycles (Algorithm 7; eq. 14).
    pub rb: f64,
}

impl PartTimes {
    /// Eq. (16): m_tot = m_LBM + m_BH + m_Coup1 + m_Coup2 + m_RB (eq. 15 for predicted times).
    pub fn total(&self) -> f64 {
        self.lbm + self.bh + self.coup1 + self.coup2 + self.rb
    }

    /// The five parts in the order of [`PARTS`].
    pub fn as_array(&self) -> [f64; 5] {
        [self.lbm, self.bh, self.coup1, self.coup2, self.rb]
    }

    /// The measured seconds of one block and step from its CPU nanoseconds per part of the step (the
    /// ghost exchange is not one of the five).
    pub fn from_part_ns(t: &ByPart<u64>) -> Self {
        let s = |p: Part| t[p] as f64 * 1e-9;
        PartTimes {
            lbm: s(STEP_PARTS[0]),
            bh: s(STEP_PARTS[1]),
            coup1: s(STEP_PARTS[2]),
            coup2: s(STEP_PARTS[3]),
            rb: s(STEP_PARTS[4]),
        }
    }
}

/// One calibration sample (section 3.3): which run (block size/diameter combination), step, block, the
/// Table 1 quantities and the measured times of the five parts.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// Index of the calibration run (one block size/diameter combination); [`cross_validate`] leaves
    /// runs out.
    pub run: usize,
    /// Time step.
    pub step: u64,
    /// Block id.
    pub block: usize,
    /// Table 1 quantities.
    pub q: Quantities,
    /// Measured seconds per part.
    pub m: PartTimes,
}

/// Names of the five parts (eqs. 10–14), in the order used everywhere in this module: TOML tables, the
/// keys of [`Evaluation::per_part`] and [`PartTimes::as_array`].
pub const PARTS: [&str; 5] = ["lbm", "bh", "coup1", "coup2", "rb"];

/// The part of the time step each of [`PARTS`] measures (same order).
pub const STEP_PARTS: [Part; 5] = [Part::Lbm, Part::Boundary, Part::Map, Part::Reconstruct, Part::RigidBody];

#[cfg(test)]
pub(crate) mod testutil {
    //! Deterministic synthetic samples for the tests of this module (splitmix64; no `rand`).

    use super::*;

    pub use crate::util::hash::SplitMix as SplitMix64;

    /// Positive "true" coefficients of a plausible size (seconds; loosely Table 2 ×1e-3 with positive
    /// intercepts), used to synthesise measurements.
    pub fn truth() -> Coefficients {
        Coefficients {
            model: Model::Paper,
            parts: [
                vec![1.0e-8, 1.6e-7, 2.0e-5],
                vec![6.6e-9, 7.0e-7, 1.0e-5],
                vec![3.1e-9, 2.4e-10, 1.4e-5, 2.8e-5, 5.0e-6],
                vec![6.0e-9, 3.9e-9, 8.8e-6, 2.5e-5, 4.0e-6],
                vec![1.2e-9, 9.6e-7, 2.8e-7, 1.5e-6, 1.9e-5],
            ],
            floor: 0.0,
            provenance: Provenance::default(),
        }
    }

    /// Raw values of eqs. (10)–(14) (no floor), the synthetic measurement before noise.
    pub fn exact(c: &Coefficients, q: &Quantities) -> PartTimes {
        PartTimes {
            lbm: c.raw(0, q),
            bh: c.raw(1, q),
            coup1: c.raw(2, q),
            coup2: c.raw(3, q),
            rb: c.raw(4, q),
        }
    }

    /// `n` samples over `runs` runs with block sizes 24..64, random fluid fraction, boundary cells,
    /// particles, contacts and S ∈ {1, 5, 10, 20}; measured times = `c`'s raw prediction times
    /// (1 + `rel_noise`·N(0,1)) per part.
    pub fn synthetic(c: &Coefficients, n: usize, runs: usize, rel_noise: f64, seed: u64) -> Vec<Sample> {
        let mut g = SplitMix64(seed);
        let sizes = [24.0f64, 32.0, 48.0, 64.0];
        let subcycles = [1.0, 5.0, 10.0, 20.0];
        (0..n)
            .map(|i| {
                let run = i % runs;
                let bs = sizes[run % sizes.len()];
                let cells = bs * bs * bs;
                let f = (cells * g.unit()).floor();
                let nb = (0.3 * f * g.unit()).floor();
                let pl = g.below(40) as f64;
                let ps = g.below(60) as f64;
                let k = g.below(3 * (pl + ps) as u64 + 1) as f64;
                let s = subcycles[g.below(4) as usize];
                let q = Quantities {
                    c: cells,
                    f,
                    nb,
                    pl,
                    ps,
                    k,
                    s,
                    ..Default::default()
                };
                let e = exact(c, &q);
                let mut noisy = |x: f64| x * (1.0 + rel_noise * g.normal());
                let m = PartTimes {
                    lbm: noisy(e.lbm),
                    bh: noisy(e.bh),
                    coup1: noisy(e.coup1),
                    coup2: noisy(e.coup2),
                    rb: noisy(e.rb),
                };
                Sample {
                    run,
                    step: (i / runs) as u64,
                    block: i % 80,
                    q,
                    m,
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn total_is_the_sum_of_the_five_parts_eq16() {
        let m = PartTimes {
            lbm: 1.0,
            bh: 2.0,
            coup1: 4.0,
            coup2: 8.0,
            rb: 16.0,
        };
        assert_eq!(m.total(), 31.0);
        assert_eq!(m.as_array(), [1.0, 2.0, 4.0, 8.0, 16.0]);
    }
}
