//! `series.csv`: the time series of global diagnostics (step, time, mass, kinetic energy, max |u|), and
//! `particles.csv`: the rigid bodies' (step, time, bodies, kinetic energy, max speed, contacts, max penetration).

use crate::error::{io_err, Result};
use crate::physics::simulation::Diagnostics;
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
    pub fn flush(&mut self) -> Result<()> {
        self.w.flush().map_err(|e| io_err(&self.path, e))
    }
}

/// One row of `particles.csv`.
#[derive(Clone, Copy, Debug, Default)]
pub struct ParticleRow {
    /// Step.
    pub step: u64,
    /// Time (step × particles.dt).
    pub time: f64,
    /// Number of bodies.
    pub bodies: usize,
    /// Σ ½ m v² + ½ I w².
    pub kinetic_energy: f64,
    /// Largest speed.
    pub max_speed: f64,
    /// Contacts of the last sub-step (over all blocks).
    pub contacts: usize,
    /// Largest penetration among them.
    pub max_penetration: f64,
}

/// An open `particles.csv`.
pub struct ParticleSeries {
    path: PathBuf,
    w: BufWriter<File>,
}

impl ParticleSeries {
    /// Creates `path` and writes the header.
    pub fn create(path: &Path) -> Result<Self> {
        let f = File::create(path).map_err(|e| io_err(path, e))?;
        let mut w = BufWriter::new(f);
        writeln!(w, "step,time,bodies,kinetic_energy,max_speed,contacts,max_penetration")
            .map_err(|e| io_err(path, e))?;
        Ok(ParticleSeries {
            path: path.to_path_buf(),
            w,
        })
    }

    /// Appends one row.
    pub fn push(&mut self, r: &ParticleRow) -> Result<()> {
        writeln!(
            self.w,
            "{},{:.17e},{},{:.17e},{:.17e},{},{:.17e}",
            r.step, r.time, r.bodies, r.kinetic_energy, r.max_speed, r.contacts, r.max_penetration
        )
        .map_err(|e| io_err(&self.path, e))
    }

    /// Flushes to disk.
    pub fn flush(&mut self) -> Result<()> {
        self.w.flush().map_err(|e| io_err(&self.path, e))
    }
}
