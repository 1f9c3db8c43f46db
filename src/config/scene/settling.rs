//! The `[scene]` keys of `kind = "settling_sphere"` and their defaults; the scene itself is built in
//! `crate::scenes::settling`.

use serde::{Deserialize, Serialize};

/// The experiment's sphere diameter, m.
pub const TEN_CATE_DIAMETER: f64 = 0.015;

/// The experiment's container (x, y, z), m.
pub const TEN_CATE_BOX: [f64; 3] = [0.1, 0.1, 0.16];

/// Start height of the centre above the bottom, m: the experiment's plotted trajectories begin with a gap
/// of about 120 mm under the sphere.
pub const TEN_CATE_START: f64 = 0.1275;

/// `[scene]` keys of `kind = "settling_sphere"`, in SI units.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SettlingSphereConfig {
    /// Cells per sphere diameter.
    #[serde(default = "d_res")]
    pub resolution: f64,
    /// A case of ten Cate et al. (2002), `"E1"` … `"E4"`: sets `fluid_density` and `fluid_viscosity` where
    /// they are not given, and the measured peak speed the run is compared with (reported only while the
    /// set-up is the experiment's: fluid, sphere, box and gravity).
    pub case: Option<String>,
    /// Fluid density ρ_f, kg/m³.
    pub fluid_density: Option<f64>,
    /// Dynamic viscosity μ_f, Pa s.
    pub fluid_viscosity: Option<f64>,
    /// Sphere density ρ_p, kg/m³ (default: the experiment's 1120).
    pub particle_density: Option<f64>,
    /// Density ratio ρ_p / ρ_f instead of `particle_density` (for stress maps down to 1).
    pub density_ratio: Option<f64>,
    /// Sphere diameter D, m.
    #[serde(default = "d_diameter")]
    pub diameter: f64,
    /// Closed box [L_x, L_y, L_z], m.
    #[serde(default = "d_box")]
    pub r#box: [f64; 3],
    /// Start height of the sphere centre above the bottom, m (centred in x and y).
    #[serde(default = "d_start")]
    pub start_height: f64,
    /// Gravitational acceleration, m/s² (default 9.81).
    pub gravity: Option<f64>,
    /// Galileo number Ga = √((ρ_p/ρ_f − 1) g D³) / ν instead of `gravity` (sets g).
    pub galileo: Option<f64>,
    /// Mach number of the estimated terminal speed, which sets dt when `fluid.tau` is absent.
    #[serde(default = "d_mach")]
    pub mach: f64,
    /// Simulated time, s; absent: long enough to reach the bottom at the estimated speed.
    pub duration: Option<f64>,
}

fn d_res() -> f64 {
    8.0
}

fn d_diameter() -> f64 {
    TEN_CATE_DIAMETER
}

fn d_box() -> [f64; 3] {
    TEN_CATE_BOX
}

fn d_start() -> f64 {
    TEN_CATE_START
}

fn d_mach() -> f64 {
    0.1
}
