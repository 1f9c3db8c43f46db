//! The `[scene]` keys of `kind = "granular_box"` and their defaults; the scene itself is built in
//! `crate::scenes::granular_box`.

use serde::{Deserialize, Serialize};

/// `[scene]` keys of `kind = "granular_box"`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct GranularBoxConfig {
    /// Number of spheres.
    #[serde(default = "d_count")]
    pub count: usize,
    /// Sphere diameter D (cells).
    #[serde(default = "d_diameter")]
    pub diameter: f64,
    /// Box size (cells).
    #[serde(default = "d_size")]
    pub size: [usize; 3],
    /// Height of the lowest sphere centres at the start (cells).
    #[serde(default = "d_fill_from")]
    pub fill_from: f64,
    /// Particle density.
    #[serde(default = "one")]
    pub density: f64,
    /// Largest initial speed per axis (random, deterministic).
    #[serde(default = "d_jitter_speed")]
    pub initial_speed: f64,
    /// Seed of the deterministic initial jitter.
    #[serde(default = "one_u")]
    pub seed: u64,
    /// Default step count.
    #[serde(default = "d_gb_steps")]
    pub steps: u64,
}

fn d_count() -> usize {
    500
}

fn d_diameter() -> f64 {
    3.5
}

fn d_size() -> [usize; 3] {
    [32, 32, 64]
}

fn d_fill_from() -> f64 {
    12.0
}

fn one() -> f64 {
    1.0
}

fn one_u() -> u64 {
    1
}

fn d_jitter_speed() -> f64 {
    0.02
}

fn d_gb_steps() -> u64 {
    1500
}
