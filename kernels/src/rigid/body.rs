//! Plain-data rigid bodies (spheres) and planes, section 2.2 of Rettinger & Rüde 2019: each particle has
//! position X_p, orientation Q_p, translational and rotational velocity V_p, W_p and acting force/torque.

use glam::{DQuat, DVec3};

/// A rigid sphere. Plain data; the solver identifies bodies by `id`, never by slice position.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Body {
    /// Unique, stable identifier; fixes the contact order (determinism).
    pub id: u64,
    /// Centre of mass X_p.
    pub position: DVec3,
    /// Orientation Q_p (unit quaternion).
    pub orientation: DQuat,
    /// Translational velocity V_p.
    pub velocity: DVec3,
    /// Angular velocity W_p (world frame).
    pub angular_velocity: DVec3,
    /// Sphere radius.
    pub radius: f64,
    /// Particle density ρ_p.
    pub density: f64,
    /// Fixed bodies have infinite mass and are never moved.
    pub fixed: bool,
    /// External force (e.g. hydrodynamic, held constant over the sub-steps of Algorithm 1).
    pub force: DVec3,
    /// External torque (e.g. hydrodynamic).
    pub torque: DVec3,
    /// The previous step's raw hydrodynamic force (for averaging the coupling force over two steps).
    pub force_prev: DVec3,
    /// The previous step's raw hydrodynamic torque.
    pub torque_prev: DVec3,
}

impl Body {
    /// A free sphere at rest with identity orientation and no external force.
    pub fn sphere(id: u64, position: DVec3, radius: f64, density: f64) -> Self {
        Body {
            id,
            position,
            orientation: DQuat::IDENTITY,
            velocity: DVec3::ZERO,
            angular_velocity: DVec3::ZERO,
            radius,
            density,
            fixed: false,
            force: DVec3::ZERO,
            torque: DVec3::ZERO,
            force_prev: DVec3::ZERO,
            torque_prev: DVec3::ZERO,
        }
    }
    /// Volume 4/3 π r³.
    pub fn volume(&self) -> f64 {
        4.0 / 3.0 * std::f64::consts::PI * self.radius.powi(3)
    }
    /// Mass ρ_p V.
    pub fn mass(&self) -> f64 {
        self.density * self.volume()
    }
    /// Moment of inertia of a solid sphere, 2/5 m r².
    pub fn inertia(&self) -> f64 {
        0.4 * self.mass() * self.radius * self.radius
    }
    /// Inverse mass; zero for fixed bodies.
    pub fn inv_mass(&self) -> f64 {
        if self.fixed {
            0.0
        } else {
            1.0 / self.mass()
        }
    }
    /// Inverse moment of inertia; zero for fixed bodies.
    pub fn inv_inertia(&self) -> f64 {
        if self.fixed {
            0.0
        } else {
            1.0 / self.inertia()
        }
    }
    /// Kinetic energy ½ m v² + ½ I w².
    pub fn kinetic_energy(&self) -> f64 {
        0.5 * self.mass() * self.velocity.length_squared()
            + 0.5 * self.inertia() * self.angular_velocity.length_squared()
    }
    /// Velocity of the material point at world position `p`: V + W × (p − X).
    pub fn point_velocity(&self, p: DVec3) -> DVec3 {
        self.velocity + self.angular_velocity.cross(p - self.position)
    }
}

/// An infinite plane n·x = offset; bodies live on the side n points into. Box walls are planes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plane {
    /// Unit normal pointing into the free side.
    pub normal: DVec3,
    /// Offset: the plane is {x : n·x = offset}.
    pub offset: f64,
    /// Identifier, used in the contact order.
    pub id: u64,
}

impl Plane {
    /// Plane through `point` with (normalised) `normal`.
    pub fn through(id: u64, point: DVec3, normal: DVec3) -> Self {
        let n = normal.normalize();
        Plane {
            normal: n,
            offset: n.dot(point),
            id,
        }
    }
    /// Signed distance of `x` from the plane (positive on the free side).
    pub fn distance(&self, x: DVec3) -> f64 {
        self.normal.dot(x) - self.offset
    }
}
