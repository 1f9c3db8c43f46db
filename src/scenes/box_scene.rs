//! `box`: a box of fluid given by the `[domain]` keys (blocks × block_size, periodic per axis, resting
//! walls on non-periodic faces), cut by planes of any orientation, with an optional uniform body force and
//! initial velocity. The general-purpose scene for geometry checks and experiments.

use super::{check, kinetic_energy, Scene};
use crate::config::Config;
use crate::error::{config_err, Result};
use crate::geometry::{Geometry, Plane};
use blockflow_kernels::TrtParams;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// One plane of `scene.planes`: cells whose centre lies on the side opposite to `normal` are solid.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PlaneConfig {
    /// A point on the plane (cells, global coordinates).
    pub point: [f64; 3],
    /// Normal pointing into the fluid (any length > 0).
    pub normal: [f64; 3],
    /// Tangential wall velocity (lattice units).
    #[serde(default)]
    pub velocity: [f64; 3],
}

/// `[scene]` keys of `kind = "box"`.
#[derive(Clone, Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct BoxConfig {
    /// Uniform body force (lattice units).
    #[serde(default)]
    pub force: [f64; 3],
    /// Uniform initial velocity (lattice units).
    #[serde(default)]
    pub velocity: [f64; 3],
    /// Planes cutting the box.
    #[serde(default)]
    pub planes: Vec<PlaneConfig>,
    /// Default step count when `run.steps` is absent.
    #[serde(default = "d_steps")]
    pub steps: u64,
}

fn d_steps() -> u64 {
    100
}

pub(super) fn build(s: &BoxConfig, cfg: &Config) -> Result<Scene> {
    let tau = cfg.fluid.tau.unwrap_or(0.8);
    let mut geometry = Geometry::default();
    for (i, p) in s.planes.iter().enumerate() {
        if p.point
            .iter()
            .chain(&p.normal)
            .chain(&p.velocity)
            .any(|v| !v.is_finite())
        {
            return config_err(format!(
                "scene.planes[{i}]: point, normal and velocity must be finite numbers"
            ));
        }
        match Plane::through(p.point, p.normal, p.velocity) {
            Some(pl) => geometry.planes.push(pl),
            None => return config_err(format!("scene.planes[{i}].normal = {:?}: must not be zero", p.normal)),
        }
    }
    for a in 0..3 {
        check("force", s.force[a], true, "must be finite")?;
        check(
            "velocity",
            s.velocity[a],
            s.velocity[a].abs() < 0.4,
            "each component must be below 0.4 in magnitude",
        )?;
    }
    let u = s.velocity;
    Ok(Scene {
        name: "box",
        cells: None,
        periodic: [true, true, true],
        default_blocks: [1, 1, 1],
        geometry,
        params: TrtParams {
            tau,
            magic: cfg.fluid.magic,
            force: s.force,
        },
        steps: s.steps,
        init: Box::new(move |_| (0.0, u)),
        observe: Box::new(|v| BTreeMap::from([("kinetic_energy".to_string(), kinetic_energy(v))])),
        particles: None,
        description: format!("box with {} planes, tau = {tau}", s.planes.len()),
    })
}
