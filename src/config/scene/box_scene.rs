//! The `[scene]` keys of `kind = "box"` and their defaults; the scene itself is built in
//! `crate::scenes::box_scene`.

use serde::{Deserialize, Serialize};

/// One plane of `scene.planes`: cells whose centre lies on the side opposite to `normal` are solid.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PlaneConfig {
    /// A point on the plane (cells, global coordinates).
    pub point: [f64; 3],
    /// Normal pointing into the fluid (any length > 0).
    pub normal: [f64; 3],
    /// Tangential wall velocity (lattice units).
    #[serde(default)]
    pub velocity: [f64; 3],
}

/// One sphere of `scene.spheres`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SphereConfig {
    /// Centre (cells, global coordinates).
    pub centre: [f64; 3],
    /// Radius (cells).
    pub radius: f64,
    /// Density relative to the fluid.
    #[serde(default = "one")]
    pub density: f64,
    /// Initial velocity (lattice units).
    #[serde(default)]
    pub velocity: [f64; 3],
    /// Initial angular velocity.
    #[serde(default)]
    pub angular_velocity: [f64; 3],
    /// A fixed sphere never moves.
    #[serde(default)]
    pub fixed: bool,
}

fn one() -> f64 {
    1.0
}

/// `[scene]` keys of `kind = "box"`.
#[derive(Clone, Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct BoxConfig {
    /// Uniform body force (lattice units).
    #[serde(default)]
    pub force: [f64; 3],
    /// Uniform initial velocity (lattice units).
    #[serde(default)]
    pub velocity: [f64; 3],
    /// Planes cutting the box.
    #[serde(default)]
    pub planes: Vec<PlaneConfig>,
    /// Spheres coupled to the fluid (ids in list order); walls and planes are also rigid planes for them.
    #[serde(default)]
    pub spheres: Vec<SphereConfig>,
    /// Gravity on the spheres (lattice units); `particles.gravity` overrides.
    #[serde(default)]
    pub gravity: [f64; 3],
    /// Default step count when `run.steps` is absent.
    #[serde(default = "d_steps")]
    pub steps: u64,
}

fn d_steps() -> u64 {
    100
}
