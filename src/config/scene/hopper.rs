//! The `[scene]` keys of `kind = "hopper"` and their defaults; the scene itself is built in
//! `crate::scenes::hopper`.

use serde::{Deserialize, Serialize};

fn d_density_ratio() -> f64 {
    1.5
}

/// `[scene]` keys of `kind = "hopper"` (section 4.3): spheres densely packed under the lid settle through
/// four inclined planes that narrow the horizontal cross-section toward the bottom.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct HopperConfig {
    /// Sphere diameter D in cells.
    #[serde(default = "d_hopper_d")]
    pub diameter: f64,
    /// Number of spheres.
    #[serde(default = "d_hopper_count")]
    pub count: usize,
    /// Galileo number (sets the gravity).
    #[serde(default = "d_hopper_ga")]
    pub galileo: f64,
    /// Density ratio ρp / ρf.
    #[serde(default = "d_density_ratio")]
    pub density_ratio: f64,
    /// Share by which the four planes reduce the horizontal cross-section at the bottom.
    #[serde(default = "d_narrowing")]
    pub narrowing: f64,
    /// Height of the funnel (where the planes meet the side walls) as a fraction of the box height.
    #[serde(default = "d_funnel")]
    pub funnel_height: f64,
    /// Seed of the initial jitter.
    #[serde(default = "super::default_seed")]
    pub seed: u64,
    /// Default step count.
    #[serde(default = "d_hopper_steps")]
    pub steps: u64,
}

fn d_hopper_d() -> f64 {
    7.5
}

fn d_hopper_count() -> usize {
    540
}

fn d_hopper_ga() -> f64 {
    50.0
}

fn d_narrowing() -> f64 {
    0.6
}

fn d_funnel() -> f64 {
    0.4
}

fn d_hopper_steps() -> u64 {
    4000
}
