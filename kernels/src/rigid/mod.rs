//! Rigid-body numerics: the hard-contact particle solver of section 2.2 and Algorithm 7 of Rettinger & Rüde
//! 2019 (contact detection, contact resolution, time integration), for spheres and planes.
//!
//! Scheme of one sub-step ([`substep`]), semi-implicit Euler with velocity-level hard contacts:
//! 1. velocities += dt · (external force + gravity − buoyancy) / m, angular velocities += dt · T / I;
//! 2. contact detection ([`detect`], all pairs or a hash grid), sorted by body ids;
//! 3. contact resolution ([`resolve`], projected Gauss–Seidel over the contacts in that sorted order, with
//!    non-penetration, restitution and the Coulomb cone; or [`JacobiSolve`], projected Jacobi with mass
//!    splitting, whose result does not depend on how the bodies are distributed);
//! 4. positions and orientations advanced with the new velocities.
//!
//! Everything is a pure function over plain data; no threads. Results do not depend on the order of the
//! body slice: contacts are generated with the lower-id body as `a` and sorted by (id a, kind, id b), and the
//! solver visits them in that order.

pub mod body;
pub mod contact;
pub mod hard_contact;
pub mod integrate;
pub mod jacobi;

pub use body::{Body, Plane};
pub use contact::{detect, detect_all_pairs, detect_grid, Contact, ContactCandidates};
pub use hard_contact::{resolve, resolve_impulses, resolve_impulses_warm, resolve_targets, SolverStats, WarmStart};
pub use integrate::{apply_forces, integrate, integrate_positions};
pub use jacobi::{apply_impulses, final_relaxation, project_impulse, JacobiSolve};

use glam::DVec3;

/// Parameters of the rigid-body solver.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RigidParams {
    /// Gravitational acceleration.
    pub gravity: DVec3,
    /// Fluid density ρ_f for buoyancy (force g (m − ρ_f V)); 0 disables buoyancy.
    pub fluid_density: f64,
    /// Coefficient of restitution e (normal).
    pub restitution: f64,
    /// Coulomb friction coefficient μ.
    pub friction: f64,
    /// Projected Gauss–Seidel sweeps over all contacts.
    pub iterations: usize,
    /// Relaxation factor ω of the PGS update (1 = plain Gauss–Seidel).
    pub relaxation: f64,
    /// Body count from which detection uses the hash grid instead of all pairs.
    pub grid_threshold: usize,
    /// Contacts are generated for gaps below this margin (speculative contacts).
    pub contact_margin: f64,
    /// Restitution is applied only for approach speeds above this.
    pub restitution_threshold: f64,
    /// Baumgarte factor β: penetration d is removed at speed β d / dt.
    pub position_correction: f64,
}

impl Default for RigidParams {
    fn default() -> Self {
        RigidParams {
            gravity: DVec3::new(0.0, 0.0, -9.81),
            fluid_density: 0.0,
            restitution: 0.5,
            friction: 0.3,
            iterations: 20,
            relaxation: 1.0,
            grid_threshold: 128,
            contact_margin: 0.0,
            restitution_threshold: 1e-3,
            position_correction: 0.2,
        }
    }
}

/// Statistics of one sub-step.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StepStats {
    /// Number of contacts detected.
    pub contacts: usize,
    /// Solver statistics.
    pub solver: SolverStats,
}

/// One rigid-body sub-step (Algorithm 7): forces, detection, resolution, position update; see the module doc.
pub fn substep(bodies: &mut [Body], planes: &[Plane], p: &RigidParams, dt: f64) -> StepStats {
    apply_forces(bodies, p, dt);
    let contacts = detect(bodies, planes, p.contact_margin, p.grid_threshold);
    let solver = resolve(bodies, &contacts, p, dt);
    integrate_positions(bodies, dt);
    StepStats {
        contacts: contacts.len(),
        solver,
    }
}
