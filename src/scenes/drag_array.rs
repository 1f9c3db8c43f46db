//! `drag_array`: one fixed sphere in a periodic cube, i.e. a simple cubic array of spheres, driven by
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
use crate::config::scene::DragArrayConfig;
use crate::config::Config;
use crate::error::Result;
use crate::physics::geometry::Geometry;
use blockflow_kernels::rigid::Body;
use blockflow_kernels::TrtParams;
use glam::DVec3;
use std::collections::BTreeMap;

/// Zick & Homsy (1982), simple cubic arrays: (φ, K = F / 6πμaU).
pub const ZICK_HOMSY: [(f64, f64); 3] = [(0.064, 2.81), (0.125, 4.29), (0.216, 7.44)];

pub(super) fn build(s: &DragArrayConfig, cfg: &Config) -> Result<Scene> {
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
        init: super::at_rest(),
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
