//! Semi-implicit Euler time integration (section 2.2, line 10 of Algorithm 7): velocities first from the
//! acting forces, then positions and orientations with the new velocities.

use super::{Body, RigidParams};
use glam::DQuat;

/// Velocity half of semi-implicit Euler: v += dt (F_ext + g (m − ρ_f V)) / m, w += dt T / I.
/// Fixed bodies are left untouched.
pub fn apply_forces(bodies: &mut [Body], p: &RigidParams, dt: f64) {
    for b in bodies.iter_mut().filter(|b| !b.fixed) {
        let m = b.mass();
        let f = b.force + p.gravity * (m - p.fluid_density * b.volume());
        b.velocity += dt * f / m;
        b.angular_velocity += dt * b.torque / b.inertia();
    }
}

/// Position half: x += dt v, q ← normalize(q + ½ dt (w, 0) q).
pub fn integrate_positions(bodies: &mut [Body], dt: f64) {
    for b in bodies.iter_mut().filter(|b| !b.fixed) {
        b.position += dt * b.velocity;
        let w = b.angular_velocity;
        let dq = DQuat::from_xyzw(w.x, w.y, w.z, 0.0) * b.orientation;
        b.orientation = (b.orientation + dq * (0.5 * dt)).normalize();
    }
}

/// Full semi-implicit Euler step without contacts: [`apply_forces`] then [`integrate_positions`].
pub fn integrate(bodies: &mut [Body], p: &RigidParams, dt: f64) {
    apply_forces(bodies, p, dt);
    integrate_positions(bodies, dt);
}
