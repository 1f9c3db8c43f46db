//! `taylor_green`: the decaying Taylor–Green vortex in a periodic box,
//! u = U0 e^{-2νk²t} (-cos kx sin ky, sin kx cos ky, 0), p = -U0²/4 e^{-4νk²t} (cos 2kx + cos 2ky), k = 2π/N.
//! This z-invariant vortex is an exact solution of the incompressible Navier–Stokes equations (the fully
//! three-dimensional Taylor–Green flow has no closed form), run on a genuinely 3D periodic D3Q19 box of
//! N × N × depth cells. The scene keeps Re = U0 N / ν and the final time in viscous units fixed when N
//! changes (diffusive scaling: τ fixed, U0 ∝ 1/N, steps ∝ N²), so the error falls as N⁻².
//! Observable `l2_error`: relative L2 error of the velocity at the final step against the analytic field.

use super::{check, kinetic_energy, relative_l2, tau_or, Scene};
use crate::config::scene::TaylorGreenConfig;
use crate::config::Config;
use crate::error::Result;
use crate::physics::geometry::Geometry;
use std::collections::BTreeMap;
use std::f64::consts::PI;

pub(super) fn build(s: &TaylorGreenConfig, cfg: &Config) -> Result<Scene> {
    check(
        "resolution",
        s.resolution as f64,
        s.resolution >= 4,
        "must be at least 4 cells",
    )?;
    check("reynolds", s.reynolds, s.reynolds > 0.0, "must be positive")?;
    check("time", s.time, s.time > 0.0, "must be positive")?;
    let depth = s.depth.unwrap_or(s.resolution);
    check("depth", depth as f64, depth >= 1, "must be at least 1 cell")?;
    let n = s.resolution as f64;
    let tau = tau_or(cfg, 0.8);
    let nu = (tau - 0.5) / 3.0;
    let k = 2.0 * PI / n;
    let u0 = s.reynolds * nu / n;
    let steps = (s.time / (2.0 * nu * k * k)).round().max(1.0) as u64;
    let field = move |g: [usize; 3], t: f64| {
        let (x, y) = (k * (g[0] as f64 + 0.5), k * (g[1] as f64 + 0.5));
        let a = u0 * (-2.0 * nu * k * k * t).exp();
        let u = [-a * x.cos() * y.sin(), a * x.sin() * y.cos(), 0.0];
        let p = -0.25 * a * a * ((2.0 * x).cos() + (2.0 * y).cos());
        (3.0 * p, u) // δρ = p / c_s²
    };
    Ok(Scene {
        name: "taylor_green",
        cells: Some([s.resolution, s.resolution, depth]),
        periodic: [true, true, true],
        default_blocks: [1, 1, 1],
        geometry: Geometry::default(),
        params: super::unforced(tau, cfg),
        steps,
        init: Box::new(move |g| field(g, 0.0)),
        observe: Box::new(move |v| {
            let t = v.steps_taken() as f64;
            BTreeMap::from([
                ("l2_error".to_string(), relative_l2(v, |g| field(g, t).1)),
                ("kinetic_energy".to_string(), kinetic_energy(v)),
            ])
        }),
        particles: None,
        units: None,
        description: format!(
            "Taylor-Green N = {n}, Re = {}, U0 = {u0:.4}, tau = {tau}, {steps} steps",
            s.reynolds
        ),
    })
}
