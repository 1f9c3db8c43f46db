//! `[fluid]`: the lattice Boltzmann model, its precision and kernels.

use crate::error::{config_err, Result};
use serde::{Deserialize, Serialize};

/// Storage and compute precision of the PDFs.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
    /// Double precision (default).
    #[default]
    F64,
    /// Single precision: about twice the MLUPS, errors floor near 1e-6.
    F32,
}

/// Which kernels a fluid block runs.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum KernelChoice {
    /// Fused pull-stream + collide (default; bitwise equal to `split`).
    #[default]
    Fused,
    /// Separate stream and collide sweeps.
    Split,
}

/// How populations stream between steps (`fluid.streaming`).
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Streaming {
    /// One PDF field updated in place (AA pattern): half the PDF memory and memory traffic (default).
    #[default]
    Aa,
    /// Two PDF fields, pull streaming from one into the other.
    Pull,
}

impl Streaming {
    /// The config word (`"aa"` or `"pull"`).
    pub fn name(self) -> &'static str {
        match self {
            Streaming::Aa => "aa",
            Streaming::Pull => "pull",
        }
    }

    /// The kernels' pattern.
    pub fn pattern(self) -> blockflow_kernels::Pattern {
        match self {
            Streaming::Aa => blockflow_kernels::Pattern::Aa,
            Streaming::Pull => blockflow_kernels::Pattern::Pull,
        }
    }
}

/// `[fluid]`: the lattice Boltzmann model.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct FluidConfig {
    /// Relaxation time τ+ (ν = (τ - 1/2)/3, eq. 5). Absent: the scene's default or derived value.
    pub tau: Option<f64>,
    /// Magic parameter Λ of eq. (5); 3/16 puts bounce-back walls exactly half-way.
    #[serde(default = "default_magic")]
    pub magic: f64,
    /// `"f64"` (default) or `"f32"`.
    #[serde(default)]
    pub precision: Precision,
    /// Largest |u| (lattice units) before the run is stopped as unstable.
    #[serde(default = "default_velocity_limit")]
    pub velocity_limit: f64,
    /// `"fused"` (default) or `"split"` kernels.
    #[serde(default)]
    pub kernel: KernelChoice,
    /// `"aa"` (default: one field, in place) or `"pull"` (two fields). Both give the same bits.
    #[serde(default)]
    pub streaming: Streaming,
    /// `false` switches the fluid off (rigid bodies only): no PDF is stored or computed, no fluid task.
    #[serde(default = "yes")]
    pub enabled: bool,
}

fn yes() -> bool {
    true
}

fn default_magic() -> f64 {
    3.0 / 16.0
}
fn default_velocity_limit() -> f64 {
    0.5
}

impl Default for FluidConfig {
    fn default() -> Self {
        FluidConfig {
            tau: None,
            magic: default_magic(),
            precision: Precision::F64,
            velocity_limit: default_velocity_limit(),
            kernel: KernelChoice::Fused,
            streaming: Streaming::Aa,
            enabled: true,
        }
    }
}

impl FluidConfig {
    /// Checks the keys' ranges; the message names the key.
    pub fn validate(&self) -> Result<()> {
        if let Some(t) = self.tau {
            if t.is_nan() || t <= 0.5 || !t.is_finite() {
                return config_err(format!(
                    "fluid.tau = {t}: must be a finite number > 0.5 (ν = (τ - 1/2)/3 must be positive)"
                ));
            }
        }
        if self.magic.is_nan() || self.magic <= 0.0 || !self.magic.is_finite() {
            return config_err(format!(
                "fluid.magic = {}: must be a finite number > 0 (default 0.1875)",
                self.magic
            ));
        }
        if self.velocity_limit.is_nan() || self.velocity_limit <= 0.0 {
            return config_err(format!(
                "fluid.velocity_limit = {}: must be > 0 (default 0.5)",
                self.velocity_limit
            ));
        }
        Ok(())
    }
}
