//! The `[scene]` keys of `kind = "calibration"` and their defaults; the scene itself is built in
//! `crate::scenes::calibration`.

use serde::{Deserialize, Serialize};

fn d_galileo() -> f64 {
    30.0
}

/// `[scene]` keys of `kind = "calibration"` (section 3.3, Figure 5): spheres at random positions in a
/// horizontally periodic box of 4 × 4 × 5 blocks whose top wall sits `top_offset` block sizes below the
/// top of the block grid, settling onto the bottom for 2.5 T with T = L_z / u_s.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationConfig {
    /// Sphere diameter D in cells.
    #[serde(default = "d_cal_d")]
    pub diameter: f64,
    /// Global solid volume fraction.
    #[serde(default = "d_cal_phi")]
    pub solid_fraction: f64,
    /// Galileo number Ga = u_s D / ν with u_s = sqrt((ρp/ρf − 1) g D).
    #[serde(default = "d_galileo")]
    pub galileo: f64,
    /// Density ratio ρp / ρf.
    #[serde(default = "d_cal_ratio")]
    pub density_ratio: f64,
    /// Offset of the top wall below the block grid, in block sizes.
    #[serde(default = "d_cal_offset")]
    pub top_offset: f64,
    /// Characteristic speed u_s in lattice units (sets ν = u_s D / Ga unless `fluid.tau` is given).
    #[serde(default = "d_cal_us")]
    pub settling_speed: f64,
    /// Duration in units of T = L_z / u_s.
    #[serde(default = "d_cal_duration")]
    pub duration: f64,
    /// Seed of the random positions.
    #[serde(default = "super::default_seed")]
    pub seed: u64,
}

fn d_cal_d() -> f64 {
    5.0
}

fn d_cal_phi() -> f64 {
    0.2
}

fn d_cal_ratio() -> f64 {
    2.5
}

fn d_cal_offset() -> f64 {
    1.05
}

fn d_cal_us() -> f64 {
    0.05
}

fn d_cal_duration() -> f64 {
    2.5
}
