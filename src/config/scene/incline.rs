//! The `[scene]` keys of `kind = "incline"` and their defaults; the scene itself is built in
//! `crate::scenes::incline`.

use serde::{Deserialize, Serialize};

/// `[scene]` keys of `kind = "incline"`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct InclineConfig {
    /// Inclination θ in degrees, in (0, 60].
    #[serde(default = "d_angle")]
    pub angle_deg: f64,
    /// Sphere diameter (cells).
    #[serde(default = "d_inc_diameter")]
    pub diameter: f64,
    /// Default step count.
    #[serde(default = "d_inc_steps")]
    pub steps: u64,
}

fn d_angle() -> f64 {
    20.0
}

fn d_inc_diameter() -> f64 {
    4.0
}

fn d_inc_steps() -> u64 {
    600
}
