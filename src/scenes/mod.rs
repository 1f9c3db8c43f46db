//! Scenes: each turns its `[scene]` keys (above all `scene.resolution`) into a domain extent, geometry,
//! fluid parameters, a step count, an initial state and its observables, keeping the physical problem
//! fixed when the resolution changes.

mod box_scene;
mod calibration;
mod cavity;
mod channel;
mod collision;
mod couette;
mod drag_array;
mod dry;
mod granular_box;
mod hopper;
mod incline;
mod settling;
mod taylor_green;
mod view;

use crate::config::{Config, DomainConfig};
use crate::error::{config_err, Result};
use crate::physics::domain::DomainSpec;
use crate::physics::geometry::Geometry;
use blockflow_kernels::rigid::{Body, Plane};
use blockflow_kernels::TrtParams;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

pub use crate::config::scene::{
    BoxConfig, CalibrationConfig, CavityConfig, ChannelConfig, CollisionConfig, CouetteConfig, DragArrayConfig,
    GranularBoxConfig, HopperConfig, InclineConfig, PlaneConfig, SceneConfig, SettlingSphereConfig, SphereConfig,
    TaylorGreenConfig, KINDS,
};
pub use settling::{schiller_naumann_reynolds, TenCateCase, TEN_CATE};

/// Read access to the fluid for observables: visits (global cell, δρ, u) of every fluid cell.
pub trait FluidView {
    /// Visits every fluid cell in a fixed order.
    fn visit(&self, f: &mut dyn FnMut([usize; 3], f64, [f64; 3]));
    /// Steps taken so far (the time in lattice units).
    fn steps_taken(&self) -> u64;
    /// The rigid bodies, sorted by id (empty without particles).
    fn bodies(&self) -> Vec<Body> {
        Vec::new()
    }
    /// Body 0 recorded at every row of the time series: (time, body).
    fn trajectory(&self) -> Vec<(f64, Body)> {
        Vec::new()
    }
    /// Hydrodynamic force and torque of the last boundary pass per body, sorted by id.
    fn hydro_forces(&self) -> Vec<crate::physics::particle_cells::BodyForce> {
        Vec::new()
    }
}

/// The rigid bodies of a scene and what the solver needs from the scene.
pub struct ParticleScene {
    /// Initial bodies (ids unique).
    pub bodies: Vec<Body>,
    /// Planes bodies collide with (box walls included).
    pub planes: Vec<Plane>,
    /// Default gravity (`particles.gravity` overrides).
    pub gravity: [f64; 3],
    /// Default restitution threshold (`particles.restitution_threshold` overrides).
    pub restitution_threshold: f64,
    /// Default time per step (`particles.dt` overrides; must be 1 with fluid).
    pub dt: f64,
}

impl ParticleScene {
    /// The bodies of a coupled scene: `bodies` and `planes` under gravity −`g` along z, lattice time
    /// steps (dt = 1) and the default restitution threshold 10⁻³.
    pub fn coupled(bodies: Vec<Body>, planes: Vec<Plane>, g: f64) -> Self {
        ParticleScene {
            bodies,
            planes,
            gravity: [0.0, 0.0, -g],
            restitution_threshold: 1e-3,
            dt: 1.0,
        }
    }
}

/// TRT parameters of relaxation time `tau` with the configured magic parameter Λ (`fluid.magic`) and
/// no body force.
pub(crate) fn unforced(tau: f64, cfg: &Config) -> TrtParams {
    TrtParams {
        tau,
        magic: cfg.fluid.magic,
        force: [0.0; 3],
    }
}

/// The initial state of fluid at rest: δρ = 0 and u = 0 in every cell.
pub(crate) fn at_rest() -> InitFn {
    Box::new(|_| (0.0, [0.0; 3]))
}

/// The rigid planes of the walls on the non-periodic faces of a box of `cells` (walls at 0 and L).
pub fn wall_planes(cells: [usize; 3], periodic: [bool; 3]) -> Vec<Plane> {
    let mut out = Vec::new();
    for a in 0..3 {
        if periodic[a] {
            continue;
        }
        let mut n = glam::DVec3::ZERO;
        n[a] = 1.0;
        let mut far = glam::DVec3::ZERO;
        far[a] = cells[a] as f64;
        out.push(Plane::through(1000 + 2 * a as u64, glam::DVec3::ZERO, n));
        out.push(Plane::through(1001 + 2 * a as u64, far, -n));
    }
    out
}

/// Initial state of a cell: (δρ, u) from its global coordinates.
pub type InitFn = Box<dyn Fn([usize; 3]) -> (f64, [f64; 3]) + Send + Sync>;
/// Scene observables from the fluid state.
pub type ObserveFn = Box<dyn Fn(&dyn FluidView) -> BTreeMap<String, f64> + Send + Sync>;

/// Everything a run needs from a scene.
pub struct Scene {
    /// Scene kind (`channel`, ...).
    pub name: &'static str,
    /// Domain extent in cells; `None` when the `[domain]` keys define it (box scene).
    pub cells: Option<[usize; 3]>,
    /// Periodicity the scene requires.
    pub periodic: [bool; 3],
    /// Block count used when neither `domain.blocks` nor `domain.block_size` is given.
    pub default_blocks: [usize; 3],
    /// Walls and planes.
    pub geometry: Geometry,
    /// τ, Λ and body force.
    pub params: TrtParams,
    /// Default number of steps.
    pub steps: u64,
    /// Initial state.
    pub init: InitFn,
    /// Observables.
    pub observe: ObserveFn,
    /// Rigid bodies, if the scene has any.
    pub particles: Option<ParticleScene>,
    /// Physical units of a scene given in SI units (absent: lattice units throughout).
    pub units: Option<Units>,
    /// One line on the physical set-up, for logs and summary.json.
    pub description: String,
}

/// The lattice spacing, time step and fluid density of a scene set up in SI units: a lattice length is
/// `dx` m, a lattice time `dt` s, a lattice velocity `dx / dt` m/s and a lattice force
/// `density dx⁴ / dt²` N.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Units {
    /// Lattice spacing, m.
    pub dx: f64,
    /// Time step, s.
    pub dt: f64,
    /// Fluid density, kg/m³ (lattice density 1).
    pub density: f64,
}

/// Builds the scene of a configuration.
pub fn build(cfg: &Config) -> Result<Scene> {
    match &cfg.scene {
        SceneConfig::Channel(s) => channel::build(s, cfg),
        SceneConfig::Couette(s) => couette::build(s, cfg),
        SceneConfig::TaylorGreen(s) => taylor_green::build(s, cfg),
        SceneConfig::Cavity(s) => cavity::build(s, cfg),
        SceneConfig::Box(s) => box_scene::build(s, cfg),
        SceneConfig::GranularBox(s) => granular_box::build(s, cfg),
        SceneConfig::Incline(s) => incline::build(s, cfg),
        SceneConfig::Collision(s) => collision::build(s, cfg),
        SceneConfig::DragArray(s) => drag_array::build(s, cfg),
        SceneConfig::SettlingSphere(s) => settling::build(s, cfg),
        SceneConfig::Hopper(s) => hopper::build(s, cfg),
        SceneConfig::Calibration(s) => calibration::build(s, cfg),
    }
}

/// Most bodies a scene may place (a bound checked before the bodies are allocated; the memory estimate of
/// the run comes later).
pub const MAX_BODIES: usize = 1_000_000;

/// Largest domain extent along one axis, in cells (far beyond any machine's memory in 3D; keeps every
/// cell and block count, and their products, inside `usize`).
pub const MAX_CELLS_PER_AXIS: usize = 1 << 20;

/// Checks a scene's domain extent before anything is sized from it: every axis between 1 and
/// [`MAX_CELLS_PER_AXIS`] cells. `what` names the keys that set the extent.
pub fn check_extent(cells: [usize; 3], what: &str) -> Result<()> {
    if cells.iter().any(|&c| c == 0 || c > MAX_CELLS_PER_AXIS) {
        return config_err(format!(
            "{what} give a domain of {cells:?} cells: every axis must have between 1 and {MAX_CELLS_PER_AXIS} cells; \
             lower them"
        ));
    }
    Ok(())
}

/// The extent `blocks × block_size` of a domain given by both keys, checked for overflow and size.
pub fn extent_of(blocks: [usize; 3], block_size: [usize; 3]) -> Result<[usize; 3]> {
    let mut cells = [0usize; 3];
    for a in 0..3 {
        cells[a] = blocks[a].saturating_mul(block_size[a]);
    }
    check_extent(
        cells,
        &format!("domain.blocks = {blocks:?} x domain.block_size = {block_size:?}"),
    )?;
    Ok(cells)
}

/// Resolves the block decomposition of a scene from the `[domain]` keys: blocks, block size or both
/// (they must multiply to the scene's extent), periodicity fixed by the scene.
pub fn domain_for(d: &DomainConfig, scene: &Scene) -> Result<DomainSpec> {
    if let Some(cells) = scene.cells {
        check_extent(cells, &format!("the scene keys of {}", scene.name))?;
    }
    if let Some(p) = d.periodic {
        if p != scene.periodic && scene.cells.is_some() {
            return config_err(format!(
                "domain.periodic = {p:?}: scene {} fixes periodicity to {:?}; remove the key",
                scene.name, scene.periodic
            ));
        }
    }
    let Some(cells) = scene.cells else {
        let blocks = d.blocks.unwrap_or([1, 1, 1]);
        let block_size = d.block_size.unwrap_or([16, 16, 16]);
        extent_of(blocks, block_size)?;
        return Ok(DomainSpec {
            blocks,
            block_size,
            periodic: d.periodic.unwrap_or(scene.periodic),
        });
    };
    let (blocks, block_size) = match (d.blocks, d.block_size) {
        (Some(b), Some(s)) => {
            let have: [usize; 3] = std::array::from_fn(|a| b[a].saturating_mul(s[a]));
            if have != cells {
                return config_err(format!(
                    "domain.blocks {b:?} x domain.block_size {s:?} = {have:?} cells, but scene {} needs {cells:?} \
                     at this scene.resolution; give only one of the two keys",
                    scene.name
                ));
            }
            (b, s)
        }
        (Some(b), None) => {
            for a in 0..3 {
                if cells[a] % b[a] != 0 {
                    return config_err(format!(
                        "domain.blocks = {b:?}: {} cells along axis {a} do not split into {} equal blocks (scene {} \
                         needs {cells:?} cells); choose a divisor",
                        cells[a], b[a], scene.name
                    ));
                }
            }
            (b, [cells[0] / b[0], cells[1] / b[1], cells[2] / b[2]])
        }
        (None, Some(s)) => {
            for a in 0..3 {
                if cells[a] % s[a] != 0 {
                    return config_err(format!(
                        "domain.block_size = {s:?}: {} cells along axis {a} are not a multiple of {} (scene {} needs \
                         {cells:?} cells); choose a divisor",
                        cells[a], s[a], scene.name
                    ));
                }
            }
            ([cells[0] / s[0], cells[1] / s[1], cells[2] / s[2]], s)
        }
        (None, None) => {
            let b = scene.default_blocks;
            let ok = (0..3).all(|a| cells[a] % b[a] == 0);
            if ok {
                (b, [cells[0] / b[0], cells[1] / b[1], cells[2] / b[2]])
            } else {
                ([1, 1, 1], cells)
            }
        }
    };
    Ok(DomainSpec {
        blocks,
        block_size,
        periodic: scene.periodic,
    })
}

/// τ from `fluid.tau` or the scene's default.
pub(crate) fn tau_or(cfg: &Config, default: f64) -> f64 {
    cfg.fluid.tau.unwrap_or(default)
}

/// Checks that a scene parameter is a finite number inside `(lo, hi]`-style bounds given as a predicate.
pub(crate) fn check(key: &str, v: f64, ok: bool, what: &str) -> Result<()> {
    if ok && v.is_finite() {
        Ok(())
    } else {
        config_err(format!("scene.{key} = {v}: {what}"))
    }
}

/// Relative L2 error of a velocity field against an analytic one: sqrt(Σ|u - u_a|²) / sqrt(Σ|u_a|²).
pub(crate) fn relative_l2(view: &dyn FluidView, exact: impl Fn([usize; 3]) -> [f64; 3]) -> f64 {
    let mut num = 0.0;
    let mut den = 0.0;
    view.visit(&mut |g, _, u| {
        let e = exact(g);
        for a in 0..3 {
            num += (u[a] - e[a]) * (u[a] - e[a]);
            den += e[a] * e[a];
        }
    });
    (num / den).sqrt()
}

/// Kinetic energy Σ ½|u|² of the fluid.
pub(crate) fn kinetic_energy(view: &dyn FluidView) -> f64 {
    let mut e = 0.0;
    view.visit(&mut |_, _, u| e += 0.5 * (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]));
    e
}

/// Steps for a wall-bounded flow to reach steady state to ~1e-13: the slowest viscous mode decays as
/// exp(-π² ν t / H²), so t = 3.1 H² / ν.
/// (H² in floating point: a width past 2³² cells, which the extent check refuses later, must not overflow
/// here first.)
pub(crate) fn steady_steps(h: usize, nu: f64) -> u64 {
    let h = h as f64;
    (3.1 * (h * h) / nu).ceil() as u64
}
