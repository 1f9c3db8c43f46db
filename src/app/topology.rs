//! `blockflow topology`: the machine's topology (hwloc) and the thread placement a process layout and
//! pinning policy would get.

use crate::error::{Error, Result};
use blockflow_scheduler::topology::{describe_placement, placement, PinPolicy, Topology};

/// Print the machine's topology and the thread placement the options would get.
#[derive(clap::Args, Debug)]
pub struct TopologyArgs {
    /// Virtual processes P.
    #[arg(long, default_value_t = 1)]
    pub processes: usize,
    /// Threads per process T.
    #[arg(long, default_value_t = 1)]
    pub threads_per_process: usize,
    /// Pinning: compact, scatter, none or a core list.
    #[arg(long, default_value = "compact")]
    pub pin: String,
}

/// Prints the topology and the placement.
pub fn execute(a: TopologyArgs) -> Result<()> {
    if a.processes == 0 || a.threads_per_process == 0 {
        return Err(Error::Config(
            "--processes and --threads-per-process must be at least 1".into(),
        ));
    }
    let pin = &a.pin;
    let policy: PinPolicy = pin.parse().map_err(|e| Error::Config(format!("--pin {pin}: {e}")))?;
    let topo = Topology::detect();
    let cores = placement(&topo, a.processes, a.threads_per_process, &policy)
        .map_err(|e| Error::Config(format!("--pin {pin}: {e}")))?;
    super::print_out(&format!(
        "{}\n\n{}\n",
        topo.describe(),
        describe_placement(a.processes, a.threads_per_process, &cores)
    ));
    Ok(())
}
