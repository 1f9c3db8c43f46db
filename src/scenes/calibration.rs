//! `calibration` (section 3.3, Figure 5 of the paper): spheres at random positions in a horizontally
//! periodic box whose top wall sits below the block grid, settling onto the bottom; the scene the workload
//! estimator is calibrated on. Observables `mean_height`, `max_speed`, `bodies`.

use super::{check, ParticleScene, Scene};
use crate::config::scene::CalibrationConfig;
use crate::config::Config;
use crate::error::Result;
use crate::physics::geometry::Geometry;
use blockflow_kernels::rigid::Body;
use glam::DVec3;
use std::collections::BTreeMap;

/// The scene: the box, the top wall, the spheres, the viscosity from `scene.galileo` and the settling
/// speed, and the run length of `scene.duration` settling times.
pub(super) fn build(s: &CalibrationConfig, cfg: &Config) -> Result<Scene> {
    check_keys(s)?;
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
    let bodies = place_spheres(s, count, [lx, ly, lz])?;
    let mut geometry = Geometry::default();
    geometry
        .planes
        .push(crate::physics::geometry::WallPlane::axis_wall(2, lz, false));
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
        params: super::unforced(tau, cfg),
        steps,
        init: super::at_rest(),
        observe,
        particles: Some(ParticleScene::coupled(bodies, planes, g)),
        units: None,
        description: format!(
            "calibration (section 3.3): {count} spheres of D = {d}, solid fraction {}, Ga = {}, rho_p/rho_f = {}, \
             {cells:?} cells with the top wall at z = {lz:.1}, tau = {tau:.4}",
            s.solid_fraction, s.galileo, s.density_ratio
        ),
    })
}

/// Checks the scene keys' ranges (one line naming the key on failure).
fn check_keys(s: &CalibrationConfig) -> Result<()> {
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
    Ok(())
}

/// Places `count` spheres of `scene.diameter` D at random in the box `[lx, ly, lz]` (periodic in x and y)
/// by random sequential addition from `scene.seed`: uniform candidates with their surface at least 0.05
/// cells from the floor and the top wall, rejected when their centre lies within D + 0.05 cells of a
/// placed sphere's. Spheres get ids 0, 1, … in the order placed; a box too full to take them all is a
/// configuration error.
fn place_spheres(s: &CalibrationConfig, count: usize, [lx, ly, lz]: [f64; 3]) -> Result<Vec<Body>> {
    // Random sequential addition: uniform candidates, rejected when they overlap a placed sphere or a wall.
    // Placed spheres are binned in a grid of cells at least the clearance wide (periodic in x and y), so a
    // candidate is checked against the spheres of the 27 cells around it only.
    let d = s.diameter;
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
        let u = |c: u64| crate::util::hash::seeded_unit(s.seed, 4 * k + c);
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
    Ok(bodies)
}
