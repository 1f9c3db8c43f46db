//! How a run is assembled from its configuration: the executor of `[processes]` (placement and pinning),
//! block weights of `balance.weights`, the initial assignment, the balancer of `balance.strategy` and the
//! pipeline that joins them. Used by `blockflow run`, `blockflow study` and the tests (re-exported by
//! [`crate::runner`]).

use crate::balance::{self, curves::Curve};
use crate::config::{Config, PinConfig, StealConfig, Strategy};
use crate::error::{Error, Result};
use crate::pipeline::Pipeline;
use crate::sim::Simulation;
use blockflow_kernels::Real;
use blockflow_scheduler::executor::{Executor, PoolConfig, Steal};
use blockflow_scheduler::topology::{placement, PinPolicy, Topology};
use std::path::Path;

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

/// Block weights of `balance.weights`: fluid cells, or the estimate of eq. (15) with the coefficients
/// of `balance.coefficients` (the file is read and checked here; errors name the file and key).
pub fn block_weights<T: Real>(cfg: &Config, sim: &Simulation<T>) -> Result<Vec<f64>> {
    use crate::config::Weights;
    match cfg.balance.weights {
        // Nothing is measured before the first interval: `measured` starts from cells.
        Weights::Cells | Weights::Measured => {
            let dry = sim.fluid_cells() == 0;
            Ok(sim
                .blocks
                .iter()
                .map(|b| if dry { b.layout.interior_cells() } else { b.current_fluid_cells() } as f64)
                .collect())
        }
        Weights::Estimator | Weights::Corrected => {
            let c = load_coefficients(cfg)?;
            Ok((0..sim.blocks.len())
                .map(|b| c.total(&crate::calibrate::quantities(sim, b)))
                .collect())
        }
    }
}

/// The estimator coefficients of `balance.coefficients`; the error names the file and key.
pub fn load_coefficients(cfg: &Config) -> Result<crate::estimator::Coefficients> {
    crate::estimator::Coefficients::load(Path::new(&cfg.balance.coefficients)).map_err(|e| {
        Error::Config(format!(
            "balance.coefficients: {e}; run `blockflow calibrate` to write one"
        ))
    })
}

/// Owner process of every block by `balance.weights` (see [`block_weights`]): curve order
/// (`balance.strategy`; `none` is the static Hilbert split), greedy prefix split.
pub fn assignment_weighted<T: Real>(cfg: &Config, sim: &Simulation<T>) -> Result<Vec<u32>> {
    let curve = match cfg.balance.strategy {
        Strategy::None | Strategy::Hilbert | Strategy::Diffusive | Strategy::Metis => Curve::Hilbert,
        Strategy::Morton => Curve::Morton,
    };
    let weights = block_weights(cfg, sim)?;
    Ok(balance::assign_with(
        sim.domain.blocks,
        &weights,
        cfg.processes.count,
        curve,
        cfg.balance.split,
    ))
}

/// Owner process of every block: curve order (`balance.strategy`; `none` is the static Hilbert split),
/// greedy prefix split by fluid-cell count (cell count in scenes without fluid).
pub fn assignment<T: Real>(cfg: &Config, sim: &Simulation<T>) -> Vec<u32> {
    let curve = match cfg.balance.strategy {
        Strategy::None | Strategy::Hilbert | Strategy::Diffusive | Strategy::Metis => Curve::Hilbert,
        Strategy::Morton => Curve::Morton,
    };
    // Without fluid (dry rigid-body scenes) every block weighs its cell count.
    let dry = sim.fluid_cells() == 0;
    let weights: Vec<f64> = sim
        .blocks
        .iter()
        .map(|b| if dry { b.layout.interior_cells() } else { b.fluid_cells } as f64)
        .collect();
    balance::assign(sim.domain.blocks, &weights, cfg.processes.count, curve)
}

/// The balancer of `balance.strategy` on `processes.count` processes (none for `"none"`: the
/// assignment never changes).
pub fn make_balancer<T: Real>(cfg: &Config, sim: &Simulation<T>) -> Result<Option<crate::balance::dynamic::Balancer>> {
    use crate::config::Weights;
    if cfg.balance.strategy == Strategy::None {
        return Ok(None);
    }
    let coeffs = match cfg.balance.weights {
        Weights::Estimator | Weights::Corrected => Some(load_coefficients(cfg)?),
        _ => None,
    };
    Ok(Some(crate::balance::dynamic::Balancer::new(
        cfg.balance.weights,
        crate::balance::strategy::strategy(&cfg.balance),
        cfg.processes.count,
        coeffs,
        &sim.domain,
    )))
}

/// The pipeline of a run: the executor of `[processes]`, the initial assignment by `balance.weights`
/// (with the load imbalance those weights predict for the first interval), the balancer, the message
/// price of the modeled times, and the first touch of every block by its owner.
pub fn make_pipeline<T: Real>(cfg: &Config, sim: &Simulation<T>) -> Result<Pipeline<T>> {
    let exec = make_executor(cfg)?;
    let owners = assignment_weighted(cfg, sim)?;
    let weights = block_weights(cfg, sim)?;
    let mut pipe = Pipeline::new(sim, exec, owners, cfg.processes.steps_per_graph, cfg.balance.interval);
    pipe.surface = cfg.particles.boundary;
    pipe.force_averaging = cfg.particles.force_averaging;
    pipe.comm = crate::study::model::CommModel {
        latency: cfg.balance.latency,
        bandwidth: cfg.balance.bandwidth,
    };
    pipe.set_predicted_imbalance(&weights);
    pipe.balancer = make_balancer(cfg, sim)?;
    pipe.first_touch(sim);
    Ok(pipe)
}

pub use crate::balance::edge_cut_mean;
