//! One sphere settling from rest in a closed box of viscous fluid, given in physical (SI) units: the
//! experiment of ten Cate, Nieuwstad, Derksen and Van den Akker, "Particle imaging velocimetry experiments
//! and lattice-Boltzmann simulations on a single sphere settling under gravity", Phys. Fluids 14, 4012
//! (2002), doi:10.1063/1.1512918.
//!
//! Units. `scene.resolution` cells per diameter fix the lattice spacing dx = D / resolution. The lattice
//! time step dt comes from one of two rules:
//! - `fluid.tau` given: **τ wins**, dt = (τ − ½)/3 · dx² / ν (diffusive scaling; the Mach number then
//!   follows and is checked against [`MAX_MACH`]);
//! - `fluid.tau` absent: the **Mach limit**, dt = Ma · c_s · dx / u_est with Ma = `scene.mach` (default
//!   0.1), c_s = 1/√3 and u_est the terminal speed in an unbounded fluid from the Schiller–Naumann drag
//!   law (an a-priori estimate; the box walls make the real speed a few per cent lower). τ then follows as
//!   ½ + 3 ν dt / dx² (acoustic scaling: τ grows with the resolution at a fixed Mach number).
//!
//! In lattice units ρ_f = 1, the sphere has ρ_p / ρ_f, gravity g dt² / dx, viscosity ν dt / dx². Forces
//! convert back with ρ_f dx⁴ / dt², velocities with dx / dt.

use super::{check, check_extent, wall_planes, ParticleScene, Scene, Units};
use crate::config::scene::{SettlingSphereConfig, TEN_CATE_BOX, TEN_CATE_DIAMETER};
use crate::config::Config;
use crate::error::{config_err, Result};
use crate::physics::geometry::Geometry;
use blockflow_kernels::rigid::Body;
use glam::DVec3;
use std::collections::BTreeMap;

/// One case of ten Cate et al. (2002): the silicone oil and the measured peak settling speed.
#[derive(Clone, Copy, Debug)]
pub struct TenCateCase {
    /// Case name, `E1` … `E4`.
    pub name: &'static str,
    /// Fluid density ρ_f, kg/m³ (their Table 1).
    pub fluid_density: f64,
    /// Dynamic viscosity μ_f, Pa s (their Table 1).
    pub fluid_viscosity: f64,
    /// Terminal speed in an unbounded fluid u_∞, m/s (their Table 1).
    pub u_infinity: f64,
    /// Measured peak settling speed in the box over u_∞ (their Table 2).
    pub peak_over_infinity: f64,
    /// Reynolds number ρ_f u_∞ D / μ_f (their Table 1).
    pub reynolds: f64,
}

impl TenCateCase {
    /// The measured peak settling speed in the box, m/s (Table 2 ratio × Table 1 u_∞).
    pub fn peak_speed(&self) -> f64 {
        self.peak_over_infinity * self.u_infinity
    }
}

/// The four cases of ten Cate et al. (2002): a nylon sphere (D = 15 mm, ρ_p = 1120 kg/m³) in four silicone
/// oils, container 100 × 100 × 160 mm.
pub const TEN_CATE: [TenCateCase; 4] = [
    TenCateCase {
        name: "E1",
        fluid_density: 970.0,
        fluid_viscosity: 0.373,
        u_infinity: 0.038,
        peak_over_infinity: 0.947,
        reynolds: 1.5,
    },
    TenCateCase {
        name: "E2",
        fluid_density: 965.0,
        fluid_viscosity: 0.212,
        u_infinity: 0.060,
        peak_over_infinity: 0.953,
        reynolds: 4.1,
    },
    TenCateCase {
        name: "E3",
        fluid_density: 962.0,
        fluid_viscosity: 0.113,
        u_infinity: 0.091,
        peak_over_infinity: 0.959,
        reynolds: 11.6,
    },
    TenCateCase {
        name: "E4",
        fluid_density: 960.0,
        fluid_viscosity: 0.058,
        u_infinity: 0.128,
        peak_over_infinity: 0.955,
        reynolds: 31.9,
    },
];

/// The experiment's sphere density, kg/m³.
pub const TEN_CATE_PARTICLE_DENSITY: f64 = 1120.0;

/// Largest Mach number (estimated terminal speed over c_s) a set-up may reach.
pub const MAX_MACH: f64 = 0.5;

/// Reynolds number of the terminal speed in an unbounded fluid from the Galileo number, by the
/// Schiller–Naumann drag law C_d = 24/Re (1 + 0.15 Re^0.687): Re (1 + 0.15 Re^0.687) = Ga² / 18.
pub fn schiller_naumann_reynolds(galileo: f64) -> f64 {
    let rhs = galileo * galileo / 18.0;
    // f(Re) is increasing; bisection on [0, rhs] is robust for every Ga.
    let (mut lo, mut hi) = (0.0, rhs.max(1e-300));
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if mid * (1.0 + 0.15 * mid.powf(0.687)) < rhs {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// The physical set-up after the defaults and the case are applied.
#[derive(Clone, Copy, Debug)]
struct Physical {
    rho_f: f64,
    mu: f64,
    rho_p: f64,
    d: f64,
    g: f64,
}

fn physical(s: &SettlingSphereConfig) -> Result<(Physical, Option<TenCateCase>)> {
    let case = match &s.case {
        None => None,
        Some(name) => match TEN_CATE.iter().find(|c| c.name.eq_ignore_ascii_case(name)) {
            Some(c) => Some(*c),
            None => return config_err(format!("scene.case = {name:?}: unknown case; one of E1, E2, E3, E4")),
        },
    };
    let rho_f = match (s.fluid_density, case) {
        (Some(v), _) => v,
        (None, Some(c)) => c.fluid_density,
        (None, None) => {
            return config_err("scene.fluid_density: missing; give it (kg/m³) or scene.case = \"E1\" … \"E4\"")
        }
    };
    let mu = match (s.fluid_viscosity, case) {
        (Some(v), _) => v,
        (None, Some(c)) => c.fluid_viscosity,
        (None, None) => {
            return config_err(
                "scene.fluid_viscosity: missing; give it (dynamic, Pa s) or scene.case = \"E1\" … \"E4\"",
            )
        }
    };
    check(
        "fluid_density",
        rho_f,
        rho_f > 0.0 && rho_f <= 1e5,
        "must be a density in (0, 1e5] kg/m³",
    )?;
    check(
        "fluid_viscosity",
        mu,
        mu > 0.0 && mu <= 1e6,
        "must be a dynamic viscosity in (0, 1e6] Pa s",
    )?;
    let rho_p = match (s.particle_density, s.density_ratio) {
        (Some(_), Some(_)) => {
            return config_err("scene.particle_density and scene.density_ratio are both given; keep one of them")
        }
        (Some(v), None) => {
            check(
                "particle_density",
                v,
                v > 0.0 && v <= 1e6,
                "must be a density in (0, 1e6] kg/m³",
            )?;
            v
        }
        (None, Some(r)) => {
            check("density_ratio", r, r > 0.0 && r <= 1e3, "must be in (0, 1000]")?;
            r * rho_f
        }
        (None, None) => TEN_CATE_PARTICLE_DENSITY,
    };
    if rho_p <= rho_f {
        return config_err(format!(
            "scene.particle_density = {rho_p} kg/m³ is not above scene.fluid_density = {rho_f} kg/m³ (density ratio \
             {:.6}): the sphere would not sink; give a denser sphere or a ratio above 1",
            rho_p / rho_f
        ));
    }
    let d = s.diameter;
    check("diameter", d, d > 0.0 && d <= 1e3, "must be a diameter in (0, 1000] m")?;
    let nu = mu / rho_f;
    let g = match (s.gravity, s.galileo) {
        (Some(_), Some(_)) => return config_err("scene.gravity and scene.galileo are both given; keep one of them"),
        (Some(g), None) => {
            check("gravity", g, g > 0.0 && g <= 1e4, "must be in (0, 1e4] m/s²")?;
            g
        }
        (None, Some(ga)) => {
            check("galileo", ga, ga > 0.0 && ga <= 1000.0, "must be in (0, 1000]")?;
            ga * ga * nu * nu / ((rho_p / rho_f - 1.0) * d.powi(3))
        }
        (None, None) => 9.81,
    };
    let p = Physical { rho_f, mu, rho_p, d, g };
    // The measured peak speed applies only to the experiment's own set-up.
    let same = |a: f64, b: f64| (a - b).abs() <= 1e-9 * b.abs();
    let reference = case.filter(|c| {
        same(rho_f, c.fluid_density)
            && same(mu, c.fluid_viscosity)
            && same(rho_p, TEN_CATE_PARTICLE_DENSITY)
            && same(d, TEN_CATE_DIAMETER)
            && same(g, 9.81)
            && (0..3).all(|a| same(s.r#box[a], TEN_CATE_BOX[a]))
    });
    Ok((p, reference))
}

/// The noise of the raw settling speed, relative to its peak: the RMS of the raw fall speed minus its running
/// mean over the steps the sphere takes to fall one cell at the peak speed, over the middle half of the
/// fall up to the peak (what the one-cell average of [`peak_settling_speed`] removes). 0 for a trace too
/// short to tell.
pub fn velocity_noise(traj: &[(f64, Body)]) -> f64 {
    let v: Vec<f64> = traj.iter().map(|(_, b)| -b.velocity.z).collect();
    let Some((ip, &peak)) = v.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1)) else {
        return 0.0;
    };
    if peak <= 0.0 || ip < 8 {
        return 0.0;
    }
    // Samples per step (the trajectory has one per step) and steps per cell at the peak.
    // An odd window, centred: the mean of a linear trend over it is its value at the centre.
    let w = ((1.0 / peak).round() as usize).clamp(1, ip / 4) | 1;
    let (lo, hi) = ((ip / 4).max(w), (3 * ip / 4).min(v.len().saturating_sub(w)));
    let mut sum2 = 0.0;
    let mut n = 0usize;
    for i in lo..hi {
        let start = i - w / 2;
        let mean = v[start..start + w].iter().sum::<f64>() / w as f64;
        sum2 += (v[i] - mean).powi(2);
        n += 1;
    }
    if n == 0 {
        0.0
    } else {
        (sum2 / n as f64).sqrt() / peak
    }
}

/// The peak settling speed (lattice units) and its time from body-0 samples (time, body): the largest fall
/// speed averaged over the time the sphere takes to fall one lattice cell, Δz / Δt over the shortest window
/// ending at a sample with Δz ≥ 1. The raw velocity carries a few per cent of noise at coarse resolutions
/// as the sphere crosses cells (cells covered and uncovered); the one-cell average removes that noise
/// without smoothing the physical curve, which changes over many cells.
pub fn peak_settling_speed(traj: &[(f64, Body)]) -> (f64, f64) {
    let (mut peak, mut t_peak) = (0.0, 0.0);
    let mut j = 0;
    for i in 0..traj.len() {
        let (ti, zi) = (traj[i].0, traj[i].1.position.z);
        // Advance j to the latest sample at least one cell above sample i.
        while j + 1 < i && traj[j + 1].1.position.z - zi >= 1.0 {
            j += 1;
        }
        let (tj, zj) = (traj[j].0, traj[j].1.position.z);
        if j < i && zj - zi >= 1.0 && ti > tj {
            let u = (zj - zi) / (ti - tj);
            if u > peak {
                peak = u;
                t_peak = 0.5 * (ti + tj);
            }
        }
    }
    (peak, t_peak)
}

/// Blocks along an axis of `n` cells: the divisor of `n` whose block edge (at least 8 cells) is closest to
/// `target` cells, fewer blocks on a tie.
fn blocks_along(n: usize, target: i64) -> usize {
    (1..=n)
        .filter(|k| n.is_multiple_of(*k) && (n / k >= 8 || *k == 1))
        .min_by_key(|k| ((n / k) as i64 - target).abs())
        .unwrap_or(1)
}

/// The default block grid (`domain.blocks` or `domain.block_size` override it): x, the kernel's inner
/// loop, is never split (long rows run fastest: at D = 12 on 2 cores, 80 × 80 × 16 blocks give 34.6
/// MLUPS, 20 × 20 × 32 blocks 19.2); z is cut into slabs of about 16 cells, and y into blocks of about 24
/// only when z gives fewer than 4 slabs.
fn default_blocks(cells: [usize; 3]) -> [usize; 3] {
    let bz = blocks_along(cells[2], 16);
    let by = if bz < 4 { blocks_along(cells[1], 24) } else { 1 };
    [1, by, bz]
}

/// The time step and τ: from `fluid.tau` where given (dt = (τ − ½)/3 · dx²/ν), else from `scene.mach`
/// (the estimated terminal speed `u_est` at that Mach number, dt = Ma c_s dx / u_est); refuses τ outside
/// [0.5001, 50] and, with `fluid.tau`, an estimated Mach number above [`MAX_MACH`].
fn time_step(s: &SettlingSphereConfig, fluid_tau: Option<f64>, nu: f64, dx: f64, u_est: f64) -> Result<(f64, f64)> {
    let cs = 1.0 / 3f64.sqrt();
    let (dt, tau) = match fluid_tau {
        Some(tau) => ((tau - 0.5) / 3.0 * dx * dx / nu, tau),
        None => {
            let dt = s.mach * cs * dx / u_est;
            (dt, 0.5 + 3.0 * nu * dt / (dx * dx))
        }
    };
    let mach_est = u_est * dt / dx / cs;
    if !(tau - 0.5 >= 1e-4 && tau <= 50.0) {
        return config_err(format!(
            "scene.mach = {} at scene.resolution = {} gives tau = {tau:.6}, outside [0.5001, 50]; {}",
            s.mach,
            s.resolution,
            if tau < 0.5001 {
                "raise scene.mach or lower scene.resolution"
            } else {
                "lower scene.mach or give fluid.tau"
            }
        ));
    }
    if fluid_tau.is_some() && mach_est > MAX_MACH {
        return config_err(format!(
            "fluid.tau = {tau} gives an estimated terminal Mach number of {mach_est:.3} (above {MAX_MACH}); lower \
             fluid.tau, or leave it out and set scene.mach"
        ));
    }
    Ok((dt, tau))
}

/// The lattice steps of `scene.duration` (s), or of `fall_time` (s) where it is absent; refuses more than
/// 1e9 steps.
fn step_count(duration: Option<f64>, fall_time: f64, dt: f64) -> Result<u64> {
    let duration = match duration {
        Some(t) => {
            check("duration", t, t > 0.0 && t <= 1e6, "must be a time in (0, 1e6] s")?;
            t
        }
        None => fall_time,
    };
    let steps_f = (duration / dt).ceil();
    if steps_f > 1e9 {
        return config_err(format!(
            "scene.duration = {duration} s is {steps_f:.3e} lattice steps of {dt:.3e} s; shorten it or coarsen \
             scene.resolution"
        ));
    }
    Ok((steps_f as u64).max(1))
}

pub(super) fn build(s: &SettlingSphereConfig, cfg: &Config) -> Result<Scene> {
    check(
        "resolution",
        s.resolution,
        (3.0..=512.0).contains(&s.resolution),
        "must be between 3 and 512 cells per diameter",
    )?;
    check(
        "mach",
        s.mach,
        s.mach > 0.0 && s.mach <= MAX_MACH,
        &format!("must be in (0, {MAX_MACH}]"),
    )?;
    let (p, reference) = physical(s)?;
    let d = p.d;
    for (a, &l) in s.r#box.iter().enumerate() {
        check(
            &format!("box[{a}]"),
            l,
            l >= 1.5 * d,
            &format!("must be at least 1.5 sphere diameters ({} m)", 1.5 * d),
        )?;
    }
    let dx = d / s.resolution;
    let cells: [usize; 3] = std::array::from_fn(|a| (s.r#box[a] / dx).round().min(1e12) as usize);
    check_extent(cells, "scene.box and scene.resolution")?;
    let h = s.start_height;
    check(
        "start_height",
        h,
        h >= 0.5 * d + dx && h <= cells[2] as f64 * dx - 0.5 * d - dx,
        &format!(
            "must keep the sphere a cell off the bottom and the lid: between {:.6} and {:.6} m",
            0.5 * d + dx,
            cells[2] as f64 * dx - 0.5 * d - dx
        ),
    )?;
    let nu = p.mu / p.rho_f;
    let ratio = p.rho_p / p.rho_f;
    let galileo = ((ratio - 1.0) * p.g * d.powi(3)).sqrt() / nu;
    let re_est = schiller_naumann_reynolds(galileo);
    let u_est = re_est * nu / d;
    let (dt, tau) = time_step(s, cfg.fluid.tau, nu, dx, u_est)?;
    let g_lat = p.g * dt * dt / dx;
    let d_lat = s.resolution;
    let centre = DVec3::new(cells[0] as f64 / 2.0, cells[1] as f64 / 2.0, h / dx);
    let body = Body::sphere(0, centre, d_lat / 2.0, ratio);
    // Without a duration: down to the bottom at 70 % of the unbounded estimate (walls and the bottom
    // slow the sphere).
    let steps = step_count(s.duration, (h - 0.5 * d) / (0.7 * u_est), dt)?;
    let planes = wall_planes(cells, [false; 3]);
    // The case names the run only where the run is that experiment (its fluid, sphere, box and gravity).
    let case_label = match (&s.case, reference.is_some()) {
        (Some(c), true) => format!(" (ten Cate {c})"),
        (Some(c), false) => format!(" (ten Cate {c} changed: not the experiment, no reference speed)"),
        (None, _) => String::new(),
    };
    let scales = Scales {
        dx,
        dt,
        d,
        nu,
        galileo,
        ratio,
        re_est,
    };
    let observe = observables(scales, reference);
    Ok(Scene {
        name: "settling_sphere",
        cells: Some(cells),
        periodic: [false; 3],
        default_blocks: default_blocks(cells),
        geometry: Geometry::default(),
        params: super::unforced(tau, cfg),
        steps,
        init: super::at_rest(),
        observe,
        particles: Some(ParticleScene::coupled(vec![body], planes, g_lat)),
        units: Some(Units {
            dx,
            dt,
            density: p.rho_f,
        }),
        description: format!(
            "sphere D = {d} m ({} cells), rho_p = {} kg/m3 in rho_f = {} kg/m3, mu = {} Pa s{} (Ga = {galileo:.2}), \
             closed {:?} m box ({cells:?} cells), dx = {dx:.4e} m, dt = {dt:.4e} s, tau = {tau:.5}",
            s.resolution, p.rho_p, p.rho_f, p.mu, case_label, s.r#box
        ),
    })
}

/// The physical scales of a run that its observables convert with.
#[derive(Clone, Copy)]
struct Scales {
    /// Cell size (m).
    dx: f64,
    /// Time step (s).
    dt: f64,
    /// Sphere diameter (m).
    d: f64,
    /// Kinematic viscosity of the fluid (m²/s).
    nu: f64,
    /// Galileo number.
    galileo: f64,
    /// Density ratio ρ_p / ρ_f.
    ratio: f64,
    /// Schiller–Naumann estimate of the terminal Reynolds number.
    re_est: f64,
}

/// The observables of a settling run: the peak settling speed (windowed over one cell of travel, and the
/// raw per-step maximum) in m/s, its Reynolds and Stokes numbers, the velocity noise, the final gap
/// to the bottom and, for one of ten Cate's cases, the errors against its measured peak.
fn observables(scales: Scales, reference: Option<TenCateCase>) -> super::ObserveFn {
    let cs = 1.0 / 3f64.sqrt();
    let Scales { dx, dt, d, nu, .. } = scales;
    Box::new(move |v: &dyn super::FluidView| {
        let traj = v.trajectory();
        let (peak, t_peak) = peak_settling_speed(&traj);
        let raw = traj.iter().map(|(_, b)| -b.velocity.z).fold(0.0, f64::max);
        let noise = velocity_noise(&traj);
        let z = v.bodies().first().map_or(0.0, |b| b.position.z);
        let u = peak * dx / dt;
        let mut o = BTreeMap::from([
            ("terminal_velocity".to_string(), u),
            ("time_of_peak".to_string(), t_peak * dt),
            ("reynolds".to_string(), u * d / nu),
            ("galileo".to_string(), scales.galileo),
            ("density_ratio".to_string(), scales.ratio),
            ("stokes".to_string(), scales.ratio * u * d / nu / 9.0),
            ("reynolds_estimate".to_string(), scales.re_est),
            ("peak_mach".to_string(), raw / cs),
            ("peak_velocity_raw".to_string(), raw * dx / dt),
            ("final_gap".to_string(), z * dx - 0.5 * d),
            ("dx".to_string(), dx),
            ("dt".to_string(), dt),
            ("velocity_noise".to_string(), noise),
        ]);
        if let Some(c) = reference {
            let r = c.peak_speed();
            o.insert("reference_velocity".to_string(), r);
            o.insert("relative_error".to_string(), (u - r).abs() / r);
            o.insert("relative_error_raw".to_string(), (raw * dx / dt - r).abs() / r);
        }
        o
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The Schiller–Naumann Reynolds number solves its defining equation, and tends to Stokes' Ga²/18.
    #[test]
    fn schiller_naumann_solves_its_equation() {
        for ga in [0.1, 1.0, 10.0, 38.88, 300.0] {
            let re = schiller_naumann_reynolds(ga);
            let lhs = re * (1.0 + 0.15 * re.powf(0.687));
            assert!((lhs - ga * ga / 18.0).abs() <= 1e-12 * ga * ga, "Ga {ga}: Re {re}");
        }
        let re = schiller_naumann_reynolds(1e-3);
        assert!((re - 1e-6 / 18.0).abs() < 1e-3 * re);
    }

    fn body_at(z: f64) -> Body {
        Body::sphere(0, DVec3::new(0.0, 0.0, z), 1.0, 2.0)
    }

    /// A fall at constant speed gives that speed; noise of period shorter than one cell averages out.
    #[test]
    fn peak_speed_averages_over_one_cell() {
        // z(t) = 100 - 0.05 t + 0.2 sin(2π t / 4): the wiggle has a period of 4 steps (0.2 cells).
        let traj: Vec<(f64, Body)> = (0..2000)
            .map(|t| {
                let t = t as f64;
                (
                    t,
                    body_at(100.0 - 0.05 * t + 0.002 * (std::f64::consts::TAU * t / 4.0).sin()),
                )
            })
            .collect();
        let (u, _) = peak_settling_speed(&traj);
        assert!((u - 0.05).abs() < 0.002 / 20.0 * 4.0 + 1e-12, "{u}");
        let steady: Vec<(f64, Body)> = (0..100).map(|t| (t as f64, body_at(50.0 - 0.1 * t as f64))).collect();
        assert!((peak_settling_speed(&steady).0 - 0.1).abs() < 1e-12);
    }

    /// A speed rising linearly to its peak has no noise; an alternating ±a on top of it has a noise of
    /// a / peak (the running mean over the odd window of about 20 steps per cell leaves one unpaired term
    /// of the alternation, a / w: a relative tolerance of 1/15).
    #[test]
    fn velocity_noise_is_the_rms_about_the_one_cell_mean() {
        let speed = |t: usize| 0.05 * (t as f64 / 1000.0).min(1.0);
        let trace = |a: f64| -> Vec<(f64, Body)> {
            (0..1200)
                .map(|t| {
                    let mut b = body_at(0.0);
                    let wiggle = if t % 2 == 0 { a } else { -a };
                    b.velocity.z = -(speed(t) + wiggle);
                    (t as f64, b)
                })
                .collect()
        };
        assert!(velocity_noise(&trace(0.0)) < 1e-12);
        let a = 5e-4;
        let n = velocity_noise(&trace(a));
        // peak 0.05 + a, steps per cell 1/peak ≈ 20 (even).
        let want = a / (0.05 + a);
        assert!((n - want).abs() < want / 15.0, "noise {n}, want {want}");
    }

    /// Block counts divide the axis and aim at the target edge; x is never split.
    #[test]
    fn blocks_divide_the_axis() {
        assert_eq!(blocks_along(53, 24), 1);
        assert_eq!(blocks_along(85, 16), 5);
        assert_eq!(blocks_along(80, 24), 4);
        assert_eq!(blocks_along(128, 16), 8);
        assert_eq!(blocks_along(5, 16), 1);
        assert_eq!(default_blocks([80, 80, 128]), [1, 1, 8]);
        assert_eq!(default_blocks([53, 53, 85]), [1, 1, 5]);
        assert_eq!(default_blocks([133, 133, 213]), [1, 7, 3]);
    }
}
