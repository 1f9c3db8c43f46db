//! `[run]`: run length, output, checkpoints and the skip rules' measurement switch.

use crate::error::{config_err, Result};
use serde::{Deserialize, Serialize};

/// `[run]`: run length, output and checkpoints.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RunConfig {
    /// Number of time steps; absent: the scene's own (e.g. to steady state).
    pub steps: Option<u64>,
    /// Output folder; absent: `out/<scene file name>`.
    pub out: Option<String>,
    /// Write a row of `series.csv` every this many steps (default: about 100 rows per run, at least every 10 steps).
    pub series_every: Option<u64>,
    /// Write VTK output every this many steps (default: never).
    pub vtk_every: Option<u64>,
    /// How the VTK files store their binary arrays: "raw" (appended raw bytes, the smallest and
    /// fastest; ParaView and VTK read it) or "base64" (appended base64 text, a third larger, but the
    /// files are well-formed XML that any XML-based reader parses, e.g. meshio, vtk.js, vtkio).
    #[serde(default)]
    pub vtk_encoding: VtkEncoding,
    /// Draw a picture of one plane of the flow every this many steps (`OUT/slices/step-<step>.png`, and
    /// `OUT/slices.gif` of them all; `--png`; default: never).
    pub png_every: Option<u64>,
    /// The axis normal to the pictured plane: "x", "y" or "z" (default: the thinnest axis where it has
    /// less than half the cells of the longest, as in a channel or a 2D scene, else "y", a vertical
    /// plane for gravity along z).
    pub png_normal: Option<String>,
    /// The plane's cell index along `png_normal` (default: the middle of the domain).
    pub png_at: Option<usize>,
    /// Write a checkpoint (`OUT/checkpoints/step-<step>`) whenever the step is a multiple of this
    /// (default: never; `--checkpoint-every`).
    pub checkpoint_every: Option<u64>,
    /// Write a checkpoint when this many wall-clock seconds have passed since the last one (default:
    /// never; `--checkpoint-wall`).
    pub checkpoint_wall: Option<f64>,
    /// Checkpoints kept: after each write all but the newest this many are deleted (default 2).
    #[serde(default = "d_checkpoints_kept")]
    pub checkpoints_kept: usize,
    /// Run every task on every block (`--no-skip`; default false): switches off the skip rules of
    /// DESIGN.md principle 2 (outside blocks, blocks without boundary cells, blocks without particles,
    /// static geometry mapped once, the fused kernel) to measure what they save. For measurement only:
    /// slower, and the results are bitwise the same. See the skip rules in `pipeline`.
    #[serde(default)]
    pub no_skip: bool,
}

/// How VTK XML files store their binary arrays (`run.vtk_encoding`).
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum VtkEncoding {
    /// `<AppendedData encoding="raw">`: the arrays' bytes as they are (default).
    #[default]
    Raw,
    /// `<AppendedData encoding="base64">`: each array with its byte-count header as base64 text.
    Base64,
}

impl VtkEncoding {
    /// The config word, also the `encoding` attribute of `<AppendedData>` (`"raw"` or `"base64"`).
    pub fn name(self) -> &'static str {
        match self {
            VtkEncoding::Raw => "raw",
            VtkEncoding::Base64 => "base64",
        }
    }
}

fn d_checkpoints_kept() -> usize {
    DEFAULT_KEPT
}

impl Default for RunConfig {
    fn default() -> Self {
        RunConfig {
            steps: None,
            out: None,
            series_every: None,
            vtk_every: None,
            vtk_encoding: VtkEncoding::default(),
            png_every: None,
            png_normal: None,
            png_at: None,
            checkpoint_every: None,
            checkpoint_wall: None,
            checkpoints_kept: d_checkpoints_kept(),
            no_skip: false,
        }
    }
}

/// Default of `run.checkpoints_kept`.
pub const DEFAULT_KEPT: usize = 2;

impl RunConfig {
    /// Checks the keys' ranges; the message names the key.
    pub fn validate(&self) -> Result<()> {
        for (name, v) in [
            ("run.series_every", self.series_every),
            ("run.vtk_every", self.vtk_every),
            ("run.png_every", self.png_every),
        ] {
            if v == Some(0) {
                return config_err(format!("{name} = 0: must be at least 1 (leave it out to disable)"));
            }
        }
        if let Some(n) = &self.png_normal {
            if !matches!(n.as_str(), "x" | "y" | "z") {
                return config_err(format!("run.png_normal = {n:?}: must be \"x\", \"y\" or \"z\""));
            }
        }
        if self.checkpoint_every == Some(0) {
            return config_err("run.checkpoint_every = 0: must be at least 1 step (leave it out to disable)");
        }
        if let Some(w) = self.checkpoint_wall {
            if !(w.is_finite() && w > 0.0) {
                return config_err(format!(
                    "run.checkpoint_wall = {w}: must be a finite number of seconds > 0 (leave it out to disable)"
                ));
            }
        }
        if self.checkpoints_kept == 0 || self.checkpoints_kept > 1_000_000 {
            return config_err(format!(
                "run.checkpoints_kept = {}: must be between 1 and 1000000",
                self.checkpoints_kept
            ));
        }
        Ok(())
    }
}
