//! `granular_box`: spheres on a jittered lattice poured into a closed box settle into a pile (a dry
//! scene, fluid off); observables `max_overlap` (largest penetration / D in the final state),
//! `kinetic_energy`, `max_speed`, `mean_height`.

use super::dry::{dry_scene, require_dry};
use super::dry::{max_penetration, uniform};
use super::{check, ParticleScene, Scene};
use crate::config::scene::GranularBoxConfig;
use crate::config::Config;
use crate::error::{config_err, Result};
use blockflow_kernels::rigid::Body;
use glam::DVec3;
use std::collections::BTreeMap;

pub(super) fn build(s: &GranularBoxConfig, cfg: &Config) -> Result<Scene> {
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
