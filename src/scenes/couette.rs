//! `couette`: shear flow between a resting wall (y = 0) and a wall moving along x (y = H), periodic in x
//! and z. Observable `l2_error` against the linear profile u = U y / H (exact with bounce-back).

use super::{check, relative_l2, steady_steps, tau_or, Scene};
use crate::config::scene::CouetteConfig;
use crate::config::Config;
use crate::error::Result;
use crate::physics::geometry::{FaceWall, Geometry};
use std::collections::BTreeMap;

pub(super) fn build(s: &CouetteConfig, cfg: &Config) -> Result<Scene> {
    check(
        "resolution",
        s.resolution as f64,
        s.resolution >= 2,
        "must be at least 2 cells",
    )?;
    check("reynolds", s.reynolds, s.reynolds > 0.0, "must be positive")?;
    check("length", s.length as f64, s.length >= 1, "must be at least 1 cell")?;
    check("width", s.width as f64, s.width >= 1, "must be at least 1 cell")?;
    let h = s.resolution as f64;
    let tau = tau_or(cfg, 0.8);
    let nu = (tau - 0.5) / 3.0;
    let u_wall = s.reynolds * nu / h;
    let mut geometry = Geometry::default();
    geometry.faces[1][1] = Some(FaceWall {
        velocity: [u_wall, 0.0, 0.0],
    });
    let exact = move |g: [usize; 3]| [u_wall * (g[1] as f64 + 0.5) / h, 0.0, 0.0];
    Ok(Scene {
        name: "couette",
        cells: Some([s.length, s.resolution, s.width]),
        periodic: [true, false, true],
        default_blocks: [1, 1, 1],
        geometry,
        params: super::unforced(tau, cfg),
        steps: steady_steps(s.resolution, nu),
        init: super::at_rest(),
        observe: Box::new(move |v| BTreeMap::from([("l2_error".to_string(), relative_l2(v, exact))])),
        particles: None,
        units: None,
        description: format!("Couette gap H = {h}, Re = {}, U = {u_wall:.4}, tau = {tau}", s.reynolds),
    })
}
