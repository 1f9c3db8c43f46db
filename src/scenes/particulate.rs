//! Particulate flow scenes (the fluid coupled to rigid spheres, section 2.3).
//!
//! - `drag_array`: one fixed sphere in a periodic cube, i.e. a simple cubic array of spheres, driven by
//!   a uniform body force (Stokes flow). `scene.resolution` is the diameter D in cells,
//!   `scene.solid_fraction` φ fixes the cube edge L = round(D (π / 6φ)^(1/3)); the radius is then set to
//!   a = (3 φ L³ / 4π)^(1/3) so that φ is exact. Observables: `drag_normalized` K = F / (6 π μ a U) with
//!   U the superficial velocity (mean velocity over the whole cube, solid included) and F the force of the
//!   equivalent pressure-driven array, F = F_me + f V_p (momentum exchange plus the driving force density
//!   times the sphere volume: Zick & Homsy drive by a mean pressure gradient, which also pushes on the
//!   sphere volume; the body force here acts on the fluid only), `drag_reference`
//!   and `relative_error` against Zick & Homsy (1982) where φ is one of their tabulated fractions,
//!   `reynolds` = U D / ν.

use super::{check, ParticleScene, Scene};
use crate::config::Config;
use crate::error::Result;
use crate::geometry::Geometry;
use blockflow_kernels::rigid::Body;
use blockflow_kernels::TrtParams;
use glam::DVec3;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// `[scene]` keys of `kind = "drag_array"`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct DragArrayConfig {
    /// Sphere diameter D in cells.
    #[serde(default = "d_res")]
    pub resolution: f64,
    /// Solid volume fraction φ of the array, in (0, 0.5].
    #[serde(default = "d_phi")]
    pub solid_fraction: f64,
    /// Particle Reynolds number U D / ν the body force aims at (Stokes regime: keep it small).
    #[serde(default = "d_re")]
    pub reynolds: f64,
    /// Steps; absent: L² / ν (the viscous time of the cube: the drag has settled to about 1e-5 by then).
    pub steps: Option<u64>,
}

fn d_res() -> f64 {
    16.0
}
fn d_phi() -> f64 {
    0.125
}
fn d_re() -> f64 {
    0.01
}

/// Zick & Homsy (1982), simple cubic arrays: (φ, K = F / 6πμaU).
pub const ZICK_HOMSY: [(f64, f64); 3] = [(0.064, 2.81), (0.125, 4.29), (0.216, 7.44)];

pub(super) fn build_drag_array(s: &DragArrayConfig, cfg: &Config) -> Result<Scene> {
    check(
        "resolution",
        s.resolution,
        s.resolution >= 2.0 && s.resolution <= 256.0,
        "must be a diameter between 2 and 256 cells",
    )?;
    check(
        "solid_fraction",
        s.solid_fraction,
        s.solid_fraction > 0.0 && s.solid_fraction <= 0.5,
        "must be in (0, 0.5] (touching spheres are at π/6 ≈ 0.524)",
    )?;
    check(
        "reynolds",
        s.reynolds,
        s.reynolds > 0.0 && s.reynolds <= 10.0,
        "must be in (0, 10]",
    )?;
    let phi = s.solid_fraction;
    let l = (s.resolution * (std::f64::consts::PI / (6.0 * phi)).cbrt())
        .round()
        .max(3.0) as usize;
    let lf = l as f64;
    let a = (3.0 * phi * lf.powi(3) / (4.0 * std::f64::consts::PI)).cbrt();
    let tau = cfg.fluid.tau.unwrap_or(1.0);
    let nu = (tau - 0.5) / 3.0;
    let u_target = s.reynolds * nu / (2.0 * a);
    // Force from a rough drag estimate (Hasimoto-type fit), only to aim at the requested Reynolds number.
    let k_est = 1.0 / (1.0 - 1.7601 * phi.cbrt() + phi - 1.5593 * phi * phi).max(0.05);
    let force = 6.0 * std::f64::consts::PI * nu * a * u_target * k_est / (lf.powi(3) * (1.0 - phi));
    let centre = DVec3::splat(lf / 2.0);
    let mut body = Body::sphere(0, centre, a, 1.0);
    body.fixed = true;
    let steps = s.steps.unwrap_or((lf * lf / nu).ceil() as u64);
    let reference = ZICK_HOMSY.iter().find(|z| (z.0 - phi).abs() < 1e-9).map(|z| z.1);
    let n_cells = lf.powi(3);
    let observe = Box::new(move |v: &dyn super::FluidView| {
        let mut ux = 0.0;
        v.visit(&mut |_, _, u| ux += u[0]);
        let u_sup = ux / n_cells;
        let f_me = v.hydro_forces().first().map_or(0.0, |x| x.force.x);
        // The body force drives the fluid only; Zick & Homsy drive by a mean pressure gradient G = f, whose
        // force on the array includes G V_p on the sphere volume: F = F_me + f V_p (= f L³ when steady).
        let f = f_me + force * 4.0 / 3.0 * std::f64::consts::PI * a.powi(3);
        let k = f / (6.0 * std::f64::consts::PI * nu * a * u_sup);
        let mut o = BTreeMap::from([
            ("drag_normalized".to_string(), k),
            ("superficial_velocity".to_string(), u_sup),
            ("reynolds".to_string(), u_sup * 2.0 * a / nu),
            ("force".to_string(), f),
            ("force_momentum_exchange".to_string(), f_me),
            ("solid_fraction".to_string(), phi),
            ("radius".to_string(), a),
        ]);
        if let Some(r) = reference {
            o.insert("drag_reference".to_string(), r);
            o.insert("relative_error".to_string(), (k - r).abs() / r);
        }
        o
    });
    Ok(Scene {
        name: "drag_array",
        cells: Some([l, l, l]),
        periodic: [true; 3],
        default_blocks: [1, 1, 1],
        geometry: Geometry::default(),
        params: TrtParams {
            tau,
            magic: cfg.fluid.magic,
            force: [force, 0.0, 0.0],
        },
        steps,
        init: Box::new(|_| (0.0, [0.0; 3])),
        observe,
        particles: Some(ParticleScene {
            bodies: vec![body],
            planes: Vec::new(),
            gravity: [0.0; 3],
            restitution_threshold: 1e-4,
            dt: 1.0,
        }),
        units: None,
        description: format!(
            "simple cubic array: sphere of D = {:.3} in a periodic {l}^3 cube, solid fraction {phi}, tau = {tau}",
            2.0 * a
        ),
    })
}

fn d_density_ratio() -> f64 {
    1.5
}
fn d_galileo() -> f64 {
    30.0
}

/// Gravity magnitude from the Galileo number: g = Ga² ν² / ((ρr − 1) D³).
fn gravity_from_galileo(ga: f64, nu: f64, ratio: f64, d: f64) -> f64 {
    ga * ga * nu * nu / ((ratio - 1.0) * d.powi(3))
}

/// `[scene]` keys of `kind = "hopper"` (section 4.3): spheres densely packed under the lid settle through
/// four inclined planes that narrow the horizontal cross-section toward the bottom.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct HopperConfig {
    /// Sphere diameter D in cells.
    #[serde(default = "d_hopper_d")]
    pub diameter: f64,
    /// Number of spheres.
    #[serde(default = "d_hopper_count")]
    pub count: usize,
    /// Galileo number (sets the gravity).
    #[serde(default = "d_hopper_ga")]
    pub galileo: f64,
    /// Density ratio ρp / ρf.
    #[serde(default = "d_density_ratio")]
    pub density_ratio: f64,
    /// Share by which the four planes reduce the horizontal cross-section at the bottom.
    #[serde(default = "d_narrowing")]
    pub narrowing: f64,
    /// Height of the funnel (where the planes meet the side walls) as a fraction of the box height.
    #[serde(default = "d_funnel")]
    pub funnel_height: f64,
    /// Seed of the initial jitter.
    #[serde(default = "d_seed")]
    pub seed: u64,
    /// Default step count.
    #[serde(default = "d_hopper_steps")]
    pub steps: u64,
}

fn d_hopper_d() -> f64 {
    7.5
}
fn d_hopper_count() -> usize {
    540
}
fn d_hopper_ga() -> f64 {
    50.0
}
fn d_narrowing() -> f64 {
    0.6
}
fn d_funnel() -> f64 {
    0.4
}
fn d_seed() -> u64 {
    1
}
fn d_hopper_steps() -> u64 {
    4000
}

pub(super) fn build_hopper(s: &HopperConfig, cfg: &Config) -> Result<Scene> {
    check("diameter", s.diameter, s.diameter >= 3.0, "must be at least 3 cells")?;
    check(
        "galileo",
        s.galileo,
        s.galileo > 0.0 && s.galileo <= 500.0,
        "must be in (0, 500]",
    )?;
    check("density_ratio", s.density_ratio, s.density_ratio > 1.0, "must be > 1")?;
    check(
        "narrowing",
        s.narrowing,
        s.narrowing > 0.0 && s.narrowing < 0.9,
        "must be in (0, 0.9)",
    )?;
    check(
        "funnel_height",
        s.funnel_height,
        s.funnel_height > 0.05 && s.funnel_height < 0.8,
        "must be in (0.05, 0.8)",
    )?;
    let blocks = cfg.domain.blocks.unwrap_or([6, 6, 8]);
    let bs = cfg.domain.block_size.unwrap_or([16, 16, 16]);
    let cells = super::extent_of(blocks, bs)?;
    let (lx, ly, lz) = (cells[0] as f64, cells[1] as f64, cells[2] as f64);
    let tau = cfg.fluid.tau.unwrap_or(0.52);
    let nu = (tau - 0.5) / 3.0;
    let d = s.diameter;
    let g = gravity_from_galileo(s.galileo, nu, s.density_ratio, d);
    // Four planes from the side walls at the funnel top down to an opening of sqrt(1 − narrowing) of the
    // width at the bottom (cross-section reduced by `narrowing`).
    let hf = s.funnel_height * lz;
    let shrink = (1.0 - (1.0 - s.narrowing).sqrt()) / 2.0;
    let (ix, iy) = (shrink * lx, shrink * ly);
    let mut geometry = Geometry::default();
    let mut planes = super::wall_planes(cells, [false; 3]);
    let mut add = |point: [f64; 3], normal: [f64; 3], id: u64| -> Result<()> {
        let fp = crate::geometry::Plane::through(point, normal, [0.0; 3]).expect("non-zero normal");
        geometry.planes.push(fp);
        planes.push(blockflow_kernels::rigid::Plane::through(
            id,
            DVec3::from(point),
            DVec3::from(normal),
        ));
        Ok(())
    };
    add([ix, 0.0, 0.0], [hf, 0.0, ix], 1)?;
    add([lx - ix, 0.0, 0.0], [-hf, 0.0, ix], 2)?;
    add([0.0, iy, 0.0], [0.0, hf, iy], 3)?;
    add([0.0, ly - iy, 0.0], [0.0, -hf, iy], 4)?;
    // Spheres on a jittered lattice under the lid.
    let spacing = 1.1 * d;
    let nx = ((lx - 0.2 * d) / spacing).floor() as usize;
    let ny = ((ly - 0.2 * d) / spacing).floor() as usize;
    let layer = nx * ny;
    if layer == 0 {
        return crate::error::config_err(format!("scene.diameter = {d}: the box {cells:?} holds no sphere"));
    }
    if s.count > super::MAX_BODIES {
        return crate::error::config_err(format!(
            "scene.count = {}: must be at most {}",
            s.count,
            super::MAX_BODIES
        ));
    }
    let layers = s.count.div_ceil(layer);
    let bottom = lz - 0.6 * d - layers.saturating_sub(1) as f64 * spacing;
    if bottom < hf + d {
        return crate::error::config_err(format!(
            "scene.count = {}: {layers} layers of {layer} spheres reach below the funnel top; lower the count or \
             enlarge the domain",
            s.count
        ));
    }
    let x0 = (lx - (nx - 1) as f64 * spacing) / 2.0;
    let y0 = (ly - (ny - 1) as f64 * spacing) / 2.0;
    let bodies: Vec<Body> = (0..s.count)
        .map(|i| {
            let (l, k) = (i / layer, i % layer);
            let u = |c: u64| super::seeded_unit(s.seed, 8 * i as u64 + c) * 2.0 - 1.0;
            let jit = 0.04 * d;
            Body::sphere(
                i as u64,
                DVec3::new(
                    x0 + (k % nx) as f64 * spacing + jit * u(0),
                    y0 + (k / nx) as f64 * spacing + jit * u(1),
                    lz - 0.6 * d - l as f64 * spacing,
                ),
                d / 2.0,
                s.density_ratio,
            )
        })
        .collect();
    let observe = Box::new(move |v: &dyn super::FluidView| {
        let b = v.bodies();
        let n = b.len().max(1) as f64;
        let h = b.iter().map(|x| x.position.z).sum::<f64>() / n;
        let vmax = b.iter().map(|x| x.velocity.length()).fold(0.0, f64::max);
        BTreeMap::from([
            ("mean_height".to_string(), h / lz),
            ("max_speed".to_string(), vmax),
            ("bodies".to_string(), b.len() as f64),
        ])
    });
    Ok(Scene {
        name: "hopper",
        cells: Some(cells),
        periodic: [false; 3],
        default_blocks: blocks,
        geometry,
        params: TrtParams {
            tau,
            magic: cfg.fluid.magic,
            force: [0.0; 3],
        },
        steps: s.steps,
        init: Box::new(|_| (0.0, [0.0; 3])),
        observe,
        particles: Some(ParticleScene {
            bodies,
            planes,
            gravity: [0.0, 0.0, -g],
            restitution_threshold: 1e-3,
            dt: 1.0,
        }),
        units: None,
        description: format!(
            "hopper: {} spheres of D = {d}, Ga = {}, rho_p/rho_f = {}, {:?} cells, cross-section narrowed by {}",
            s.count, s.galileo, s.density_ratio, cells, s.narrowing
        ),
    })
}

/// `[scene]` keys of `kind = "calibration"` (section 3.3, Figure 5): spheres at random positions in a
/// horizontally periodic box of 4 × 4 × 5 blocks whose top wall sits `top_offset` block sizes below the
/// top of the block grid, settling onto the bottom for 2.5 T with T = L_z / u_s.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationConfig {
    /// Sphere diameter D in cells.
    #[serde(default = "d_cal_d")]
    pub diameter: f64,
    /// Global solid volume fraction.
    #[serde(default = "d_cal_phi")]
    pub solid_fraction: f64,
    /// Galileo number Ga = u_s D / ν with u_s = sqrt((ρp/ρf − 1) g D).
    #[serde(default = "d_galileo")]
    pub galileo: f64,
    /// Density ratio ρp / ρf.
    #[serde(default = "d_cal_ratio")]
    pub density_ratio: f64,
    /// Offset of the top wall below the block grid, in block sizes.
    #[serde(default = "d_cal_offset")]
    pub top_offset: f64,
    /// Characteristic speed u_s in lattice units (sets ν = u_s D / Ga unless `fluid.tau` is given).
    #[serde(default = "d_cal_us")]
    pub settling_speed: f64,
    /// Duration in units of T = L_z / u_s.
    #[serde(default = "d_cal_duration")]
    pub duration: f64,
    /// Seed of the random positions.
    #[serde(default = "d_seed")]
    pub seed: u64,
}

fn d_cal_d() -> f64 {
    5.0
}
fn d_cal_phi() -> f64 {
    0.2
}
fn d_cal_ratio() -> f64 {
    2.5
}
fn d_cal_offset() -> f64 {
    1.05
}
fn d_cal_us() -> f64 {
    0.05
}
fn d_cal_duration() -> f64 {
    2.5
}

pub(super) fn build_calibration(s: &CalibrationConfig, cfg: &Config) -> Result<Scene> {
    check("diameter", s.diameter, s.diameter >= 3.0, "must be at least 3 cells")?;
    check(
        "solid_fraction",
        s.solid_fraction,
        s.solid_fraction > 0.0 && s.solid_fraction <= 0.3,
        "must be in (0, 0.3] (random placement jams above)",
    )?;
    check(
        "galileo",
        s.galileo,
        s.galileo > 0.0 && s.galileo <= 500.0,
        "must be in (0, 500]",
    )?;
    check("density_ratio", s.density_ratio, s.density_ratio > 1.0, "must be > 1")?;
    check(
        "top_offset",
        s.top_offset,
        (0.0..2.0).contains(&s.top_offset),
        "must be in [0, 2) block sizes",
    )?;
    check(
        "settling_speed",
        s.settling_speed,
        s.settling_speed > 0.0 && s.settling_speed <= 0.1,
        "must be in (0, 0.1] (Mach number)",
    )?;
    check("duration", s.duration, s.duration > 0.0, "must be positive")?;
    let blocks = cfg.domain.blocks.unwrap_or([4, 4, 5]);
    let bs = cfg.domain.block_size.unwrap_or([16, 16, 16]);
    let cells = super::extent_of(blocks, bs)?;
    let (lx, ly) = (cells[0] as f64, cells[1] as f64);
    let lz = cells[2] as f64 - s.top_offset * bs[2] as f64;
    let d = s.diameter;
    let nu = cfg
        .fluid
        .tau
        .map_or(s.settling_speed * d / s.galileo, |t| (t - 0.5) / 3.0);
    let tau = 0.5 + 3.0 * nu;
    let u_s = s.galileo * nu / d;
    let g = u_s * u_s / ((s.density_ratio - 1.0) * d);
    let vol = std::f64::consts::PI / 6.0 * d.powi(3);
    let wanted = (s.solid_fraction * lx * ly * lz / vol).round().max(0.0);
    if wanted > super::MAX_BODIES as f64 {
        return crate::error::config_err(format!(
            "scene.solid_fraction = {}: {wanted} spheres of D = {d} in {cells:?} cells, more than {}; lower it, \
             raise scene.diameter or use fewer blocks",
            s.solid_fraction,
            super::MAX_BODIES
        ));
    }
    let count = wanted as usize;
    // Random sequential addition: uniform candidates, rejected when they overlap a placed sphere or a wall.
    // Placed spheres are binned in a grid of cells at least the clearance wide (periodic in x and y), so a
    // candidate is checked against the spheres of the 27 cells around it only.
    let r = d / 2.0;
    let clearance = d + 0.05;
    let gx = ((lx / clearance).floor() as i64).max(1);
    let gy = ((ly / clearance).floor() as i64).max(1);
    let cell_of = |p: DVec3| -> (i64, i64, i64) {
        (
            ((p.x / lx * gx as f64).floor() as i64).rem_euclid(gx),
            ((p.y / ly * gy as f64).floor() as i64).rem_euclid(gy),
            (p.z / clearance).floor() as i64,
        )
    };
    let mut grid: std::collections::HashMap<(i64, i64, i64), Vec<usize>> = std::collections::HashMap::new();
    let mut bodies: Vec<Body> = Vec::with_capacity(count);
    let mut k = 0u64;
    // Candidates rejected in a row: past 100 000 the box is jammed (thin slab, high fraction); stop early.
    let mut misses = 0u64;
    while bodies.len() < count {
        if k > 2000 * count as u64 + 10_000 || misses > 100_000 {
            return crate::error::config_err(format!(
                "scene.solid_fraction = {}: could not place {count} spheres at random; lower it",
                s.solid_fraction
            ));
        }
        let u = |c: u64| super::seeded_unit(s.seed, 4 * k + c);
        let p = DVec3::new(u(0) * lx, u(1) * ly, r + 0.05 + u(2) * (lz - d - 0.1));
        k += 1;
        let (cx, cy, cz) = cell_of(p);
        let mut near: Vec<(i64, i64, i64)> = Vec::with_capacity(27);
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let c = ((cx + dx).rem_euclid(gx), (cy + dy).rem_euclid(gy), cz + dz);
                    if !near.contains(&c) {
                        near.push(c);
                    }
                }
            }
        }
        let clear = near.iter().filter_map(|c| grid.get(c)).flatten().all(|&i| {
            let mut dv = bodies[i].position - p;
            dv.x -= lx * (dv.x / lx).round();
            dv.y -= ly * (dv.y / ly).round();
            dv.length() > clearance
        });
        misses += 1;
        if clear {
            misses = 0;
            grid.entry((cx, cy, cz)).or_default().push(bodies.len());
            bodies.push(Body::sphere(bodies.len() as u64, p, r, s.density_ratio));
        }
    }
    let mut geometry = Geometry::default();
    geometry.planes.push(crate::geometry::Plane::axis_wall(2, lz, false));
    let mut planes = super::wall_planes(cells, [true, true, false]);
    planes.retain(|p| p.normal.z > 0.0);
    planes.push(blockflow_kernels::rigid::Plane::through(
        1,
        DVec3::new(0.0, 0.0, lz),
        DVec3::new(0.0, 0.0, -1.0),
    ));
    let steps = (s.duration * lz / u_s).ceil() as u64;
    let observe = Box::new(move |v: &dyn super::FluidView| {
        let b = v.bodies();
        let n = b.len().max(1) as f64;
        BTreeMap::from([
            (
                "mean_height".to_string(),
                b.iter().map(|x| x.position.z).sum::<f64>() / n / lz,
            ),
            (
                "max_speed".to_string(),
                b.iter().map(|x| x.velocity.length()).fold(0.0, f64::max),
            ),
            ("bodies".to_string(), b.len() as f64),
        ])
    });
    Ok(Scene {
        name: "calibration",
        cells: Some(cells),
        periodic: [true, true, false],
        default_blocks: blocks,
        geometry,
        params: TrtParams {
            tau,
            magic: cfg.fluid.magic,
            force: [0.0; 3],
        },
        steps,
        init: Box::new(|_| (0.0, [0.0; 3])),
        observe,
        particles: Some(ParticleScene {
            bodies,
            planes,
            gravity: [0.0, 0.0, -g],
            restitution_threshold: 1e-3,
            dt: 1.0,
        }),
        units: None,
        description: format!(
            "calibration (section 3.3): {count} spheres of D = {d}, solid fraction {}, Ga = {}, rho_p/rho_f = {}, \
             {cells:?} cells with the top wall at z = {lz:.1}, tau = {tau:.4}",
            s.solid_fraction, s.galileo, s.density_ratio
        ),
    })
}
