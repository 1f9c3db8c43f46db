//! `cavity`: the lid-driven cubic cavity. Five resting walls and a lid (the y = N face) moving along x at
//! U; Re = U N / ν with U fixed (acoustic scaling: ν follows from Re). Observables: the extreme centre-line
//! velocities normalised by U (`u_min_vertical` along the vertical centre line, `v_max_horizontal` and
//! `v_min_horizontal` along the horizontal one, both in the mid-plane z = N/2; compare with published 3D
//! cavity data such as Albensoeder & Kuhlmann 2005) and the kinetic energy.

use super::{check, kinetic_energy, Scene};
use crate::config::scene::CavityConfig;
use crate::config::Config;
use crate::error::{config_err, Result};
use crate::physics::geometry::{FaceWall, Geometry};
use blockflow_kernels::TrtParams;
use std::collections::BTreeMap;

pub(super) fn build(s: &CavityConfig, cfg: &Config) -> Result<Scene> {
    check(
        "resolution",
        s.resolution as f64,
        s.resolution >= 4,
        "must be at least 4 cells",
    )?;
    check("reynolds", s.reynolds, s.reynolds > 0.0, "must be positive")?;
    check(
        "lid_velocity",
        s.lid_velocity,
        s.lid_velocity > 0.0 && s.lid_velocity < 0.4,
        "must lie in (0, 0.4)",
    )?;
    check("turnovers", s.turnovers, s.turnovers > 0.0, "must be positive")?;
    if cfg.fluid.tau.is_some() {
        return config_err(
            "fluid.tau: the cavity derives τ from scene.reynolds and scene.lid_velocity; remove fluid.tau",
        );
    }
    let n = s.resolution;
    let u = s.lid_velocity;
    let nu = u * n as f64 / s.reynolds;
    let tau = TrtParams::tau_for_viscosity(nu);
    if tau <= 0.5 + 1e-6 {
        return config_err(format!(
            "scene.reynolds = {}: τ = {tau} is too close to 1/2 at this resolution",
            s.reynolds
        ));
    }
    let mut geometry = Geometry::default();
    geometry.faces[1][1] = Some(FaceWall {
        velocity: [u, 0.0, 0.0],
    });
    let steps = (s.turnovers * n as f64 / u).ceil() as u64;
    let mid = n / 2;
    let odd = n % 2 == 1;
    Ok(Scene {
        name: "cavity",
        cells: Some([n, n, n]),
        periodic: [false, false, false],
        default_blocks: [1, 1, 1],
        geometry,
        params: super::unforced(tau, cfg),
        steps,
        init: super::at_rest(),
        observe: Box::new(move |v| {
            // Centre lines: average over the cells adjacent to the centre (one cell when N is odd).
            let near = |c: usize| c == mid || (!odd && c + 1 == mid);
            let w = if odd { 1.0 } else { 0.25 };
            let mut vert = vec![0.0; n];
            let mut horiz = vec![0.0; n];
            v.visit(&mut |g, _, vel| {
                if near(g[0]) && near(g[2]) {
                    vert[g[1]] += w * vel[0] / u;
                }
                if near(g[1]) && near(g[2]) {
                    horiz[g[0]] += w * vel[1] / u;
                }
            });
            BTreeMap::from([
                (
                    "u_min_vertical".to_string(),
                    vert.iter().cloned().fold(f64::MAX, f64::min),
                ),
                (
                    "v_max_horizontal".to_string(),
                    horiz.iter().cloned().fold(f64::MIN, f64::max),
                ),
                (
                    "v_min_horizontal".to_string(),
                    horiz.iter().cloned().fold(f64::MAX, f64::min),
                ),
                ("kinetic_energy".to_string(), kinetic_energy(v)),
            ])
        }),
        particles: None,
        units: None,
        description: format!(
            "lid-driven cavity N = {n}, Re = {}, U = {u}, tau = {tau:.5}",
            s.reynolds
        ),
    })
}
