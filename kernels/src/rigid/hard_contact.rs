//! Hard-contact resolution with Coulomb friction (lines 6–8 of Algorithm 7; inelastic hard contacts after
//! Preclik & Rüde, ref. [35] of Rettinger & Rüde 2019), solved at velocity level by projected Gauss–Seidel.
//!
//! Per contact with normal n (from b to a) and relative velocity u = (V_a + W_a × r_a) − (V_b + W_b × r_b):
//! - non-penetration: normal impulse λ_n ≥ 0 with u·n ≥ target, where the target is
//!   −e u_n⁰ if the bodies approach faster than `restitution_threshold` and touch within this step
//!   (restitution), else −gap/dt for a separated (speculative) contact, else β·depth/dt (Baumgarte);
//! - Coulomb cone: the 2-D tangential impulse λ_t drives the tangential slip to zero, clamped to |λ_t| ≤ μ λ_n.
//!
//! Impulses act on linear and angular velocity (r × λ); fixed bodies and planes have infinite mass. Each sweep
//! visits the contacts in the order of the slice, which [`super::detect`] sorts by body ids: results do not
//! depend on the order of the body slice.

use super::{Body, Contact, RigidParams};
use glam::DVec3;

/// Statistics of one call to [`resolve`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SolverStats {
    /// Sweeps performed.
    pub iterations: usize,
    /// Largest impulse change in the last sweep (convergence indicator).
    pub last_change: f64,
    /// Largest penetration depth among the contacts (before resolution).
    pub max_penetration: f64,
}

struct Row {
    ra: DVec3,
    rb: DVec3,
    k_n: f64,
    k_t: f64,
    target: f64,
    lambda_n: f64,
    lambda_t: DVec3,
}

fn rel_velocity(bodies: &[Body], c: &Contact, row: &Row) -> DVec3 {
    let a = &bodies[c.a];
    let mut u = a.velocity + a.angular_velocity.cross(row.ra);
    if let Some(b) = c.b {
        let b = &bodies[b];
        u -= b.velocity + b.angular_velocity.cross(row.rb);
    }
    u
}

fn apply(bodies: &mut [Body], c: &Contact, row: &Row, j: DVec3) {
    let a = &mut bodies[c.a];
    if !a.fixed {
        a.velocity += j * a.inv_mass();
        a.angular_velocity += row.ra.cross(j) * a.inv_inertia();
    }
    if let Some(b) = c.b {
        let b = &mut bodies[b];
        if !b.fixed {
            b.velocity -= j * b.inv_mass();
            b.angular_velocity -= row.rb.cross(j) * b.inv_inertia();
        }
    }
}

/// Projected Gauss–Seidel over `contacts` (in slice order), `p.iterations` sweeps with relaxation
/// `p.relaxation`; updates the velocities of `bodies` in place. See the module doc for the constraints.
pub fn resolve(bodies: &mut [Body], contacts: &[Contact], p: &RigidParams, dt: f64) -> SolverStats {
    let mut stats = SolverStats::default();
    let mut rows: Vec<Row> = contacts
        .iter()
        .map(|c| {
            let a = &bodies[c.a];
            let ra = c.point - a.position;
            // Effective inverse masses; K_t is isotropic in the tangent plane because r ∥ n for spheres.
            let mut k_n = a.inv_mass() + a.inv_inertia() * ra.cross(c.normal).length_squared();
            let mut k_t = a.inv_mass() + a.inv_inertia() * ra.length_squared();
            let mut rb = DVec3::ZERO;
            if let Some(b) = c.b {
                let b = &bodies[b];
                rb = c.point - b.position;
                k_n += b.inv_mass() + b.inv_inertia() * rb.cross(c.normal).length_squared();
                k_t += b.inv_mass() + b.inv_inertia() * rb.length_squared();
            }
            let mut row = Row {
                ra,
                rb,
                k_n,
                k_t,
                target: 0.0,
                lambda_n: 0.0,
                lambda_t: DVec3::ZERO,
            };
            let un0 = rel_velocity(bodies, c, &row).dot(c.normal);
            let bias = if c.depth > 0.0 {
                p.position_correction * c.depth / dt
            } else {
                c.depth / dt
            };
            // Restitution if approaching fast and touching within this step (gap + u_n dt ≤ 0).
            row.target = if un0 < -p.restitution_threshold && un0 * dt <= c.depth {
                (-p.restitution * un0).max(bias)
            } else {
                bias
            };
            stats.max_penetration = stats.max_penetration.max(c.depth);
            row
        })
        .collect();
    let w = p.relaxation;
    for _ in 0..p.iterations {
        let mut change: f64 = 0.0;
        for (c, row) in contacts.iter().zip(rows.iter_mut()) {
            if row.k_n <= 0.0 {
                continue;
            }
            // Normal row: λ_n ← max(0, λ_n + ω (target − u_n) / K_n).
            let un = rel_velocity(bodies, c, row).dot(c.normal);
            let new_n = (row.lambda_n + w * (row.target - un) / row.k_n).max(0.0);
            let dn = new_n - row.lambda_n;
            row.lambda_n = new_n;
            apply(bodies, c, row, c.normal * dn);
            change = change.max(dn.abs());
            // Friction rows (2-D): λ_t ← clamp_{|λ_t| ≤ μ λ_n}(λ_t − ω u_t / K_t). K_t is isotropic for spheres.
            let u = rel_velocity(bodies, c, row);
            let ut = u - c.normal * u.dot(c.normal);
            let mut new_t = row.lambda_t - ut * (w / row.k_t);
            let limit = p.friction * row.lambda_n;
            let len = new_t.length();
            if len > limit {
                new_t *= if len > 0.0 { limit / len } else { 0.0 };
            }
            let dt_imp = new_t - row.lambda_t;
            row.lambda_t = new_t;
            apply(bodies, c, row, dt_imp);
            change = change.max(dt_imp.length());
        }
        stats.iterations += 1;
        stats.last_change = change;
    }
    stats
}
