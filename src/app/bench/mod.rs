//! `blockflow bench ...`: the benchmarks that print tables, one module each.

pub mod accuracy;
pub mod balance;
pub mod coupled;
pub mod kernel;
pub mod mpi;
pub mod rigid;
pub mod scheduler;
pub mod skip;

use crate::error::{Error, Result};
use clap::Subcommand;
use std::path::PathBuf;

/// Benchmarks.
#[derive(Subcommand, Debug)]
pub enum BenchKind {
    /// Per-task overhead and the fluid step through the task graph vs a plain loop on the same threads.
    Scheduler {
        /// Short timings.
        #[arg(long)]
        quick: bool,
    },
    /// Rigid-body sub-step: time and contacts per second for 100 … 20 000 spheres, grid vs all pairs.
    Rigid {
        /// Short timings.
        #[arg(long)]
        quick: bool,
    },
    /// Copy-bandwidth roofline and the fused kernel's MLUPS (f64, f32; 1 and 2 threads).
    Kernel {
        /// Short timings.
        #[arg(long)]
        quick: bool,
        /// Cells per block edge.
        #[arg(long, default_value_t = 128)]
        size: usize,
        /// Thread counts, comma-separated.
        #[arg(long, value_delimiter = ',', default_value = "1,2")]
        threads: Vec<usize>,
    },
    /// Cost of the balancing step: curve keys and splits for 100 000 blocks, diffusive and METIS on the
    /// hopper's 288 blocks for 32 processes.
    Balance,
    /// Skipped work, measured: channel, calibration, hopper-small and granular_box with the skip rules and
    /// with --no-skip; tasks per kind, tasks skipped per rule, wall time saved, checksums compared.
    Skip {
        /// The CI size (under 3 minutes on 2 cores).
        #[arg(long)]
        quick: bool,
        /// Output folder (skip.csv, skip.md and the runs).
        #[arg(long, default_value = "out/skip")]
        out: PathBuf,
    },
    /// The coupled step's cost structure: every particulate scene with its bodies and fluid-only on the
    /// same blocks, MLUPS and each part's share of the thread time, next to the paper's figure 7.
    Coupled {
        /// The CI size (a few steps of three scenes).
        #[arg(long)]
        quick: bool,
        /// Threads of every run (one virtual process).
        #[arg(long, default_value_t = 2)]
        threads: usize,
        /// Another blockflow binary: its `run` repeats the coupled runs beside this one's.
        #[arg(long, value_name = "BINARY")]
        baseline: Option<PathBuf>,
        /// A `KEY=VALUE` override the baseline's runs get after the scene's own (repeatable), e.g.
        /// `balance.coefficients="OLD.toml"` for a binary that does not know the current coefficient
        /// file's keys.
        #[arg(long = "baseline-set", value_name = "KEY=VALUE", requires = "baseline")]
        baseline_set: Vec<String>,
        /// Runs of each scene and variant, in an order that rotates from round to round; the table
        /// shows the median (3 puts every run once in every position).
        #[arg(long, default_value_t = 1)]
        rounds: usize,
        /// Output folder (coupled.md, coupled.csv and the runs).
        #[arg(long, default_value = "out/coupled")]
        out: PathBuf,
    },
    /// Ranks against virtual processes: hopper-small on N = 1 … max ranks of an MPI job (`mpirun` of
    /// this binary, built with `--features mpi`; else the in-process ranks of `--ranks`) and on N virtual
    /// processes: time per step, messages per step and per rank pair, modeled time.
    Mpi {
        /// The CI size (1 and 2 ranks, 40 steps).
        #[arg(long)]
        quick: bool,
        /// Most ranks.
        #[arg(long, default_value_t = 4)]
        max: usize,
        /// Steps of every run.
        #[arg(long, default_value_t = 400)]
        steps: u64,
        /// Output folder (the runs and mpi.md).
        #[arg(long, default_value = "out/mpi")]
        out: PathBuf,
    },
    /// Run time against error: channel, couette, Taylor-Green and the drag array (CLI and SBB, three solid
    /// fractions) over resolution, f64 and f32; Pareto front per scene.
    Accuracy {
        /// The CI size (about 3 minutes).
        #[arg(long)]
        quick: bool,
        /// Output folder (one sweep per scene).
        #[arg(long, default_value = "out/accuracy")]
        out: PathBuf,
    },
}

/// Runs a benchmark and prints its table.
pub fn execute(which: BenchKind) -> Result<()> {
    let print = super::print_out;
    match which {
        BenchKind::Accuracy { quick, out } => {
            let cases = accuracy::run(quick, &out, &accuracy::configs_dir())?;
            print(&format!(
                "{}results in {}\n",
                accuracy::to_markdown(&cases),
                out.display()
            ));
            Ok(())
        }
        BenchKind::Skip { quick, out } => {
            let report = skip::run(quick, &out, &accuracy::configs_dir())?;
            print(&format!("{}results in {}\n", skip::to_markdown(&report), out.display()));
            if report.iter().any(|s| !s.checksums_equal()) {
                return Err(Error::Config(
                    "bench skip: the checksums with and without --no-skip differ (see the table)".into(),
                ));
            }
            Ok(())
        }
        BenchKind::Coupled {
            quick,
            threads,
            baseline,
            baseline_set,
            rounds,
            out,
        } => {
            let opts = coupled::CoupledOptions {
                quick,
                threads,
                baseline,
                baseline_sets: baseline_set,
                rounds,
                program: std::env::current_exe().ok(),
                out: out.clone(),
                configs: accuracy::configs_dir(),
            };
            let rows = coupled::run(&opts)?;
            print(&format!(
                "{}results in {}\n",
                coupled::to_markdown(&rows),
                out.display()
            ));
            Ok(())
        }
        BenchKind::Mpi { quick, max, steps, out } => {
            let (max, steps) = if quick {
                (max.min(2), steps.min(40))
            } else {
                (max, steps)
            };
            if max == 0 || steps == 0 {
                return Err(Error::Config("bench mpi: --max and --steps must be at least 1".into()));
            }
            let rows = mpi::bench(max, steps, &out, &accuracy::configs_dir())?;
            let text = mpi::to_markdown(&rows);
            crate::util::fs::write_atomic(&out.join("mpi.md"), text.as_bytes())?;
            print(&format!("{text}results in {}\n", out.display()));
            if rows.windows(2).any(|w| w[0].checksum != w[1].checksum) {
                return Err(Error::Config(
                    "bench mpi: the checksums differ between runs (see the table)".into(),
                ));
            }
            Ok(())
        }
        BenchKind::Balance => {
            print(&balance::scale_table());
            Ok(())
        }
        BenchKind::Scheduler { quick } => {
            let rows = scheduler::run(quick, &[(1, 1), (1, 2), (2, 1)])?;
            print(&scheduler::to_markdown(&rows));
            Ok(())
        }
        BenchKind::Rigid { quick } => {
            let report = rigid::run(quick)?;
            print(&rigid::to_markdown(&report));
            Ok(())
        }
        BenchKind::Kernel { quick, size, threads } => {
            if !(8..=4096).contains(&size) || threads.is_empty() || threads.contains(&0) {
                return Err(Error::Config(
                    "bench kernel: --size must be between 8 and 4096 and --threads positive".into(),
                ));
            }
            let opts = kernel::KernelBenchOptions { quick, size, threads };
            // Refused before anything is allocated: a block per thread past the memory would abort the
            // run or call the out-of-memory killer.
            let need = kernel::memory_needed(&opts);
            if let Some(avail) = crate::app::run::resources::available_memory().filter(|&a| need > a) {
                return Err(Error::Config(format!(
                    "bench kernel: --size {size} with --threads up to {} needs an estimated {need} bytes ({:.1} GiB) \
                     but the machine has {avail} bytes available; lower --size or --threads",
                    opts.threads.iter().max().unwrap_or(&1),
                    need as f64 / (1u64 << 30) as f64
                )));
            }
            let report = kernel::run(&opts);
            print(&format!("{}\n", report.to_markdown()));
            Ok(())
        }
    }
}
