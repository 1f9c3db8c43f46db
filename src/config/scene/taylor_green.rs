//! The `[scene]` keys of `kind = "taylor_green"` and their defaults; the scene itself is built in
//! `crate::scenes::taylor_green`.

use serde::{Deserialize, Serialize};

/// `[scene]` keys of `kind = "taylor_green"`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct TaylorGreenConfig {
    /// Period N in cells (box N × N × depth).
    #[serde(default = "d_res")]
    pub resolution: usize,
    /// Reynolds number U0 N / ν.
    #[serde(default = "d_re")]
    pub reynolds: f64,
    /// Final time in units of the amplitude's decay time 1/(2νk²).
    #[serde(default = "d_time")]
    pub time: f64,
    /// Cells along z; absent: N.
    pub depth: Option<usize>,
}

fn d_res() -> usize {
    32
}

fn d_re() -> f64 {
    10.0
}

fn d_time() -> f64 {
    1.0
}
