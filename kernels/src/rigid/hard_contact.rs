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

/// One contact's constraint rows, with the inverse masses and inertias of both bodies cached (zero for
/// fixed bodies and planes, so the updates need no branches).
#[derive(Clone, Debug)]
pub(super) struct Row {
    pub(super) ra: DVec3,
    pub(super) rb: DVec3,
    pub(super) im_a: f64,
    pub(super) ii_a: f64,
    pub(super) im_b: f64,
    pub(super) ii_b: f64,
    pub(super) k_n: f64,
    pub(super) k_t: f64,
    pub(super) target: f64,
    pub(super) lambda_n: f64,
    pub(super) lambda_t: DVec3,
}

impl Row {
    /// One projected update of the contact's rows at relative velocity `u` (normal `normal`), with
    /// effective inverse masses `k_n` (normal) and `k_t` (tangential) and relaxation `w`; returns the
    /// changes of the normal impulse and of the tangential impulse.
    ///
    /// Normal row: λ_n ← max(0, λ_n + ω (target − u_n) / K_n). Friction rows (2-D):
    /// λ_t ← clamp_{|λ_t| ≤ μ λ_n}(λ_t − ω u_t / K_t). K_t is isotropic for spheres, and a normal impulse
    /// leaves the tangential slip unchanged (r ∥ n), so u_t is taken from the same u and both impulses
    /// are applied together.
    pub(super) fn project(
        &mut self,
        u: DVec3,
        normal: DVec3,
        k_n: f64,
        k_t: f64,
        w: f64,
        friction: f64,
    ) -> (f64, DVec3) {
        let un = u.dot(normal);
        let new_n = (self.lambda_n + w * (self.target - un) / k_n).max(0.0);
        let dn = new_n - self.lambda_n;
        self.lambda_n = new_n;
        let ut = u - normal * un;
        let mut new_t = self.lambda_t - ut * (w / k_t);
        let limit = friction * self.lambda_n;
        let len = new_t.length();
        if len > limit {
            new_t *= if len > 0.0 { limit / len } else { 0.0 };
        }
        let dt_imp = new_t - self.lambda_t;
        self.lambda_t = new_t;
        (dn, dt_imp)
    }
}

/// Translational and angular velocity of a body, the state the solver iterates on.
#[derive(Clone, Copy, Debug)]
pub(super) struct Vel {
    pub(super) v: DVec3,
    pub(super) w: DVec3,
}

pub(super) fn rel_velocity(vel: &[Vel], c: &Contact, row: &Row) -> DVec3 {
    let a = &vel[c.a];
    let mut u = a.v + a.w.cross(row.ra);
    if let Some(b) = c.b {
        let b = &vel[b];
        u -= b.v + b.w.cross(row.rb);
    }
    u
}

pub(super) fn apply(vel: &mut [Vel], c: &Contact, row: &Row, j: DVec3) {
    let a = &mut vel[c.a];
    a.v += j * row.im_a;
    a.w += row.ra.cross(j) * row.ii_a;
    if let Some(b) = c.b {
        let b = &mut vel[b];
        b.v -= j * row.im_b;
        b.w -= row.rb.cross(j) * row.ii_b;
    }
}

/// Projected Gauss–Seidel over `contacts` (in slice order), `p.iterations` sweeps with relaxation
/// `p.relaxation`; updates the velocities of `bodies` in place. See the module doc for the constraints.
pub fn resolve(bodies: &mut [Body], contacts: &[Contact], p: &RigidParams, dt: f64) -> SolverStats {
    let mut impulses = Vec::new();
    let (stats, vel) = solve(bodies, contacts, p, dt, None, &mut impulses);
    for (b, v) in bodies.iter_mut().zip(&vel) {
        if !b.fixed {
            b.velocity = v.v;
            b.angular_velocity = v.w;
        }
    }
    stats
}

/// The same solve as [`resolve`], but leaves `bodies` unchanged and returns in `impulses` the total
/// impulse of every contact (acting on body `a`; body `b` receives its negative). A caller that owns only
/// some of the contacts applies just those (the block decomposition of `blockflow`'s particles).
pub fn resolve_impulses(
    bodies: &[Body],
    contacts: &[Contact],
    p: &RigidParams,
    dt: f64,
    impulses: &mut Vec<DVec3>,
) -> SolverStats {
    solve(bodies, contacts, p, dt, None, impulses).0
}

/// A solve that continues an earlier one of the same contacts: the velocity targets it fixed (from the
/// approach speeds before any impulse of the sub-step, so restitution is not re-applied) and the total
/// impulse each contact has given so far, whose effect `bodies`' velocities already include.
#[derive(Clone, Copy, Debug)]
pub struct WarmStart<'a> {
    /// Velocity target of each contact, as [`resolve_targets`] returns them.
    pub targets: &'a [f64],
    /// Total impulse of each contact so far (on body `a`).
    pub impulses: &'a [DVec3],
}

/// The velocity target u·n ≥ target of each contact for bodies at their velocities before this sub-step's
/// impulses (restitution, speculative gap or Baumgarte term; module docs): what a [`WarmStart`] carries
/// from the first solve of a sub-step into the next ones.
pub fn resolve_targets(bodies: &[Body], contacts: &[Contact], p: &RigidParams, dt: f64) -> Vec<f64> {
    let vel = velocities(bodies);
    let inv = inverse_masses(bodies);
    contacts
        .iter()
        .map(|c| row(bodies, &vel, &inv, c, p, dt).target)
        .collect()
}

/// Projected Gauss–Seidel as [`resolve_impulses`], continued from `warm`: each contact starts from its
/// impulse so far (normal part ≥ 0, tangential part within the cone) and its fixed target, `bodies`
/// carry the velocities those impulses produced; `impulses` returns the new totals (their difference
/// from `warm.impulses` is what this solve adds).
pub fn resolve_impulses_warm(
    bodies: &[Body],
    contacts: &[Contact],
    p: &RigidParams,
    dt: f64,
    warm: WarmStart<'_>,
    impulses: &mut Vec<DVec3>,
) -> SolverStats {
    assert_eq!(warm.targets.len(), contacts.len(), "one target per contact");
    assert_eq!(warm.impulses.len(), contacts.len(), "one impulse per contact");
    solve(bodies, contacts, p, dt, Some(warm), impulses).0
}

pub(super) fn velocities(bodies: &[Body]) -> Vec<Vel> {
    bodies
        .iter()
        .map(|b| Vel {
            v: b.velocity,
            w: b.angular_velocity,
        })
        .collect()
}

pub(super) fn inverse_masses(bodies: &[Body]) -> Vec<(f64, f64)> {
    bodies.iter().map(|b| (b.inv_mass(), b.inv_inertia())).collect()
}

/// The constraint rows of contact `c` at velocities `vel`, with zero impulses.
pub(super) fn row(bodies: &[Body], vel: &[Vel], inv: &[(f64, f64)], c: &Contact, p: &RigidParams, dt: f64) -> Row {
    let a = &bodies[c.a];
    let ra = c.point - a.position;
    let (im_a, ii_a) = inv[c.a];
    // Effective inverse masses; K_t is isotropic in the tangent plane because r ∥ n for spheres.
    let mut k_n = im_a + ii_a * ra.cross(c.normal).length_squared();
    let mut k_t = im_a + ii_a * ra.length_squared();
    let (mut rb, mut im_b, mut ii_b) = (DVec3::ZERO, 0.0, 0.0);
    if let Some(b) = c.b {
        rb = c.point - bodies[b].position;
        (im_b, ii_b) = inv[b];
        k_n += im_b + ii_b * rb.cross(c.normal).length_squared();
        k_t += im_b + ii_b * rb.length_squared();
    }
    let mut row = Row {
        ra,
        rb,
        im_a,
        ii_a,
        im_b,
        ii_b,
        k_n,
        k_t,
        target: 0.0,
        lambda_n: 0.0,
        lambda_t: DVec3::ZERO,
    };
    let un0 = rel_velocity(vel, c, &row).dot(c.normal);
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
    row
}

fn solve(
    bodies: &[Body],
    contacts: &[Contact],
    p: &RigidParams,
    dt: f64,
    warm: Option<WarmStart<'_>>,
    impulses: &mut Vec<DVec3>,
) -> (SolverStats, Vec<Vel>) {
    let mut stats = SolverStats::default();
    impulses.clear();
    if contacts.is_empty() {
        return (stats, Vec::new());
    }
    let mut vel = velocities(bodies);
    let inv = inverse_masses(bodies);
    let mut rows: Vec<Row> = contacts
        .iter()
        .enumerate()
        .map(|(k, c)| {
            let mut row = row(bodies, &vel, &inv, c, p, dt);
            if let Some(w) = warm {
                row.target = w.targets[k];
                let j = w.impulses[k];
                row.lambda_n = j.dot(c.normal);
                row.lambda_t = j - c.normal * row.lambda_n;
            }
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
            let u = rel_velocity(&vel, c, row);
            let (k_n, k_t) = (row.k_n, row.k_t);
            let (dn, dt_imp) = row.project(u, c.normal, k_n, k_t, w, p.friction);
            change = change.max(dn.abs());
            apply(&mut vel, c, row, c.normal * dn + dt_imp);
            change = change.max(dt_imp.length());
        }
        stats.iterations += 1;
        stats.last_change = change;
    }
    impulses.extend(
        contacts
            .iter()
            .zip(&rows)
            .map(|(c, r)| c.normal * r.lambda_n + r.lambda_t),
    );
    (stats, vel)
}
