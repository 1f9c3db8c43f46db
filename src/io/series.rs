//! `series.csv`: the time series of global diagnostics (step, time, mass, kinetic energy, max |u|).

use crate::error::{io_err, Result};
use crate::sim::Diagnostics;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// An open CSV time series.
pub struct Series {
    path: PathBuf,
    w: BufWriter<File>,
}

impl Series {
    /// Creates `path` and writes the header.
    pub fn create(path: &Path) -> Result<Self> {
        let f = File::create(path).map_err(|e| io_err(path, e))?;
        let mut s = Series {
            path: path.to_path_buf(),
            w: BufWriter::new(f),
        };
        s.line("step,time,mass,mass_deviation,kinetic_energy,max_velocity")?;
        Ok(s)
    }

    fn line(&mut self, l: &str) -> Result<()> {
        writeln!(self.w, "{l}").map_err(|e| io_err(&self.path, e))
    }

    /// Appends the diagnostics of one step (time = step in lattice units).
    pub fn push(&mut self, step: u64, d: &Diagnostics) -> Result<()> {
        self.line(&format!(
            "{step},{step},{:.17e},{:.17e},{:.17e},{:.17e}",
            d.mass, d.mass_deviation, d.kinetic_energy, d.max_velocity
        ))
    }

    /// Flushes to disk.
    pub fn finish(mut self) -> Result<()> {
        self.w.flush().map_err(|e| io_err(&self.path, e))
    }
}
