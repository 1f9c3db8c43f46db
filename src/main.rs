//! The `blockflow` binary: parses the command line and reports errors as one line with a non-zero exit.

use clap::Parser;

fn main() {
    // The allowed cores are read once here, on the un-pinned main thread (core_affinity reports the
    // calling thread's mask).
    blockflow_scheduler::topology::init_allowed_cores();
    let cli = blockflow::cli::Cli::parse();
    if let Err(e) = blockflow::cli::execute(cli) {
        eprintln!("error: {e}");
        std::process::exit(e.exit_code());
    }
}
