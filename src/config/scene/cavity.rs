//! The `[scene]` keys of `kind = "cavity"` and their defaults; the scene itself is built in
//! `crate::scenes::cavity`.

use serde::{Deserialize, Serialize};

/// `[scene]` keys of `kind = "cavity"`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CavityConfig {
    /// Edge length N in cells.
    #[serde(default = "d_res")]
    pub resolution: usize,
    /// Reynolds number U N / ν (100 to 1000 are the classic cases).
    #[serde(default = "d_re")]
    pub reynolds: f64,
    /// Lid velocity U (lattice units; the Mach number is U √3).
    #[serde(default = "d_lid")]
    pub lid_velocity: f64,
    /// Run length in lid turnovers N / U.
    #[serde(default = "d_turn")]
    pub turnovers: f64,
}

fn d_res() -> usize {
    32
}

fn d_re() -> f64 {
    100.0
}

fn d_lid() -> f64 {
    0.1
}

fn d_turn() -> f64 {
    10.0
}
