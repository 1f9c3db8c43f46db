//! The `blockflow` binary: parses the command line and reports errors as one line with a non-zero exit.

use clap::Parser;

fn main() {
    let cli = blockflow::cli::Cli::parse();
    if let Err(e) = blockflow::cli::execute(cli) {
        eprintln!("error: {e}");
        std::process::exit(e.exit_code());
    }
}
