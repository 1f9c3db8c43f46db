//! `hopper` (section 4.3 of the paper, scaled to a small node): spheres densely packed under the lid
//! settle through four inclined planes that narrow the horizontal cross-section toward the bottom.
//! Observables `mean_height` (of the sphere centres, over the box height), `max_speed`, `bodies`.

use super::{check, ParticleScene, Scene};
use crate::config::scene::HopperConfig;
use crate::config::Config;
use crate::error::Result;
use crate::physics::geometry::Geometry;
use blockflow_kernels::rigid::Body;
use glam::DVec3;
use std::collections::BTreeMap;

/// Gravity magnitude from the Galileo number: g = Ga² ν² / ((ρr − 1) D³).
fn gravity_from_galileo(ga: f64, nu: f64, ratio: f64, d: f64) -> f64 {
    ga * ga * nu * nu / ((ratio - 1.0) * d.powi(3))
}

pub(super) fn build(s: &HopperConfig, cfg: &Config) -> Result<Scene> {
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
        let fp = crate::physics::geometry::WallPlane::through(point, normal, [0.0; 3]).expect("non-zero normal");
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
            let u = |c: u64| crate::util::hash::seeded_unit(s.seed, 8 * i as u64 + c) * 2.0 - 1.0;
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
        params: super::unforced(tau, cfg),
        steps: s.steps,
        init: super::at_rest(),
        observe,
        particles: Some(ParticleScene::coupled(bodies, planes, g)),
        units: None,
        description: format!(
            "hopper: {} spheres of D = {d}, Ga = {}, rho_p/rho_f = {}, {:?} cells, cross-section narrowed by {}",
            s.count, s.galileo, s.density_ratio, cells, s.narrowing
        ),
    })
}
