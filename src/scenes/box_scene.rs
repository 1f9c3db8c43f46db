//! `box`: a box of fluid given by the `[domain]` keys (blocks × block_size, periodic per axis, resting
//! walls on non-periodic faces), cut by planes of any orientation, with an optional uniform body force and
//! initial velocity. The general-purpose scene for geometry checks and experiments.

use super::{check, kinetic_energy, ParticleScene, Scene};
use crate::config::Config;
use crate::error::{config_err, Result};
use crate::physics::geometry::{Geometry, WallPlane};
use blockflow_kernels::rigid::{Body, Plane};
use blockflow_kernels::TrtParams;
use glam::DVec3;
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

/// One sphere of `scene.spheres`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SphereConfig {
    /// Centre (cells, global coordinates).
    pub centre: [f64; 3],
    /// Radius (cells).
    pub radius: f64,
    /// Density relative to the fluid.
    #[serde(default = "one")]
    pub density: f64,
    /// Initial velocity (lattice units).
    #[serde(default)]
    pub velocity: [f64; 3],
    /// Initial angular velocity.
    #[serde(default)]
    pub angular_velocity: [f64; 3],
    /// A fixed sphere never moves.
    #[serde(default)]
    pub fixed: bool,
}

fn one() -> f64 {
    1.0
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
    /// Spheres coupled to the fluid (ids in list order); walls and planes are also rigid planes for them.
    #[serde(default)]
    pub spheres: Vec<SphereConfig>,
    /// Gravity on the spheres (lattice units); `particles.gravity` overrides.
    #[serde(default)]
    pub gravity: [f64; 3],
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
        match WallPlane::through(p.point, p.normal, p.velocity) {
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
    let mut bodies = Vec::new();
    for (i, sp) in s.spheres.iter().enumerate() {
        let vals = sp.centre.iter().chain(&sp.velocity).chain(&sp.angular_velocity);
        if vals.clone().any(|v| !v.is_finite())
            || sp.radius.is_nan()
            || sp.radius <= 0.0
            || sp.density.is_nan()
            || sp.density <= 0.0
        {
            return config_err(format!(
                "scene.spheres[{i}]: centre, velocity and angular_velocity must be finite, radius and density > 0"
            ));
        }
        let mut b = Body::sphere(i as u64, DVec3::from(sp.centre), sp.radius, sp.density);
        b.velocity = DVec3::from(sp.velocity);
        b.angular_velocity = DVec3::from(sp.angular_velocity);
        b.fixed = sp.fixed;
        bodies.push(b);
    }
    let particles = if bodies.is_empty() {
        None
    } else {
        let periodic = cfg.domain.periodic.unwrap_or([true; 3]);
        let cells = super::extent_of(
            cfg.domain.blocks.unwrap_or([1, 1, 1]),
            cfg.domain.block_size.unwrap_or([16, 16, 16]),
        )?;
        let mut planes = super::wall_planes(cells, periodic);
        for (i, p) in geometry.planes.iter().enumerate() {
            planes.push(Plane {
                normal: DVec3::from(p.normal),
                offset: p.offset,
                id: i as u64,
            });
        }
        Some(ParticleScene {
            bodies,
            planes,
            gravity: s.gravity,
            restitution_threshold: 1e-3,
            dt: 1.0,
        })
    };
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
        particles,
        units: None,
        description: format!(
            "box with {} planes and {} spheres, tau = {tau}",
            s.planes.len(),
            s.spheres.len()
        ),
    })
}
