//! Shared pieces of the dry rigid-body scenes (the fluid switched off with `fluid.enabled = false`):
//! lengths in cells, time in steps of `particles.dt`, so the same block grid and tasks run them as a coupled
//! scene. The scenes: [`super::granular_box`], [`super::incline`], [`super::collision`].

use super::Scene;
use crate::config::Config;
use crate::error::{config_err, Result};
use crate::physics::geometry::Geometry;
use blockflow_kernels::rigid::{detect_grid, Body, Plane};
use blockflow_kernels::TrtParams;
use std::collections::BTreeMap;

/// Deterministic uniform numbers in [-1, 1) from a seed and a counter.
pub(super) fn uniform(seed: u64, k: u64) -> f64 {
    crate::util::hash::seeded_unit(seed, k) * 2.0 - 1.0
}

/// Refuses a dry scene run with the fluid on (the message names the scene and the key).
pub(super) fn require_dry(cfg: &Config, name: &str) -> Result<()> {
    if cfg.fluid.enabled {
        return config_err(format!(
            "scene {name} is a dry rigid-body scene: set fluid.enabled = false (the fluid coupling is not part of it)"
        ));
    }
    Ok(())
}

/// The scene skeleton of a dry scene: a closed box of `cells` without fluid, at rest.
pub(super) fn dry_scene(name: &'static str, cells: [usize; 3], blocks: [usize; 3], steps: u64) -> Scene {
    Scene {
        name,
        cells: Some(cells),
        periodic: [false; 3],
        default_blocks: blocks,
        geometry: Geometry {
            no_fluid: true,
            ..Geometry::default()
        },
        params: TrtParams {
            tau: 1.0,
            magic: 3.0 / 16.0,
            force: [0.0; 3],
        },
        steps,
        init: super::at_rest(),
        observe: Box::new(|_| BTreeMap::new()),
        particles: None,
        units: None,
        description: String::new(),
    }
}

/// Largest penetration over all sphere pairs and sphere–plane contacts of `bodies`.
pub(super) fn max_penetration(bodies: &[Body], planes: &[Plane]) -> f64 {
    detect_grid(bodies, planes, 0.0)
        .iter()
        .map(|c| c.depth)
        .fold(0.0, f64::max)
}
