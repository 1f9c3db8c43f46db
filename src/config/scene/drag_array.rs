//! The `[scene]` keys of `kind = "drag_array"` and their defaults; the scene itself is built in
//! `crate::scenes::drag_array`.

use serde::{Deserialize, Serialize};

/// `[scene]` keys of `kind = "drag_array"`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct DragArrayConfig {
    /// Sphere diameter D in cells.
    #[serde(default = "d_res")]
    pub resolution: f64,
    /// Solid volume fraction φ of the array, in (0, 0.5].
    #[serde(default = "d_phi")]
    pub solid_fraction: f64,
    /// Particle Reynolds number U D / ν the body force aims at (Stokes regime: keep it small).
    #[serde(default = "d_re")]
    pub reynolds: f64,
    /// Steps; absent: L² / ν (the viscous time of the cube: the drag has settled to about 1e-5 by then).
    pub steps: Option<u64>,
}

fn d_res() -> f64 {
    16.0
}

fn d_phi() -> f64 {
    0.125
}

fn d_re() -> f64 {
    0.01
}
