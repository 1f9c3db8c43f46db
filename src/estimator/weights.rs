//! Block weights from measurements (section 3.5 of Rettinger & Rüde 2019): `measured` takes the
//! block's own m_tot over the last interval; `corrected` is the predictor–corrector the paper proposes,
//! the estimate of eq. (15) scaled by the block's measured/predicted ratio.
//!
//! Rule of the corrector, per block b and interval i with prediction P_b,i (eq. 15 summed over the
//! interval's steps) and measurement M_b,i (m_tot summed likewise):
//! - r_b ← (1 − α) r_b + α M_b,i / P_b,i when both are positive (exponential smoothing over recent
//!   intervals; r_b starts at 1, α = `alpha`, default 0.5);
//! - a block with P_b,i ≤ 0 or M_b,i ≤ 0 (nothing predicted or nothing measured) keeps its ratio;
//! - the ratio is clamped to [1/`clamp`, `clamp`] (default 10) so one disturbed interval cannot make a
//!   block look arbitrarily heavy or light;
//! - the weight for the next distribution is r_b times the block's current estimate.

/// The estimate forecast to the middle of the coming balancing interval: each block's estimate now, e,
/// plus half its change since the balancing step before, e₋ (one interval earlier):
/// w = max(e + ½ (e − e₋), ½ e). The balancer weighs a block by what it will cost *over* the coming
/// interval, and bodies settling through the domain move load from block to block steadily, so the load
/// at the interval's middle, linear in time, is its mean. The floor keeps a block whose load fell (a body
/// left) from being forecast below half its estimate, where a trend that ended would overshoot most.
/// Without an estimate one interval earlier (`before` empty or of another length: the first balancing
/// step, or a restart from a checkpoint without it) the weights are the estimate itself.
pub fn forecast(now: &[f64], before: &[f64]) -> Vec<f64> {
    if before.len() != now.len() {
        return now.to_vec();
    }
    now.iter()
        .zip(before)
        .map(|(&e, &p)| (e + 0.5 * (e - p)).max(0.5 * e))
        .collect()
}

/// The predictor–corrector state of every block.
#[derive(Clone, Debug, PartialEq)]
pub struct Corrector {
    /// Smoothed measured/predicted ratio per block.
    pub ratio: Vec<f64>,
    /// Smoothing factor α in (0, 1].
    pub alpha: f64,
    /// Largest factor a ratio may reach either way.
    pub clamp: f64,
}

impl Corrector {
    /// A corrector for `blocks` blocks with ratio 1, α = 0.5 and clamp 10.
    pub fn new(blocks: usize) -> Self {
        Corrector {
            ratio: vec![1.0; blocks],
            alpha: 0.5,
            clamp: 10.0,
        }
    }

    /// Folds one interval's predictions and measurements (per block, same length) into the ratios.
    pub fn update(&mut self, predicted: &[f64], measured: &[f64]) {
        assert_eq!(predicted.len(), self.ratio.len());
        assert_eq!(measured.len(), self.ratio.len());
        for ((r, &p), &m) in self.ratio.iter_mut().zip(predicted).zip(measured) {
            if p > 0.0 && m > 0.0 && p.is_finite() && m.is_finite() {
                let x = (1.0 - self.alpha) * *r + self.alpha * (m / p);
                *r = x.clamp(1.0 / self.clamp, self.clamp);
            }
        }
    }

    /// Corrected weights: each block's current estimate times its ratio.
    pub fn weights(&self, estimate: &[f64]) -> Vec<f64> {
        estimate.iter().zip(&self.ratio).map(|(e, r)| e * r).collect()
    }
}

/// `measured` weights: the blocks' m_tot over the last interval, with blocks that measured nothing set to
/// the smallest positive measurement (a block without tasks still has to sit somewhere; zero weights would
/// let the greedy split put any number of them on one process).
pub fn measured(block_load: &[f64]) -> Vec<f64> {
    let min = block_load
        .iter()
        .copied()
        .filter(|x| *x > 0.0 && x.is_finite())
        .fold(f64::INFINITY, f64::min);
    let floor = if min.is_finite() { min } else { 1.0 };
    block_load
        .iter()
        .map(|&x| if x > 0.0 && x.is_finite() { x } else { floor })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A steady ratio converges geometrically: after n intervals r = ρ + (1 − ρ)(1 − α)^n.
    #[test]
    fn corrector_converges_to_the_measured_ratio() {
        let mut c = Corrector::new(3);
        for n in 1..=20 {
            c.update(&[2.0, 1.0, 0.0], &[3.0, 0.5, 4.0]);
            let want = 1.5 + (1.0 - 1.5) * 0.5f64.powi(n);
            assert!(
                (c.ratio[0] - want).abs() < 1e-15,
                "interval {n}: {} vs {want}",
                c.ratio[0]
            );
        }
        assert!((c.ratio[1] - 0.5).abs() < 1e-5);
        assert_eq!(c.ratio[2], 1.0, "nothing predicted: ratio kept");
        assert_eq!(
            c.weights(&[4.0, 4.0, 4.0]),
            vec![4.0 * c.ratio[0], 4.0 * c.ratio[1], 4.0]
        );
    }

    /// A load rising linearly in time is forecast exactly to its value half an interval ahead, which
    /// is its mean over the coming interval; a falling one as well, down to half the estimate; without
    /// the estimate one interval earlier the forecast is the estimate.
    #[test]
    fn forecast_extends_a_linear_trend_to_the_interval_middle() {
        // Loads 4 + t (rising), 8 − t (falling) and 10 − 8t (falling fast), estimates at t = 0 and 1.
        let before = [4.0, 8.0, 10.0];
        let now = [5.0, 7.0, 2.0];
        // Means over t in [1, 2]: 5.5 and 6.5; the third would be −2, floored at 1.
        assert_eq!(forecast(&now, &before), vec![5.5, 6.5, 1.0]);
        assert_eq!(forecast(&now, &[]), now.to_vec());
        assert_eq!(forecast(&now, &[1.0]), now.to_vec());
    }

    #[test]
    fn corrector_clamps_and_measured_fills_empty_blocks() {
        let mut c = Corrector::new(2);
        c.alpha = 1.0;
        c.update(&[1.0, 1.0], &[1000.0, 1e-6]);
        assert_eq!(c.ratio, vec![10.0, 0.1]);
        assert_eq!(measured(&[0.0, 2.0, 3.0, f64::NAN]), vec![2.0, 2.0, 3.0, 2.0]);
        assert_eq!(measured(&[0.0, 0.0]), vec![1.0, 1.0]);
    }
}
