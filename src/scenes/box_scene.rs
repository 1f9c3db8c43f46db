//! `box`: a box of fluid given by the `[domain]` keys (blocks × block_size, periodic per axis, resting
//! walls on non-periodic faces), cut by planes of any orientation, with an optional uniform body force and
//! initial velocity. The general-purpose scene for geometry checks and experiments.

use super::{check, kinetic_energy, ParticleScene, Scene};
use crate::config::scene::BoxConfig;
use crate::config::Config;
use crate::error::{config_err, Result};
use crate::physics::geometry::{Geometry, WallPlane};
use blockflow_kernels::rigid::{Body, Plane};
use blockflow_kernels::TrtParams;
use glam::DVec3;
use std::collections::BTreeMap;

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
