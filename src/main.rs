//! The `blockflow` binary: parses the command line and reports errors as one line with a non-zero exit.

use clap::Parser;

fn main() {
    // The allowed cores are read once here, on the un-pinned main thread (core_affinity reports the
    // calling thread's mask).
    blockflow_scheduler::topology::init_allowed_cores();
    let cli = match blockflow::app::cli::Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => usage_error(e),
    };
    use blockflow::app::mpi;
    let r = mpi::start(cli.command.name()).and_then(|_| blockflow::app::execute(cli));
    let own = r
        .as_ref()
        .is_err_and(|e| !matches!(e, blockflow::error::Error::Aborted { .. }));
    mpi::finish(r.is_ok(), own);
    if let Err(e) = r {
        if mpi::reports() {
            eprintln!("error: {}", e.one_line());
        }
        std::process::exit(e.exit_code());
    }
}

/// A command-line error of clap: help and version print as usual; anything else is one line (clap's own
/// first paragraph joined, without the tip and usage blocks) and exit code 2.
fn usage_error(e: clap::Error) -> ! {
    use clap::error::ErrorKind;
    if matches!(
        e.kind(),
        ErrorKind::DisplayHelp | ErrorKind::DisplayVersion | ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand
    ) {
        e.exit();
    }
    let text = e.to_string();
    let first: Vec<&str> = text.lines().map(str::trim).take_while(|l| !l.is_empty()).collect();
    let first = first.join(" ");
    let first = first.strip_prefix("error: ").unwrap_or(&first);
    eprintln!("error: {first} (see blockflow --help)");
    std::process::exit(2);
}
