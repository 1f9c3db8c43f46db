//! `channel`: force-driven Poiseuille flow between two resting walls (y), periodic in x and z.
//! Observable `l2_error`: relative L2 error of the velocity against u(y) = F/(2ν) y (H - y), walls half-way
//! between the last fluid cell and the first wall cell. With Λ = 3/16 the TRT solution is exact to rounding.

use super::{check, relative_l2, steady_steps, tau_or, Scene};
use crate::config::scene::ChannelConfig;
use crate::config::Config;
use crate::error::Result;
use crate::physics::geometry::Geometry;
use blockflow_kernels::TrtParams;
use std::collections::BTreeMap;

pub(super) fn build(s: &ChannelConfig, cfg: &Config) -> Result<Scene> {
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
    let u_max = s.reynolds * nu / h;
    let force = 8.0 * nu * u_max / (h * h);
    let params = TrtParams {
        tau,
        magic: cfg.fluid.magic,
        force: [force, 0.0, 0.0],
    };
    let exact = move |g: [usize; 3]| {
        let y = g[1] as f64 + 0.5;
        [force / (2.0 * nu) * y * (h - y), 0.0, 0.0]
    };
    Ok(Scene {
        name: "channel",
        cells: Some([s.length, s.resolution, s.width]),
        periodic: [true, false, true],
        default_blocks: [1, 1, 1],
        geometry: Geometry::default(),
        params,
        steps: steady_steps(s.resolution, nu),
        init: super::at_rest(),
        observe: Box::new(move |v| BTreeMap::from([("l2_error".to_string(), relative_l2(v, exact))])),
        particles: None,
        units: None,
        description: format!(
            "Poiseuille channel H = {h}, Re = {}, u_max = {u_max:.4}, tau = {tau}",
            s.reynolds
        ),
    })
}
