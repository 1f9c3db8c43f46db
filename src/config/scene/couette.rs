//! The `[scene]` keys of `kind = "couette"` and their defaults; the scene itself is built in
//! `crate::scenes::couette`.

use serde::{Deserialize, Serialize};

/// `[scene]` keys of `kind = "couette"`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CouetteConfig {
    /// Gap H in cells.
    #[serde(default = "d_res")]
    pub resolution: usize,
    /// Reynolds number U H / ν (fixed across resolutions).
    #[serde(default = "d_re")]
    pub reynolds: f64,
    /// Cells along x.
    #[serde(default = "d_len")]
    pub length: usize,
    /// Cells along z.
    #[serde(default = "d_len")]
    pub width: usize,
}

fn d_res() -> usize {
    16
}

fn d_re() -> f64 {
    10.0
}

fn d_len() -> usize {
    4
}
