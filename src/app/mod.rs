//! The commands: the command line ([`cli`]) and one module per command (`run`, `topology`, `calibrate`,
//! `study`, `sweep` in [`scan`], `stress`, `bench`). Each parses its arguments, drives runs through the
//! time loop and prints its result; nothing in the engine imports this layer.

pub mod bench;
pub mod calibrate;
pub mod cli;
pub mod mpi;
pub mod run;
pub mod scan;
pub mod signals;
pub mod stress;
pub mod study;
pub mod topology;

use crate::error::Result;
use cli::{Cli, Command};

/// Executes a parsed command line.
pub fn execute(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Run(a) => run::execute(a),
        Command::Topology(a) => topology::execute(a),
        Command::Calibrate(a) => calibrate::execute(a),
        Command::Study(a) => study::execute(a),
        Command::Sweep(a) => scan::execute(a),
        Command::Stress(a) => stress::execute(a),
        Command::Bench { which } => bench::execute(which),
    }
}

/// Writes to stdout, ignoring a closed pipe (`blockflow run ... | head` must not panic).
pub fn print_out(text: &str) {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    let _ = out.write_all(text.as_bytes()).and_then(|_| out.flush());
}
