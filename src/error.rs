//! Errors a user can cause, each a one-line message naming the key, file, block or cell concerned.

use std::fmt;

/// Where an unstable run was caught and what the cell held (DESIGN.md principle 5).
#[derive(Clone, Debug, PartialEq)]
pub struct Instability {
    /// Step at which the detector fired (1-based: the state after this many steps).
    pub step: u64,
    /// Block id.
    pub block: usize,
    /// Block coordinates in the block grid.
    pub block_coords: [usize; 3],
    /// Global cell coordinates (0-based, interior cells).
    pub cell: [usize; 3],
    /// Density ρ = 1 + δρ of that cell.
    pub density: f64,
    /// Velocity of that cell.
    pub velocity: [f64; 3],
    /// The velocity limit in force (`fluid.velocity_limit`).
    pub limit: f64,
}

impl fmt::Display for Instability {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let [x, y, z] = self.cell;
        let [bx, by, bz] = self.block_coords;
        let u = self.velocity;
        let what = if self.density.is_finite() && u.iter().all(|v| v.is_finite()) {
            format!("|u| above fluid.velocity_limit = {}", self.limit)
        } else {
            "a non-finite value".to_string()
        };
        write!(
            f,
            "unstable at step {}: {what} in block {} ({bx},{by},{bz}), cell ({x},{y},{z}): density {:.6e}, \
             velocity ({:.6e}, {:.6e}, {:.6e}); lower the velocity (Mach number), raise fluid.tau or refine \
             scene.resolution",
            self.step, self.block, self.density, u[0], u[1], u[2]
        )
    }
}

/// Everything that stops a run.
#[derive(Debug)]
pub enum Error {
    /// Bad configuration, command-line value or impossible geometry. The message names the key.
    Config(String),
    /// A file could not be read or written. The message names the file.
    Io(String),
    /// The run became unstable.
    Unstable(Instability),
    /// The rigid bodies left what the solver can follow (a body moved too far in one sub-step, or out of
    /// the blocks that had tasks). The message names the body, block and step.
    ParticlesUnstable(String),
    /// A checkpoint could not be used for a restart (unreadable, not a checkpoint, another format version,
    /// truncated, corrupt, or from another scene). The message names the file and the reason.
    Checkpoint(String),
    /// Another rank of the group failed and ended the run: its index, exit code and one-line message
    /// (which that rank reports; the others exit with the same code).
    Aborted {
        /// The rank that failed.
        rank: usize,
        /// Its exit code.
        code: i32,
        /// Its message.
        message: String,
    },
    /// SIGINT or SIGTERM stopped the run after `step` steps; a checkpoint of that step was written
    /// (summary.json says `"status": "interrupted"`).
    Interrupted {
        /// The signal (2 = SIGINT, 15 = SIGTERM).
        signal: i32,
        /// Steps completed.
        step: u64,
        /// The checkpoint written at `step`, if one could be.
        checkpoint: Option<String>,
    },
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Error::Config(m) | Error::Io(m) => f.write_str(m),
            Error::Unstable(i) => i.fmt(f),
            Error::ParticlesUnstable(m) | Error::Checkpoint(m) => f.write_str(m),
            Error::Aborted { rank, message, .. } => write!(f, "rank {rank}: {message}"),
            Error::Interrupted {
                signal,
                step,
                checkpoint,
            } => {
                write!(f, "interrupted by {} at step {step}", signal_name(*signal))?;
                match checkpoint {
                    Some(c) => write!(
                        f,
                        "; checkpoint {c} written, continue with `blockflow run --restart {c}`"
                    ),
                    None => f.write_str("; no checkpoint written"),
                }
            }
        }
    }
}

impl std::error::Error for Error {}

impl Error {
    /// Process exit code: 1 for configuration and I/O errors (2 is clap's, for a bad command line), 3 for
    /// an unstable run, 4 for a checkpoint that cannot be restarted from, 128 + the signal number for a
    /// run stopped by a signal (130 for SIGINT, 143 for SIGTERM, as shells report them).
    pub fn exit_code(&self) -> i32 {
        match self {
            Error::Config(_) | Error::Io(_) => 1,
            Error::Unstable(_) | Error::ParticlesUnstable(_) => 3,
            Error::Checkpoint(_) => 4,
            Error::Aborted { code, .. } => *code,
            Error::Interrupted { signal, .. } => 128 + signal,
        }
    }

    /// The message as one line: control characters that reached it from user input (a `--set` value
    /// or a file name with a line break) are written as escapes (`\n`, `\t`, `\u{1b}`).
    pub fn one_line(&self) -> String {
        escape_controls(&self.to_string())
    }
}

/// `s` with each control character written as its Rust escape, everything else as it is.
pub fn escape_controls(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        if c.is_control() {
            out.extend(c.escape_default());
        } else {
            out.push(c);
        }
    }
    out
}

/// Name of a signal number for messages (`SIGINT`, `SIGTERM`, `SIGUSR1`, else `signal N`).
pub fn signal_name(sig: i32) -> String {
    match sig {
        libc::SIGINT => "SIGINT".into(),
        libc::SIGTERM => "SIGTERM".into(),
        libc::SIGUSR1 => "SIGUSR1".into(),
        s => format!("signal {s}"),
    }
}

/// Shorthand for a configuration error.
pub fn config_err<T>(msg: impl Into<String>) -> Result<T> {
    Err(Error::Config(msg.into()))
}

/// An I/O error that names the path.
pub fn io_err(path: &std::path::Path, e: std::io::Error) -> Error {
    Error::Io(format!("{}: {e}", path.display()))
}

/// Result with [`Error`].
pub type Result<T> = std::result::Result<T, Error>;

#[cfg(test)]
mod tests {
    use super::*;

    /// A message with a line break, a tab and an escape character prints as one line; others unchanged.
    #[test]
    fn messages_print_as_one_line() {
        let e = Error::Config("--set fluid.tau=0.7\n[scene]\tx\u{1b}".into());
        assert_eq!(e.one_line(), "--set fluid.tau=0.7\\n[scene]\\tx\\u{1b}");
        assert!(!e.one_line().contains('\n'));
        let plain = "scene.kind = \"boxx\": unknown scene; one of channel, … (é)";
        assert_eq!(escape_controls(plain), plain);
    }
}
