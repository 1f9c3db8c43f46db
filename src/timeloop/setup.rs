//! How a run is assembled from its configuration: the simulation of a scene, the executor of
//! `[processes]` (placement and pinning), the estimator coefficients of `balance.coefficients` and the
//! initial assignment by `balance.weights`.

use crate::balance::{self, weights};
use crate::config::{Config, ContactSolver, PinConfig, StealConfig, Weights, DEFAULT_COEFFICIENTS};
use crate::error::{Error, Result};
use crate::estimator::coefficients::BUILT_IN_COEFFICIENTS;
use crate::estimator::Coefficients;
use crate::physics::coupling;
use crate::physics::domain::DomainSpec;
use crate::physics::particles::Particles;
use crate::physics::simulation::{CouplingParams, Simulation};
use crate::scenes::{self, ParticleScene, Scene};
use blockflow_kernels::rigid::RigidParams;
use blockflow_kernels::Real;
use blockflow_scheduler::executor::{Executor, PoolConfig, Steal};
use blockflow_scheduler::topology::{placement, PinPolicy, Topology};
use glam::DVec3;
use std::path::Path;

/// Builds the simulation of a scene: domain resolved, blocks built, bodies distributed and mapped,
/// initial state set.
pub fn build_sim<T: Real>(cfg: &Config, scene: &Scene) -> Result<Simulation<T>> {
    let mut sim = build_state(cfg, scene)?;
    sim.init(&scene.init);
    Ok(sim)
}

/// [`build_sim`] without the initial state: the blocks' fluid is left at rest (zero PDFs, no page
/// touched), for the caller to give up the blocks it will not hold before [`Simulation::init`].
pub fn build_state<T: Real>(cfg: &Config, scene: &Scene) -> Result<Simulation<T>> {
    let domain = scenes::domain_for(&cfg.domain, scene)?;
    let mut geometry = scene.geometry.clone();
    geometry.no_fluid |= !cfg.fluid.enabled;
    let coupling = CouplingParams {
        surface: cfg.particles.boundary,
        force_averaging: cfg.particles.force_averaging,
        conserve_momentum: cfg.particles.conserve_momentum,
        refill: cfg.particles.refill,
    };
    let mut sim = Simulation::<T>::new(
        domain,
        &geometry,
        scene.params,
        cfg.fluid.velocity_limit,
        cfg.fluid.kernel,
        cfg.fluid.streaming.pattern(),
        coupling,
    );
    if let Some(ps) = scene.particles.as_ref().filter(|_| cfg.particles.enabled) {
        let parts = build_particles(cfg, ps, domain)?;
        if !geometry.no_fluid {
            coupling::tasks::map_all(&parts, &sim.blocks, 0);
        }
        sim.particles = Some(parts);
    }
    if sim.fluid_cells() == 0 && !geometry.no_fluid {
        return Err(Error::Config(format!(
            "scene {}: the geometry leaves no fluid cell in the {:?}-cell domain; check the walls and planes \
             (scene.planes) and the domain size",
            scene.name,
            domain.cells()
        )));
    }
    Ok(sim)
}

/// The rigid bodies of a scene on the block grid, with `[particles]` applied over the scene's defaults.
pub fn build_particles(cfg: &Config, ps: &ParticleScene, domain: DomainSpec) -> Result<Particles> {
    let c = &cfg.particles;
    if cfg.fluid.enabled && c.dt.is_some_and(|dt| dt != 1.0) {
        return Err(Error::Config(
            "particles.dt: with the fluid on the step is the lattice time unit; remove the key".into(),
        ));
    }
    let params = RigidParams {
        gravity: DVec3::from(c.gravity.unwrap_or(ps.gravity)),
        fluid_density: if cfg.fluid.enabled { 1.0 } else { 0.0 },
        restitution: c.restitution,
        friction: c.friction,
        iterations: c.iterations(),
        relaxation: c.relaxation(),
        grid_threshold: c.grid_threshold,
        contact_margin: c.contact_margin,
        restitution_threshold: c.restitution_threshold.unwrap_or(ps.restitution_threshold),
        position_correction: c.position_correction,
    };
    Particles::new(
        domain,
        ps.bodies.clone(),
        ps.planes.clone(),
        params,
        c.subcycles,
        c.dt.unwrap_or(ps.dt),
    )
    .map(|p| match c.solver {
        ContactSolver::BlockGaussSeidel => p.with_rounds(c.rounds),
        ContactSolver::Jacobi => p.with_jacobi(c.warm_start),
    })
}

/// The pinning policy of a configuration.
pub fn pin_policy(cfg: &Config) -> Result<PinPolicy> {
    match &cfg.processes.pin {
        PinConfig::Name(s) => s
            .parse::<PinPolicy>()
            .map_err(|e| Error::Config(format!("processes.pin = {s:?}: {e}"))),
        PinConfig::Cores(v) => Ok(PinPolicy::List(v.clone())),
    }
}

/// Starts the worker threads of `[processes]`: P × T threads, pinned by `processes.pin`.
pub fn make_executor(cfg: &Config) -> Result<Executor> {
    let pr = &cfg.processes;
    let topo = Topology::detect();
    let cores = placement(&topo, pr.count, pr.threads_per_process, &pin_policy(cfg)?)
        .map_err(|e| Error::Config(format!("processes.pin: {e}")))?;
    Executor::new(PoolConfig {
        processes: pr.count,
        threads_per_process: pr.threads_per_process,
        cores,
        steal: match pr.steal {
            StealConfig::Process => Steal::Process,
            StealConfig::Global => Steal::Global,
        },
    })
    .map_err(|e| Error::Config(format!("[processes]: {e}")))
}

/// Starts the worker threads of one rank of `world`: one process of `processes.threads_per_process`
/// threads, pinned by `processes.pin` to the rank's share of the cores that the ranks on this machine
/// would use as that many processes (all ranks of an in-process group share one machine).
pub fn make_rank_executor(cfg: &Config, world: &crate::ranks::World) -> Result<Executor> {
    let pr = &cfg.processes;
    let ranks = world.ranks();
    if pr.count != ranks {
        return Err(Error::Config(format!(
            "processes.count = {} on {ranks} ranks: each rank is one process; set processes.count = {ranks} or              leave it out",
            pr.count
        )));
    }
    if pr.steal == StealConfig::Global {
        return Err(Error::Config(
            "processes.steal = \"global\" needs the processes to share memory; ranks do not: use \"process\"".into(),
        ));
    }
    let topo = Topology::detect();
    let t = pr.threads_per_process;
    let cores =
        placement(&topo, ranks, t, &pin_policy(cfg)?).map_err(|e| Error::Config(format!("processes.pin: {e}")))?;
    let r = world.rank();
    Executor::new(PoolConfig {
        processes: 1,
        threads_per_process: t,
        cores: cores[r * t..(r + 1) * t].to_vec(),
        steal: Steal::Process,
    })
    .map_err(|e| Error::Config(format!("[processes] of rank {r}: {e}")))
}

/// The estimator coefficients of `balance.coefficients` when `balance.weights` needs them (`estimator`,
/// `corrected`): the file, or for the default path without such a file in the working folder the copy
/// built into the binary; the error names the file and key.
pub fn coefficients(cfg: &Config) -> Result<Option<Coefficients>> {
    if !matches!(cfg.balance.weights, Weights::Estimator | Weights::Corrected) {
        return Ok(None);
    }
    let path = Path::new(&cfg.balance.coefficients);
    let loaded = if cfg.balance.coefficients == DEFAULT_COEFFICIENTS && !path.exists() {
        Coefficients::parse(BUILT_IN_COEFFICIENTS, "the built-in configs/coefficients.toml")
    } else {
        Coefficients::load(path)
    };
    loaded.map(Some).map_err(|e| {
        Error::Config(format!(
            "balance.coefficients: {e}; run `blockflow calibrate` to write one"
        ))
    })
}

/// The initial assignment of a configuration: the block weights of `balance.weights` before anything
/// was measured ([`weights::initial`]), and the owner process of every block by curve order
/// (`balance.strategy`; `none` is the static Hilbert split) and `balance.split`.
pub struct InitialAssignment {
    /// Block weights.
    pub weights: Vec<f64>,
    /// Owner process of every block.
    pub owners: Vec<u32>,
}

impl InitialAssignment {
    /// The initial assignment of `cfg` for `sim` on `cfg.processes.count` processes.
    pub fn of<T: Real>(cfg: &Config, sim: &Simulation<T>, coefficients: Option<&Coefficients>) -> Self {
        let weights = weights::initial(cfg.balance.weights, &weights::BlockState::of(sim), coefficients);
        let owners = balance::assign_with(
            sim.domain.blocks,
            &weights,
            cfg.processes.count,
            balance::curve_of(cfg.balance.strategy),
            cfg.balance.split,
        );
        InitialAssignment { weights, owners }
    }
}
