//! `[particles]`: the rigid-body solver and the fluid-particle coupling switches.

use crate::error::{config_err, Result};
use serde::{Deserialize, Serialize};

/// `[particles]`: the hard-contact rigid-body solver (section 2.2, Algorithm 7) of scenes with bodies.
/// Units are the scene's: lattice units (Δx = Δt = 1) when the fluid is on. Keys left out take the
/// scene's default where it has one (gravity, restitution threshold), else the default below.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ParticlesConfig {
    /// Rigid-body sub-steps S per time step (Algorithm 1; the hydrodynamic force is held over them).
    #[serde(default = "d_subcycles")]
    pub subcycles: usize,
    /// Coefficient of restitution e of the normal contact (0: plastic, 1: elastic).
    #[serde(default = "d_restitution")]
    pub restitution: f64,
    /// Coulomb friction coefficient μ.
    #[serde(default = "d_friction")]
    pub friction: f64,
    /// Sweeps over the contacts per sub-step: under Jacobi, sweeps over all contacts, each one round
    /// between the blocks; under block Gauss–Seidel, sweeps over the contacts of a block per round. Absent:
    /// [`JACOBI_ITERATIONS`] under Jacobi, [`BLOCK_GAUSS_SEIDEL_ITERATIONS`] under block Gauss–Seidel
    /// ([`ParticlesConfig::iterations`]).
    #[serde(default)]
    pub iterations: Option<usize>,
    /// Rounds of the contact solve per sub-step. Between rounds every block's velocity changes are
    /// summed and published without moving a body, and the next round continues the solve from the
    /// impulses so far. Contacts a block does not see (beyond its halo) then reach its solve within
    /// the sub-step instead of one sub-step late. 1: one solve per sub-step.
    #[serde(default = "d_rounds")]
    pub rounds: usize,
    /// Relaxation ω of the Gauss–Seidel or Jacobi update, in (0, 2); absent: 1 under block
    /// Gauss–Seidel, [`JACOBI_RELAXATION`] under Jacobi ([`ParticlesConfig::relaxation`]).
    #[serde(default)]
    pub relaxation: Option<f64>,
    /// How the contacts of all blocks are solved: `"block_gauss_seidel"` (default) or `"jacobi"`.
    #[serde(default)]
    pub solver: ContactSolver,
    /// With `solver = "jacobi"`: the share in [0, 1] of each contact's impulse of the previous
    /// sub-step it starts from (0: from zero). Above about 0.9 a pile keeps bouncing.
    #[serde(default = "d_warm_start")]
    pub warm_start: f64,
    /// Body count (locals + shadows of a block) from which detection uses the hash grid, not all pairs.
    #[serde(default = "d_grid_threshold")]
    pub grid_threshold: usize,
    /// Gap below which a contact is generated (speculative contacts), ≥ 0.
    #[serde(default)]
    pub contact_margin: f64,
    /// Baumgarte factor β in [0, 1]: a penetration d is removed at speed β d / Δt_sub.
    #[serde(default = "d_position_correction")]
    pub position_correction: f64,
    /// Approach speed above which restitution applies; absent: the scene's default.
    pub restitution_threshold: Option<f64>,
    /// Gravitational acceleration; absent: the scene's default.
    pub gravity: Option<[f64; 3]>,
    /// Time per step for scenes without fluid (with fluid the step is the lattice time unit, 1); absent:
    /// the scene's default.
    pub dt: Option<f64>,
    /// Boundary condition at particle surfaces: `"cli"` (default; eq. 6 with the ray–sphere δ_q, simple
    /// bounce-back where the second fluid cell is missing) or `"sbb"` (simple bounce-back).
    #[serde(default)]
    pub boundary: SurfaceBoundary,
    /// Average the hydrodynamic force and torque over the current and the previous step (default on:
    /// without it, spheres lighter than about twice the fluid's density oscillate and blow up).
    #[serde(default = "yes")]
    pub force_averaging: bool,
    /// Exchange the momentum of cells a body covers or uncovers with that body (fluid plus bodies then
    /// conserve momentum to the refill's rounding). Off by default, as in waLBerla's coupling benchmarks
    /// (`conserveMomentum = false`): the impulse of a cell changing state is a one-step spike of up to
    /// several times the drag, which at 9 cells per diameter puts 1.1–1.3 % of noise on the settling
    /// speed (0.1–0.2 % without) and moves its peak by up to 3 % (`docs/benchmarks.md`).
    #[serde(default)]
    pub conserve_momentum: bool,
    /// `"equilibrium"` (default), `"grad"` or `"extrapolation"`: how uncovered cells are rebuilt.
    #[serde(default)]
    pub refill: Refill,
    /// `false` leaves the scene's bodies out: the fluid runs alone on the same blocks and geometry (to
    /// measure what the bodies cost, `blockflow bench coupled`).
    #[serde(default = "yes")]
    pub enabled: bool,
}

/// The Jacobi solver's default over-relaxation ω. Mass splitting (each body's mass divided among its
/// contacts) makes every sweep's update conservative, so it converges for ω up to near 2; the last
/// sweep of a sub-step is unrelaxed, so an isolated collision still ends at its exact restitution.
/// Over the settled hopper-small pile on 96 blocks (10 sweeps, three seeds) ω = 1.8 leaves 1.15× the
/// one-block penetration (geometric mean) against 1.52× at ω = 1, at the same cost, and at ω = 1.95
/// the pile gets worse again (`docs/benchmarks.md`, "Hard contacts across blocks").
pub const JACOBI_RELAXATION: f64 = 1.8;

/// The Jacobi solver's default sweeps per sub-step. Over 4000 steps of the hopper-small pile (96 blocks of
/// 12³, 2 threads, three seeds) 10 Jacobi sweeps take 0.96× the time of 20 block Gauss–Seidel sweeps and
/// leave 1.15× the one-block penetration against 5.05× (`docs/benchmarks.md`, "Hard contacts across
/// blocks"); 7 sweeps save 3 % of the time for 1.38×.
pub const JACOBI_ITERATIONS: usize = 10;

/// Block Gauss–Seidel's default sweeps over a block's contacts per round.
pub const BLOCK_GAUSS_SEIDEL_ITERATIONS: usize = 20;

fn d_subcycles() -> usize {
    10
}
fn d_restitution() -> f64 {
    0.5
}
fn d_friction() -> f64 {
    0.3
}
fn d_rounds() -> usize {
    1
}
fn d_warm_start() -> f64 {
    0.8
}
fn d_grid_threshold() -> usize {
    128
}
fn d_position_correction() -> f64 {
    0.2
}

impl Default for ParticlesConfig {
    fn default() -> Self {
        ParticlesConfig {
            subcycles: d_subcycles(),
            restitution: d_restitution(),
            friction: d_friction(),
            iterations: None,
            rounds: d_rounds(),
            relaxation: None,
            solver: ContactSolver::default(),
            warm_start: d_warm_start(),
            grid_threshold: d_grid_threshold(),
            contact_margin: 0.0,
            position_correction: d_position_correction(),
            restitution_threshold: None,
            gravity: None,
            dt: None,
            boundary: Default::default(),
            force_averaging: true,
            conserve_momentum: false,
            refill: Refill::Equilibrium,
            enabled: true,
        }
    }
}

impl ParticlesConfig {
    /// The relaxation ω the solver uses: `relaxation` if given, else 1 under block Gauss–Seidel and
    /// [`JACOBI_RELAXATION`] under Jacobi.
    pub fn relaxation(&self) -> f64 {
        self.relaxation.unwrap_or(match self.solver {
            ContactSolver::BlockGaussSeidel => 1.0,
            ContactSolver::Jacobi => JACOBI_RELAXATION,
        })
    }

    /// The sweeps per sub-step the solver uses: `iterations` if given, else [`JACOBI_ITERATIONS`] under
    /// Jacobi and [`BLOCK_GAUSS_SEIDEL_ITERATIONS`] under block Gauss–Seidel.
    pub fn iterations(&self) -> usize {
        self.iterations.unwrap_or(match self.solver {
            ContactSolver::BlockGaussSeidel => BLOCK_GAUSS_SEIDEL_ITERATIONS,
            ContactSolver::Jacobi => JACOBI_ITERATIONS,
        })
    }

    /// Checks every key's range; the message names the key and the allowed range.
    pub fn validate(&self) -> Result<()> {
        let p = self;
        if p.subcycles == 0 || p.subcycles > 255 {
            return config_err(format!(
                "particles.subcycles = {}: must be between 1 and 255",
                p.subcycles
            ));
        }
        if p.rounds == 0 || p.subcycles * p.rounds > 255 {
            return config_err(format!(
                "particles.rounds = {}: must be at least 1, with particles.subcycles × rounds at most 255 ({} here)",
                p.rounds,
                p.subcycles * p.rounds
            ));
        }
        if p.solver == ContactSolver::Jacobi {
            if p.rounds != 1 {
                return config_err(format!(
                    "particles.rounds = {}: the jacobi solver exchanges velocities after every sweep; remove the \
                     key, or set particles.solver = \"block_gauss_seidel\" (rounds apply to it)",
                    p.rounds
                ));
            }
            if p.subcycles * (p.iterations() + 1) > 255 {
                return config_err(format!(
                    "particles.iterations = {}: with solver = \"jacobi\", particles.subcycles × (iterations + 1) \
                     must be at most 255 ({} here)",
                    p.iterations(),
                    p.subcycles * (p.iterations() + 1)
                ));
            }
        }
        if !((0.0..=1.0).contains(&p.warm_start)) {
            return config_err(format!(
                "particles.warm_start = {}: must be between 0 and 1",
                p.warm_start
            ));
        }
        if p.iterations() == 0 || p.iterations() > 100_000 {
            return config_err(format!(
                "particles.iterations = {}: must be between 1 and 100000",
                p.iterations()
            ));
        }
        let checks: [(&str, f64, bool, &str); 5] = [
            (
                "restitution",
                p.restitution,
                (0.0..=1.0).contains(&p.restitution),
                "between 0 and 1",
            ),
            ("friction", p.friction, p.friction >= 0.0, "≥ 0"),
            (
                "relaxation",
                p.relaxation(),
                p.relaxation() > 0.0 && p.relaxation() < 2.0,
                "in (0, 2)",
            ),
            ("contact_margin", p.contact_margin, p.contact_margin >= 0.0, "≥ 0"),
            (
                "position_correction",
                p.position_correction,
                (0.0..=1.0).contains(&p.position_correction),
                "between 0 and 1",
            ),
        ];
        for (k, v, ok, what) in checks {
            if !ok || !v.is_finite() {
                return config_err(format!("particles.{k} = {v}: must be {what}"));
            }
        }
        if let Some(t) = p.restitution_threshold {
            if !(t >= 0.0 && t.is_finite()) {
                return config_err(format!("particles.restitution_threshold = {t}: must be ≥ 0"));
            }
        }
        if let Some(g) = p.gravity {
            if g.iter().any(|v| !v.is_finite()) {
                return config_err(format!("particles.gravity = {g:?}: must be finite"));
            }
        }
        if let Some(dt) = p.dt {
            if !(dt > 0.0 && dt.is_finite()) {
                return config_err(format!("particles.dt = {dt}: must be a finite number > 0"));
            }
        }
        Ok(())
    }
}

/// How the hard contacts of all blocks are solved (`particles.solver`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ContactSolver {
    /// Each block solves every contact it sees by projected Gauss–Seidel from zero impulses and keeps
    /// those it owns; blocks are coupled block-Jacobi once per round (`particles.rounds`). The result
    /// depends on how the domain is cut into blocks.
    #[default]
    BlockGaussSeidel,
    /// Projected Jacobi with mass splitting over all contacts, warm-started from the previous sub-step
    /// (`particles.warm_start`): every sweep (`particles.iterations` per sub-step) is one round, after
    /// which each block publishes its bodies' velocities. The result does not depend on the block
    /// layout (bitwise in a box without periodic axes, to rounding across periodic faces).
    Jacobi,
}

/// How a cell a body uncovers is given its populations (`particles.refill`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Refill {
    /// The (forced) equilibrium at the body's surface velocity and the neighbours' mean density
    /// (Algorithm 6).
    #[default]
    Equilibrium,
    /// The equilibrium plus Grad's non-equilibrium part from the velocity gradient of the fluid
    /// neighbours (central differences where both neighbours along an axis are fluid, else one-sided).
    Grad,
    /// Every population extrapolated from the fluid cells along the lattice direction closest to the
    /// sphere's outward normal: quadratic 3f₁ − 3f₂ + f₃ with three such cells, linear 2f₁ − f₂ with two;
    /// with fewer, as `grad` (waLBerla's extrapolation reconstructor with its sphere-normal direction).
    Extrapolation,
}

/// Boundary condition at particle surfaces (`particles.boundary`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum SurfaceBoundary {
    /// Central linear interpolation with δ_q from the ray–sphere intersection (eq. 6), simple bounce-back
    /// where the second fluid cell is missing.
    #[default]
    Cli,
    /// Simple bounce-back (δ_q = 1/2 everywhere).
    Sbb,
}

fn yes() -> bool {
    true
}
