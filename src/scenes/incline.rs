//! `incline`: one sphere on a plane inclined by θ, starting at rest (a dry scene, fluid off). Theory:
//! it rolls without slipping with a = (5/7) g sin θ when tan θ ≤ (7/2) μ, else slides with
//! a = g (sin θ − μ cos θ). Observables `acceleration` (measured: the final down-slope speed over the
//! elapsed time), `acceleration_theory`, `relative_error`, `rolling` (1 if the theory says it rolls) and
//! `slip_speed` at the contact point.

use super::dry::{dry_scene, require_dry};
use super::{check, ParticleScene, Scene};
use crate::config::scene::InclineConfig;
use crate::config::Config;
use crate::error::Result;
use blockflow_kernels::rigid::{Body, Plane};
use glam::DVec3;
use std::collections::BTreeMap;

pub(super) fn build(s: &InclineConfig, cfg: &Config) -> Result<Scene> {
    require_dry(cfg, "incline")?;
    check(
        "angle_deg",
        s.angle_deg,
        s.angle_deg > 0.0 && s.angle_deg <= 60.0,
        "must be in (0, 60] degrees",
    )?;
    check(
        "diameter",
        s.diameter,
        s.diameter > 0.0 && s.diameter <= 8.0,
        "must be in (0, 8] cells",
    )?;
    let cells = [96, 16, 48];
    let th = s.angle_deg.to_radians();
    let n = DVec3::new(-th.sin(), 0.0, th.cos());
    let p0 = DVec3::new(86.0, 8.0, 40.0);
    let mut planes = super::wall_planes(cells, [false; 3]);
    planes.push(Plane::through(1, p0, n));
    let r = s.diameter / 2.0;
    let body = Body::sphere(0, p0 + n * r, r, 1.0);
    let g = cfg.particles.gravity.unwrap_or([0.0, 0.0, -2e-4]);
    let g_mag = DVec3::from(g).length();
    let mu = cfg.particles.friction;
    let rolls = th.tan() <= 3.5 * mu;
    let theory = if rolls {
        5.0 / 7.0 * g_mag * th.sin()
    } else {
        g_mag * (th.sin() - mu * th.cos())
    };
    let down = DVec3::new(-th.cos(), 0.0, -th.sin());
    let dt = cfg.particles.dt.unwrap_or(1.0);
    let mut scene = dry_scene("incline", cells, [6, 1, 3], s.steps);
    scene.observe = Box::new(move |v| {
        let b = v.bodies();
        let t = v.steps_taken() as f64 * dt;
        let x = &b[0];
        let a = x.velocity.dot(down) / t;
        let slip = x.point_velocity(x.position - n * x.radius).length();
        BTreeMap::from([
            ("acceleration".to_string(), a),
            ("acceleration_theory".to_string(), theory),
            ("relative_error".to_string(), (a - theory).abs() / theory.abs()),
            ("rolling".to_string(), if rolls { 1.0 } else { 0.0 }),
            ("slip_speed".to_string(), slip),
            ("distance".to_string(), (x.position - (p0 + n * r)).dot(down)),
        ])
    });
    scene.particles = Some(ParticleScene {
        bodies: vec![body],
        planes,
        gravity: [0.0, 0.0, -2e-4],
        restitution_threshold: 1e-3,
        dt: 1.0,
    });
    scene.description = format!(
        "sphere of D = {} on a plane inclined by {} degrees, mu = {mu}: {} expected",
        s.diameter,
        s.angle_deg,
        if rolls { "rolling" } else { "sliding" }
    );
    Ok(scene)
}
