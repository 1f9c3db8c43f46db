//! The `[scene]` keys of `kind = "collision"` and their defaults; the scene itself is built in
//! `crate::scenes::collision`.

use serde::{Deserialize, Serialize};

/// `[scene]` keys of `kind = "collision"`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CollisionConfig {
    /// Sphere diameter (cells).
    #[serde(default = "d_inc_diameter")]
    pub diameter: f64,
    /// Approach speed of each sphere (cells per step).
    #[serde(default = "d_speed")]
    pub speed: f64,
    /// Lateral offset of the oblique pair as a fraction of D, in [0, 1).
    #[serde(default = "d_impact")]
    pub impact_parameter: f64,
    /// Default step count.
    #[serde(default = "d_col_steps")]
    pub steps: u64,
}

fn d_speed() -> f64 {
    0.05
}

fn d_impact() -> f64 {
    0.5
}

fn d_col_steps() -> u64 {
    200
}

fn d_inc_diameter() -> f64 {
    4.0
}
