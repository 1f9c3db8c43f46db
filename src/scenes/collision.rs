//! `collision`: a head-on pair (unequal masses) and an oblique, spinning pair, each meeting on a block
//! face (a dry scene, fluid off). Observables `restitution_head_on` (measured normal velocity ratio, to
//! compare with `particles.restitution`), `momentum_error` and `angular_momentum_error` (relative to the
//! sums of the magnitudes, both conserved by the contact impulses), `energy_ratio` (final / initial, ≤ 1).

use super::dry::{dry_scene, require_dry};
use super::{check, ParticleScene, Scene};
use crate::config::scene::CollisionConfig;
use crate::config::Config;
use crate::error::Result;
use blockflow_kernels::rigid::Body;
use glam::DVec3;
use std::collections::BTreeMap;

/// Linear and angular momentum (about the origin) of a set of bodies, and the sums of the magnitudes
/// of the terms (the scale of their rounding errors).
fn momenta(bodies: &[Body]) -> (DVec3, DVec3, f64, f64) {
    let (mut p, mut l, mut ps, mut ls) = (DVec3::ZERO, DVec3::ZERO, 0.0, 0.0);
    for b in bodies {
        let mv = b.mass() * b.velocity;
        let lo = b.position.cross(mv);
        let ls_ = b.inertia() * b.angular_velocity;
        p += mv;
        l += lo + ls_;
        ps += mv.length();
        ls += lo.length() + ls_.length();
    }
    (p, l, ps, ls)
}

pub(super) fn build(s: &CollisionConfig, cfg: &Config) -> Result<Scene> {
    require_dry(cfg, "collision")?;
    check(
        "diameter",
        s.diameter,
        s.diameter > 0.0 && s.diameter <= 8.0,
        "must be in (0, 8] cells",
    )?;
    check(
        "speed",
        s.speed,
        s.speed > 0.0 && s.speed < 0.5,
        "must be in (0, 0.5) cells per step",
    )?;
    check(
        "impact_parameter",
        s.impact_parameter,
        (0.0..1.0).contains(&s.impact_parameter),
        "must be in [0, 1)",
    )?;
    let cells = [64, 32, 32];
    let (d, r, u) = (s.diameter, s.diameter / 2.0, s.speed);
    let gap = 10.0 * u; // they meet after 5 steps
    let mut a = Body::sphere(0, DVec3::new(32.0 - r - gap / 2.0, 8.0, 8.0), r, 1.0);
    let mut b = Body::sphere(1, DVec3::new(32.0 + r + gap / 2.0, 8.0, 8.0), r, 2.0);
    a.velocity = DVec3::new(u, 0.0, 0.0);
    b.velocity = DVec3::new(-u, 0.0, 0.0);
    let h = s.impact_parameter * d;
    let lateral = (d * d - h * h).sqrt();
    let mut c = Body::sphere(
        2,
        DVec3::new(32.0 - lateral / 2.0 - gap / 2.0, 16.0 - h / 2.0, 24.0),
        r,
        1.0,
    );
    let mut e = Body::sphere(
        3,
        DVec3::new(32.0 + lateral / 2.0 + gap / 2.0, 16.0 + h / 2.0, 24.0),
        r,
        1.0,
    );
    c.velocity = DVec3::new(u, 0.0, 0.0);
    c.angular_velocity = DVec3::new(0.0, 0.0, 0.3 * u / r);
    e.velocity = DVec3::new(-u, 0.0, 0.0);
    let initial = vec![a, b, c, e];
    let (p0, l0, ps, ls) = momenta(&initial);
    let e0: f64 = initial.iter().map(|x| x.kinetic_energy()).sum();
    let approach = 2.0 * u;
    let mut scene = dry_scene("collision", cells, [4, 2, 2], s.steps);
    scene.observe = Box::new(move |v| {
        let bs = v.bodies();
        let (p, l, _, _) = momenta(&bs);
        let e1: f64 = bs.iter().map(|x| x.kinetic_energy()).sum();
        BTreeMap::from([
            (
                "restitution_head_on".to_string(),
                (bs[1].velocity.x - bs[0].velocity.x) / approach,
            ),
            ("momentum_error".to_string(), (p - p0).length() / ps),
            ("angular_momentum_error".to_string(), (l - l0).length() / ls),
            ("energy_ratio".to_string(), e1 / e0),
        ])
    });
    scene.particles = Some(ParticleScene {
        bodies: initial,
        planes: super::wall_planes(cells, [false; 3]),
        gravity: [0.0; 3],
        restitution_threshold: 1e-4,
        dt: 1.0,
    });
    scene.description = format!(
        "head-on pair (density 1 and 2) and oblique spinning pair (offset {} D), D = {d}, speed {u}",
        s.impact_parameter
    );
    Ok(scene)
}
