//! Runs launched as an MPI job (`mpirun -np N blockflow run SCENE ...`, `srun blockflow run ...`): each
//! process is one rank of the run ([`crate::ranks`]), talking through the MPI transport (a build with
//! `--features mpi`). [`start`] initialises MPI when the launcher's environment says this process is
//! part of a job, [`world`] hands the job to `blockflow run`, [`finish`] finalises MPI after a
//! successful command.

use crate::error::{Error, Result};
use crate::ranks::World;
use std::sync::{Arc, OnceLock};

/// The MPI job of this process, once [`start`] found one.
static JOB: OnceLock<Job> = OnceLock::new();

struct Job {
    world: Arc<World>,
    #[cfg(feature = "mpi")]
    mpi: Arc<blockflow_scheduler::transport::Mpi>,
}

/// The size of the MPI job the launcher started this process in (Open MPI, MPICH/Hydra, Slurm's PMI),
/// if any.
pub fn launched_size() -> Option<usize> {
    ["OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_SIZE"]
        .iter()
        .find_map(|v| std::env::var(v).ok()?.parse().ok())
}

/// This process's rank in the job the launcher started, from the environment (before MPI is up).
pub fn launched_rank() -> Option<usize> {
    ["OMPI_COMM_WORLD_RANK", "PMI_RANK", "PMIX_RANK"]
        .iter()
        .find_map(|v| std::env::var(v).ok()?.parse().ok())
}

/// Joins the MPI job this process was launched in, if any, for command `command` (only `run` runs on
/// ranks; the others run in one process and refuse a job of several). Call once, from the main thread,
/// before anything else starts threads that would call MPI.
pub fn start(command: &str) -> Result<()> {
    let Some(size) = launched_size() else {
        return Ok(());
    };
    if command != "run" {
        if size > 1 {
            return Err(Error::Config(format!(
                "blockflow {command} runs in one process; under mpirun only `blockflow run` spreads over ranks \
                 (start it without mpirun)"
            )));
        }
        return Ok(());
    }
    join(size)
}

#[cfg(feature = "mpi")]
fn join(_size: usize) -> Result<()> {
    let mpi = Arc::new(blockflow_scheduler::transport::Mpi::init().map_err(Error::Config)?);
    let world = Arc::new(World::new(mpi.clone()));
    let _ = JOB.set(Job { world, mpi });
    Ok(())
}

#[cfg(not(feature = "mpi"))]
fn join(size: usize) -> Result<()> {
    if size > 1 {
        return Err(Error::Config(format!(
            "launched as {size} MPI ranks, but this blockflow was built without MPI: build it with \
             `cargo build --release --features mpi` (scripts/setup installs Open MPI)"
        )));
    }
    Ok(())
}

/// The MPI job `blockflow run` runs on (`None`: not launched by an MPI launcher, or a build without MPI).
pub fn world() -> Option<Arc<World>> {
    JOB.get().map(|j| j.world.clone())
}

/// Whether this process reports a failure: outside an MPI job always; in one, rank 0 only. Rank 0 hears
/// of every other rank's failure (an abort notice, or the same error reached together), because every
/// rank's last step that can fail comes before a collective of rank 0's.
pub fn reports() -> bool {
    world().map(|w| w.rank()).or_else(launched_rank).unwrap_or(0) == 0
}

/// Ends this process's part of the job after a command: a successful one finalises MPI; a failed one
/// leaves it (the other ranks may be anywhere) and the process exits with the error's code, which ends
/// the job. A rank other than 0 that failed on its own (`own_failure`) first gives rank 0 a moment to
/// take its notice and report it (the launcher ends every rank once one exits with an error).
pub fn finish(ok: bool, own_failure: bool) {
    if own_failure && !ok && world().is_some_and(|w| !w.is_root()) {
        std::thread::sleep(std::time::Duration::from_secs(1));
    }
    #[cfg(feature = "mpi")]
    if let (true, Some(job)) = (ok, JOB.get()) {
        job.mpi.finish(std::time::Duration::from_secs(10));
    }
    #[cfg(not(feature = "mpi"))]
    let _ = (ok, &JOB);
}
