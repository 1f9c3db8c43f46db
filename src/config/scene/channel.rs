//! The `[scene]` keys of `kind = "channel"` and their defaults; the scene itself is built in
//! `crate::scenes::channel`.

use serde::{Deserialize, Serialize};

/// `[scene]` keys of `kind = "channel"`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ChannelConfig {
    /// Channel height H in cells.
    #[serde(default = "d_res")]
    pub resolution: usize,
    /// Reynolds number u_max H / ν (kept fixed across resolutions: diffusive scaling).
    #[serde(default = "d_re")]
    pub reynolds: f64,
    /// Cells along the (periodic) flow direction x.
    #[serde(default = "d_len")]
    pub length: usize,
    /// Cells along the (periodic) z direction.
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
