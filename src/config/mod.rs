//! Scene configuration: TOML files with the stable keys of DESIGN.md, one file per table (`[domain]`,
//! `[fluid]`, `[run]`, `[processes]`, `[balance]`, `[particles]`, and `[scene]` in [`scene`], one module per
//! scene kind), `--set key.path=value` overrides ([`load`], [`parse()`]), unknown keys rejected by name. The
//! enums that switch a run's algorithms (precision, kernels, surface boundary, strategy, weights, split) live
//! here too, so every layer above reads them from one place.

mod balance;
mod domain;
mod fluid;
mod parse;
mod particles;
mod processes;
mod run;
pub mod scene;

pub use balance::{
    BalanceConfig, DiffusiveMode, SplitKind, Strategy, Weights, DEFAULT_BANDWIDTH, DEFAULT_COEFFICIENTS,
    DEFAULT_LATENCY,
};
pub use domain::DomainConfig;
pub use fluid::{FluidConfig, KernelChoice, Precision, Streaming};
pub use parse::{apply_override, load, parse, parse_table};
pub use particles::{ContactSolver, ParticlesConfig, Refill, SurfaceBoundary};
pub use processes::{PinConfig, ProcessesConfig, StealConfig, MAX_PROCESS_COUNT};
pub use run::{RunConfig, VtkEncoding, DEFAULT_KEPT};

use crate::error::Result;
use serde::{Deserialize, Serialize};

/// A whole scene file.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// Block decomposition (`[domain]`).
    #[serde(default)]
    pub domain: DomainConfig,
    /// Fluid model (`[fluid]`).
    #[serde(default)]
    pub fluid: FluidConfig,
    /// Run control (`[run]`).
    #[serde(default)]
    pub run: RunConfig,
    /// Virtual processes and threads (`[processes]`).
    #[serde(default)]
    pub processes: ProcessesConfig,
    /// Block assignment and balancing (`[balance]`).
    #[serde(default)]
    pub balance: BalanceConfig,
    /// Rigid bodies and their solver (`[particles]`).
    #[serde(default)]
    pub particles: ParticlesConfig,
    /// The scene and its physical parameters (`[scene]`, chosen by `kind`).
    pub scene: scene::SceneConfig,
}

impl Config {
    /// Checks the generic keys; scenes check their own.
    pub fn validate(&self) -> Result<()> {
        self.fluid.validate()?;
        self.domain.validate()?;
        self.processes.validate()?;
        self.particles.validate()?;
        self.balance.validate()?;
        if !self.fluid.enabled && !self.particles.enabled {
            return crate::error::config_err(
                "fluid.enabled = false and particles.enabled = false: nothing is left to simulate; enable one",
            );
        }
        self.run.validate()
    }

    /// The configuration as TOML (what `effective.toml` holds: every default and override resolved).
    pub fn to_toml(&self) -> String {
        let mut c = self.clone();
        c.particles.relaxation = Some(self.particles.relaxation());
        c.particles.iterations = Some(self.particles.iterations());
        toml::to_string(&c).unwrap_or_default()
    }
}
