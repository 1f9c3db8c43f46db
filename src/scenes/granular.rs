//! Dry rigid-body scenes (the fluid switched off with `fluid.enabled = false`): lengths in cells, time in
//! steps of `particles.dt`, so the same block grid and tasks run them as a coupled scene.
//!
//! - `granular_box`: spheres on a jittered lattice poured into a closed box settle into a pile;
//!   observables `max_overlap` (largest penetration / D in the final state), `kinetic_energy`,
//!   `max_speed`, `mean_height`.
//! - `incline`: one sphere on a plane inclined by θ, starting at rest. Theory: it rolls without slipping
//!   with a = (5/7) g sin θ when tan θ ≤ (7/2) μ, else slides with a = g (sin θ − μ cos θ). Observables
//!   `acceleration` (measured: the final down-slope speed over the elapsed time), `acceleration_theory`,
//!   `relative_error`, `rolling` (1 if the theory says it rolls) and `slip_speed` at the contact point.
//! - `collision`: a head-on pair (unequal masses) and an oblique, spinning pair, each meeting on a block
//!   face. Observables `restitution_head_on` (measured normal velocity ratio, to compare with
//!   `particles.restitution`), `momentum_error` and `angular_momentum_error` (relative to the sums of the
//!   magnitudes, both conserved by the contact impulses), `energy_ratio` (final / initial, ≤ 1).

use super::{check, ParticleScene, Scene};
use crate::config::Config;
use crate::error::{config_err, Result};
use crate::geometry::Geometry;
use blockflow_kernels::rigid::{detect_grid, Body, Plane};
use blockflow_kernels::TrtParams;
use glam::DVec3;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// `[scene]` keys of `kind = "granular_box"`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct GranularBoxConfig {
    /// Number of spheres.
    #[serde(default = "d_count")]
    pub count: usize,
    /// Sphere diameter D (cells).
    #[serde(default = "d_diameter")]
    pub diameter: f64,
    /// Box size (cells).
    #[serde(default = "d_size")]
    pub size: [usize; 3],
    /// Height of the lowest sphere centres at the start (cells).
    #[serde(default = "d_fill_from")]
    pub fill_from: f64,
    /// Particle density.
    #[serde(default = "one")]
    pub density: f64,
    /// Largest initial speed per axis (random, deterministic).
    #[serde(default = "d_jitter_speed")]
    pub initial_speed: f64,
    /// Seed of the deterministic initial jitter.
    #[serde(default = "one_u")]
    pub seed: u64,
    /// Default step count.
    #[serde(default = "d_gb_steps")]
    pub steps: u64,
}

fn d_count() -> usize {
    500
}
fn d_diameter() -> f64 {
    3.5
}
fn d_size() -> [usize; 3] {
    [32, 32, 64]
}
fn d_fill_from() -> f64 {
    12.0
}
fn one() -> f64 {
    1.0
}
fn one_u() -> u64 {
    1
}
fn d_jitter_speed() -> f64 {
    0.02
}
fn d_gb_steps() -> u64 {
    1500
}

/// `[scene]` keys of `kind = "incline"`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct InclineConfig {
    /// Inclination θ in degrees, in (0, 60].
    #[serde(default = "d_angle")]
    pub angle_deg: f64,
    /// Sphere diameter (cells).
    #[serde(default = "d_inc_diameter")]
    pub diameter: f64,
    /// Default step count.
    #[serde(default = "d_inc_steps")]
    pub steps: u64,
}

fn d_angle() -> f64 {
    20.0
}
fn d_inc_diameter() -> f64 {
    4.0
}
fn d_inc_steps() -> u64 {
    600
}

/// `[scene]` keys of `kind = "collision"`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CollisionConfig {
    /// Sphere diameter (cells).
    #[serde(default = "d_inc_diameter")]
    pub diameter: f64,
    /// Approach speed of each sphere (cells per step).
    #[serde(default = "d_speed")]
    pub speed: f64,
    /// Lateral offset of the oblique pair as a fraction of D, in [0, 1).
    #[serde(default = "d_impact")]
    pub impact_parameter: f64,
    /// Default step count.
    #[serde(default = "d_col_steps")]
    pub steps: u64,
}

fn d_speed() -> f64 {
    0.05
}
fn d_impact() -> f64 {
    0.5
}
fn d_col_steps() -> u64 {
    200
}

/// Deterministic uniform numbers in [-1, 1) from a seed and a counter.
fn uniform(seed: u64, k: u64) -> f64 {
    super::seeded_unit(seed, k) * 2.0 - 1.0
}

fn require_dry(cfg: &Config, name: &str) -> Result<()> {
    if cfg.fluid.enabled {
        return config_err(format!(
            "scene {name} is a dry rigid-body scene: set fluid.enabled = false (the fluid coupling is not part of it)"
        ));
    }
    Ok(())
}

fn dry_scene(name: &'static str, cells: [usize; 3], blocks: [usize; 3], steps: u64) -> Scene {
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
        init: Box::new(|_| (0.0, [0.0; 3])),
        observe: Box::new(|_| BTreeMap::new()),
        particles: None,
        units: None,
        description: String::new(),
    }
}

/// Largest penetration over all sphere pairs and sphere–plane contacts of `bodies`.
pub fn max_penetration(bodies: &[Body], planes: &[Plane]) -> f64 {
    detect_grid(bodies, planes, 0.0)
        .iter()
        .map(|c| c.depth)
        .fold(0.0, f64::max)
}

pub(super) fn build_granular_box(s: &GranularBoxConfig, cfg: &Config) -> Result<Scene> {
    require_dry(cfg, "granular_box")?;
    check("diameter", s.diameter, s.diameter > 0.0, "must be positive")?;
    check("density", s.density, s.density > 0.0, "must be positive")?;
    check("initial_speed", s.initial_speed, s.initial_speed >= 0.0, "must be ≥ 0")?;
    check(
        "fill_from",
        s.fill_from,
        s.fill_from >= s.diameter / 2.0,
        "must be at least D/2 (cells)",
    )?;
    if s.size.iter().any(|&n| (n as f64) < 2.0 * s.diameter) {
        return config_err(format!(
            "scene.size = {:?}: every side must hold at least two diameters",
            s.size
        ));
    }
    if s.count > super::MAX_BODIES {
        return config_err(format!(
            "scene.count = {}: must be at most {}",
            s.count,
            super::MAX_BODIES
        ));
    }
    let d = s.diameter;
    let spacing = 1.15 * d;
    let per = |a: usize| ((s.size[a] as f64 - 0.2 * d) / spacing).floor().max(0.0) as usize;
    let (nx, ny) = (per(0), per(1));
    let layer = nx * ny;
    let layers = if layer == 0 {
        usize::MAX
    } else {
        s.count.div_ceil(layer)
    };
    let top = s.fill_from + (layers.saturating_sub(1)) as f64 * spacing + d / 2.0;
    if layer == 0 || top > s.size[2] as f64 {
        return config_err(format!(
            "scene.count = {}: {} spheres of diameter {d} in layers of {layer} above scene.fill_from = {} need a box {:.1} \
             cells high, but scene.size = {:?}; lower the count or enlarge the box",
            s.count, s.count, s.fill_from, top, s.size
        ));
    }
    let r = d / 2.0;
    let off = |a: usize, n: usize| (s.size[a] as f64 - (n - 1) as f64 * spacing) / 2.0;
    let (x0, y0) = (off(0, nx), off(1, ny));
    let bodies: Vec<Body> = (0..s.count)
        .map(|i| {
            let (l, k) = (i / layer, i % layer);
            let (ix, iy) = (k % nx, k / nx);
            let u = |c: u64| uniform(s.seed, 8 * i as u64 + c);
            let jit = 0.04 * d;
            let mut b = Body::sphere(
                i as u64,
                DVec3::new(
                    x0 + ix as f64 * spacing + jit * u(0),
                    y0 + iy as f64 * spacing + jit * u(1),
                    s.fill_from + l as f64 * spacing,
                ),
                r,
                s.density,
            );
            b.velocity = DVec3::new(u(2), u(3), u(4)) * s.initial_speed;
            b
        })
        .collect();
    let planes = super::wall_planes(s.size, [false; 3]);
    let obs_planes = planes.clone();
    let mut scene = dry_scene("granular_box", s.size, [2, 2, 4], s.steps);
    scene.observe = Box::new(move |v| {
        let b = v.bodies();
        let ke: f64 = b.iter().map(|x| x.kinetic_energy()).sum();
        let vmax = b.iter().map(|x| x.velocity.length()).fold(0.0, f64::max);
        let h = b.iter().map(|x| x.position.z).sum::<f64>() / b.len().max(1) as f64;
        BTreeMap::from([
            ("max_overlap".to_string(), max_penetration(&b, &obs_planes) / d),
            ("kinetic_energy".to_string(), ke),
            ("max_speed".to_string(), vmax),
            ("mean_height".to_string(), h),
            ("bodies".to_string(), b.len() as f64),
        ])
    });
    scene.particles = Some(ParticleScene {
        bodies,
        planes,
        gravity: [0.0, 0.0, -2e-3],
        restitution_threshold: 1e-3,
        dt: 1.0,
    });
    scene.description = format!(
        "{} spheres of D = {d} cells poured into a closed {:?}-cell box, fluid off",
        s.count, s.size
    );
    Ok(scene)
}

pub(super) fn build_incline(s: &InclineConfig, cfg: &Config) -> Result<Scene> {
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

pub(super) fn build_collision(s: &CollisionConfig, cfg: &Config) -> Result<Scene> {
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
