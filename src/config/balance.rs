//! `[balance]`: the initial assignment, the balancing strategy and its block weights, and the message
//! price of the modeled times.

use crate::error::{config_err, Result};
use serde::{Deserialize, Serialize};

/// `balance.strategy`: how blocks are assigned to processes.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Strategy {
    /// Static Hilbert split by fluid-cell count at the start (the paper's baseline).
    #[default]
    None,
    /// 3D Hilbert curve order, greedy prefix split.
    Hilbert,
    /// Morton curve order, greedy prefix split.
    Morton,
    /// Diffusive balancing between neighbouring processes (waLBerla's `DynamicDiffusionBalance`), starting
    /// from the Hilbert assignment; see `balance::diffusive`.
    Diffusive,
    /// METIS k-way graph partitioning of the block graph (eq. 17 edge weights), relabelled to keep blocks
    /// where they are, starting from the Hilbert assignment; see `balance::metis`.
    Metis,
}

/// `balance.diffusive_mode`: who decides which blocks move in the diffusive strategy.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum DiffusiveMode {
    /// Processes with outflow send blocks to their neighbours (default).
    #[default]
    Push,
    /// Processes with inflow take blocks from their neighbours.
    Pull,
}

/// `[balance]`: assignment and balancing.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct BalanceConfig {
    /// Strategy.
    #[serde(default)]
    pub strategy: Strategy,
    /// Steps per balancing / measurement interval.
    #[serde(default = "d_interval")]
    pub interval: u64,
    /// Block weight: `"corrected"` (default: eq. 15 with `balance.coefficients`, times the block's
    /// smoothed measured/predicted ratio, the predictor–corrector of section 3.5), `"estimator"` (eq. 15
    /// alone, the paper's method, by default forecast to the coming interval's middle by half its change
    /// since the balancing step before: `balance.forecast`), `"cells"` (fluid cells), `"measured"` (the
    /// block's m_tot over the last interval) or `"uniform"` (1 per block: equal block counts). With every strategy but `"none"` (which
    /// never moves a block) the blocks are redistributed with these weights at the end of every interval.
    #[serde(default)]
    pub weights: Weights,
    /// `weights = "estimator"`: forecast each block's estimate to the middle of the coming interval from
    /// its change since the balancing step before (`estimator::forecast`; default true), or weigh by
    /// the estimate at the balancing step alone, as the paper does (false).
    #[serde(default = "d_forecast")]
    pub forecast: bool,
    /// Coefficients file of the estimator (written by `blockflow calibrate`); used with
    /// `weights = "estimator"` and `"corrected"`.
    #[serde(default = "d_coefficients")]
    pub coefficients: String,
    /// How the curve order is cut into processes: `"greedy"` (the paper's prefix split; default) or
    /// `"optimal"` (the contiguous split minimising the heaviest process, by bisection on the bottleneck).
    #[serde(default)]
    pub split: SplitKind,
    /// Diffusive strategy: diffusion iterations over the process graph per main iteration (the flow
    /// estimate on every process-process edge; at least 1).
    #[serde(default = "d_flow_iterations")]
    pub flow_iterations: usize,
    /// Diffusive strategy: main iterations per balancing step (a block moves at most one process hop per
    /// main iteration; at least 1).
    #[serde(default = "d_diffusive_iterations")]
    pub diffusive_iterations: usize,
    /// Diffusive strategy: `"push"` (overloaded processes send; default) or `"pull"` (underloaded processes
    /// take).
    #[serde(default)]
    pub diffusive_mode: DiffusiveMode,
    /// METIS strategy: allowed load imbalance, max part weight / mean part weight (METIS' ufactor is
    /// `(metis_imbalance - 1) * 1000`; at least 1.0; default 1.05).
    #[serde(default = "d_metis_imbalance")]
    pub metis_imbalance: f64,
    /// Latency α of a message between processes in the modeled times (seconds; default 2e-6, an
    /// InfiniBand FDR cluster like the paper's SuperMUC).
    #[serde(default = "d_latency")]
    pub latency: f64,
    /// Bandwidth β of a message between processes in the modeled times (bytes per second; default 5e9).
    #[serde(default = "d_bandwidth")]
    pub bandwidth: f64,
}

/// `balance.split`.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum SplitKind {
    /// For each process in turn, take blocks while that brings it closer to remaining weight / remaining
    /// processes.
    #[default]
    Greedy,
    /// The contiguous split of the same order with the lightest heaviest part.
    Optimal,
}

/// `balance.weights`: what a block weighs.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Weights {
    /// Fluid cells (cells when the fluid is off).
    Cells,
    /// The workload estimate of eq. (15) from the block's Table 1 quantities (the paper's method, with
    /// the built-in coefficients where the working folder has none), by default forecast to the middle
    /// of the coming interval from its change since the balancing step before (`balance.forecast`; the
    /// plain estimate for the initial assignment and the first balancing step).
    Estimator,
    /// The block's own measured m_tot over the last interval (cells for the initial assignment).
    Measured,
    /// The estimate scaled by the block's smoothed measured/predicted ratio (section 3.5; see
    /// `estimator::weights`; the plain estimate for the initial assignment). The default: it follows
    /// the particles as the estimate does and the blocks' own costs as measurements do.
    #[default]
    Corrected,
    /// Every block weighs 1: equal block counts per process (the paper's uniform initial split).
    Uniform,
}

/// Default `balance.coefficients`: the file `blockflow calibrate` writes for this machine. Where the
/// working folder has none, runs use the copy built into the binary.
pub const DEFAULT_COEFFICIENTS: &str = "configs/coefficients.toml";

fn d_coefficients() -> String {
    DEFAULT_COEFFICIENTS.to_string()
}

fn d_forecast() -> bool {
    true
}

fn d_interval() -> u64 {
    100
}

fn d_flow_iterations() -> usize {
    15
}

fn d_diffusive_iterations() -> usize {
    20
}

fn d_metis_imbalance() -> f64 {
    1.05
}

fn d_latency() -> f64 {
    DEFAULT_LATENCY
}

fn d_bandwidth() -> f64 {
    DEFAULT_BANDWIDTH
}

impl Default for BalanceConfig {
    fn default() -> Self {
        BalanceConfig {
            strategy: Strategy::None,
            interval: d_interval(),
            weights: Weights::Corrected,
            forecast: d_forecast(),
            coefficients: d_coefficients(),
            split: SplitKind::Greedy,
            flow_iterations: d_flow_iterations(),
            diffusive_iterations: d_diffusive_iterations(),
            diffusive_mode: DiffusiveMode::Push,
            metis_imbalance: d_metis_imbalance(),
            latency: d_latency(),
            bandwidth: d_bandwidth(),
        }
    }
}

/// Default message latency α in seconds (an InfiniBand FDR cluster like the paper's SuperMUC).
pub const DEFAULT_LATENCY: f64 = 2e-6;
/// Default bandwidth β in bytes per second.
pub const DEFAULT_BANDWIDTH: f64 = 5e9;

impl BalanceConfig {
    /// Checks the keys' ranges; the message names the key.
    pub fn validate(&self) -> Result<()> {
        if self.interval == 0 {
            return config_err("balance.interval = 0: must be at least 1 step");
        }
        for (name, v) in [
            ("balance.flow_iterations", self.flow_iterations),
            ("balance.diffusive_iterations", self.diffusive_iterations),
        ] {
            if v == 0 || v > 100_000 {
                return config_err(format!("{name} = {v}: must be between 1 and 100000"));
            }
        }
        let mi = self.metis_imbalance;
        if !(mi.is_finite() && (1.0..=3.0).contains(&mi)) {
            return config_err(format!(
                "balance.metis_imbalance = {mi}: must be a finite number between 1.0 and 3.0"
            ));
        }
        let (a, b) = (self.latency, self.bandwidth);
        if !(a.is_finite() && (0.0..=1.0).contains(&a)) {
            return config_err(format!("balance.latency = {a}: must be between 0 and 1 second"));
        }
        if !(b.is_finite() && b >= 1e3) {
            return config_err(format!(
                "balance.bandwidth = {b}: must be at least 1e3 bytes per second"
            ));
        }
        Ok(())
    }
}
