//! The `blockflow` command line (DESIGN.md, "Command line and output contract"): one subcommand per
//! command module, each with its own arguments.

use super::bench::BenchKind;
use super::calibrate::CalibrateArgs;
use super::run::RunArgs;
use super::scan::SweepArgs;
use super::stress::StressArgs;
use super::study::StudyArgs;
use super::topology::TopologyArgs;
use clap::{Parser, Subcommand};

/// blockflow: lattice Boltzmann (D3Q19 TRT) on blocks, for particulate flow and load-balancing studies.
#[derive(Parser, Debug)]
#[command(name = "blockflow", version, about)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// Subcommands.
#[derive(Subcommand, Debug)]
pub enum Command {
    /// Run a scene and write summary.json, series.csv (and VTK with --vtk) to the output folder.
    /// SIGINT / SIGTERM stop the run at the end of the graph run under way, write a checkpoint and
    /// summary.json (`"status": "interrupted"`) and exit with 128 + the signal number; a second signal
    /// ends it at once.
    Run(RunArgs),
    /// Print the machine's topology and the thread placement the options would get.
    Topology(TopologyArgs),
    /// Calibrate the workload estimator (paper section 3.3): run the calibration scene for each block size
    /// and diameter, fit eqs. (10)-(14), write samples.csv, coefficients.toml, calibration.json and figures
    /// 6-8 to --out.
    Calibrate(CalibrateArgs),
    /// The load-balancing study (paper section 4.3): run SCENE once, replay its measured task times under
    /// every strategy on P processes of T threads (Table 3, figures 10 and 11 in --out); --live also runs
    /// every strategy for real and prints modeled against measured.
    Study(StudyArgs),
    /// Run a scene over every combination of the varied keys: sweep.csv (values, status, wall and core
    /// seconds, MLUPS, load imbalance, cores, observables) and sweep.png (error against run time,
    /// log-log, fitted orders; without an error observable, MLUPS, wall time and LI per configuration).
    Sweep(SweepArgs),
    /// Stability map: run every combination of one or two keys for a fixed number of steps with the
    /// instability detector on; stress.png and stress.csv say stable, inaccurate or unstable (at which step).
    Stress(StressArgs),
    /// Benchmarks that print tables.
    Bench {
        /// Which benchmark.
        #[command(subcommand)]
        which: BenchKind,
    },
}

impl Command {
    /// The subcommand's name on the command line.
    pub fn name(&self) -> &'static str {
        match self {
            Command::Run(_) => "run",
            Command::Topology(_) => "topology",
            Command::Calibrate(_) => "calibrate",
            Command::Study(_) => "study",
            Command::Sweep(_) => "sweep",
            Command::Stress(_) => "stress",
            Command::Bench { .. } => "bench",
        }
    }
}
