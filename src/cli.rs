//! The `blockflow` command line (DESIGN.md, "Command line and output contract").

use crate::error::{Error, Result};
use clap::{Parser, Subcommand};
use std::path::PathBuf;

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
    Run {
        /// Scene file (TOML), e.g. configs/channel.toml. With --restart it may be left out; if given, it
        /// must describe the checkpoint's physics.
        #[arg(required_unless_present = "restart")]
        scene: Option<PathBuf>,
        /// Override a key of the scene file: --set fluid.tau=0.6 (repeatable; same dotted path as the file).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        /// Output folder (default: run.out, else out/<scene file name>).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Number of time steps (default: run.steps, else the scene's own).
        #[arg(long)]
        steps: Option<u64>,
        /// Write VTK output (fluid.pvd) every N steps.
        #[arg(long, value_name = "EVERY")]
        vtk: Option<u64>,
        /// Virtual processes P (processes.count).
        #[arg(long)]
        processes: Option<usize>,
        /// Threads per process T (processes.threads_per_process).
        #[arg(long)]
        threads_per_process: Option<usize>,
        /// Pinning: compact, scatter, none or a core list such as 0,1 (processes.pin).
        #[arg(long)]
        pin: Option<String>,
        /// Assignment strategy: none, hilbert, morton, diffusive, metis (balance.strategy).
        #[arg(long)]
        balance: Option<String>,
        /// Steps per balancing / measurement interval (balance.interval).
        #[arg(long)]
        interval: Option<u64>,
        /// Write a Chrome trace (Perfetto, chrome://tracing) of every task to FILE.
        #[arg(long, value_name = "FILE")]
        trace: Option<PathBuf>,
        /// Write a checkpoint to OUT/checkpoints/step-<step> whenever the step is a multiple of N
        /// (run.checkpoint_every).
        #[arg(long, value_name = "N")]
        checkpoint_every: Option<u64>,
        /// Write a checkpoint when SECONDS of wall-clock time have passed since the last one
        /// (run.checkpoint_wall).
        #[arg(long, value_name = "SECONDS")]
        checkpoint_wall: Option<f64>,
        /// Checkpoints to keep, the newest (run.checkpoints_kept, default 2).
        #[arg(long, value_name = "K")]
        checkpoints_kept: Option<usize>,
        /// Continue from a checkpoint file (or the newest one in a folder or its checkpoints/ subfolder).
        /// The configuration is the checkpoint's, with this command line's overrides of run.*,
        /// processes.* and balance.* keys on top; the final state is bitwise the uninterrupted run's.
        #[arg(long, value_name = "PATH")]
        restart: Option<PathBuf>,
        /// Run every task on every block: switch off the skip rules (outside blocks, blocks without
        /// boundary cells, blocks without particles, static geometry mapped once, the fused kernel) to
        /// measure what they save (run.no_skip = true). Slower; the results are bitwise the same.
        #[arg(long)]
        no_skip: bool,
    },
    /// Print the machine's topology and the thread placement the options would get.
    Topology {
        /// Virtual processes P.
        #[arg(long, default_value_t = 1)]
        processes: usize,
        /// Threads per process T.
        #[arg(long, default_value_t = 1)]
        threads_per_process: usize,
        /// Pinning: compact, scatter, none or a core list.
        #[arg(long, default_value = "compact")]
        pin: String,
    },
    /// Calibrate the workload estimator (paper section 3.3): run the calibration scene for each block size
    /// and diameter, fit eqs. (10)-(14), write samples.csv, coefficients.toml, calibration.json and figures
    /// 6-8 to --out.
    Calibrate {
        /// Calibration scene (default configs/calibration.toml).
        #[arg(default_value = "configs/calibration.toml")]
        scene: PathBuf,
        /// Block edge lengths in cells, comma-separated (default 12,16; --quick 12; --paper 24,32,48,64).
        #[arg(long, value_delimiter = ',')]
        block_sizes: Vec<usize>,
        /// Sphere diameters in cells, comma-separated (default 4,6; --paper 10,20).
        #[arg(long, value_delimiter = ',')]
        diameters: Vec<f64>,
        /// A short campaign (about two minutes), for tests.
        #[arg(long)]
        quick: bool,
        /// The paper's sizes (block sizes 24, 32, 48, 64; D = 10, 20; 2.5 T), for big machines.
        #[arg(long, conflicts_with = "quick")]
        paper: bool,
        /// Output folder.
        #[arg(long, default_value = "out/calibration")]
        out: PathBuf,
    },
    /// The load-balancing study (paper section 4.3): run SCENE once, replay its measured task times under
    /// every strategy on P processes of T threads (Table 3, figures 10 and 11 in --out); --live also runs
    /// every strategy for real and prints modeled against measured.
    Study {
        /// Scene file (TOML), e.g. configs/hopper.toml.
        scene: PathBuf,
        /// Processes P of the strategies (any number: the run is replayed, not executed, on them).
        #[arg(long)]
        processes: usize,
        /// Threads per process T of the strategies.
        #[arg(long, default_value_t = 1)]
        threads_per_process: usize,
        /// Strategies, comma-separated: none, hilbert, morton, diffusive, metis, steal-global; a suffix
        /// @cells, @estimator, @measured or @corrected sets the block weights of one (hilbert@estimator).
        #[arg(
            long,
            value_delimiter = ',',
            default_value = "none,hilbert,morton,diffusive,metis,steal-global"
        )]
        strategies: Vec<String>,
        /// Block weights of the rebalancing strategies: cells, estimator, measured, corrected
        /// (default: the scene's balance.weights).
        #[arg(long)]
        weights: Option<String>,
        /// Number of time steps (default: run.steps, else the scene's own).
        #[arg(long)]
        steps: Option<u64>,
        /// Steps per balancing interval (balance.interval).
        #[arg(long)]
        interval: Option<u64>,
        /// Override a key of the scene file (repeatable).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        /// Also run every strategy for real on P × T threads: modeled against measured.
        #[arg(long)]
        live: bool,
        /// Threads of the recording run (default: the machine's cores).
        #[arg(long)]
        record_threads: Option<usize>,
        /// Output folder.
        #[arg(long, default_value = "out/study")]
        out: PathBuf,
    },
    /// Run a scene over every combination of the varied keys: sweep.csv (values, status, wall and core
    /// seconds, MLUPS, observables) and sweep.png (error against run time, log-log, fitted orders).
    Sweep {
        /// Scene file (TOML).
        scene: PathBuf,
        /// KEY=V1,V2,... (repeatable; the first key drives convergence, e.g. scene.resolution=16,32,64).
        #[arg(long, value_name = "KEY=V1,V2,...", required = true)]
        vary: Vec<String>,
        /// Fixed override (repeatable).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        /// Runs per combination; the fastest wall time is kept.
        #[arg(long, default_value_t = 1)]
        repeat: usize,
        /// Number of time steps (default: the scene's).
        #[arg(long)]
        steps: Option<u64>,
        /// Observable plotted as the error (default: the first whose name contains "error").
        #[arg(long)]
        error: Option<String>,
        /// Output folder.
        #[arg(long, default_value = "out/sweep")]
        out: PathBuf,
    },
    /// Stability map: run every combination of one or two keys for a fixed number of steps with the
    /// instability detector on; stress.png and stress.csv say stable, inaccurate or unstable (at which step).
    Stress {
        /// Scene file (TOML).
        scene: PathBuf,
        /// KEY=V1,V2,... or KEY=A:B:N or KEY=A:B:N:log (one or two).
        #[arg(long, value_name = "KEY=RANGE", required = true)]
        vary: Vec<String>,
        /// Fixed override (repeatable).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        /// Steps of every run (default: the scene's).
        #[arg(long)]
        steps: Option<u64>,
        /// Error observable for "inaccurate" (default: the first whose name contains "error").
        #[arg(long)]
        error: Option<String>,
        /// A stable run with the error observable above this is "inaccurate".
        #[arg(long)]
        max_error: Option<f64>,
        /// Output folder.
        #[arg(long, default_value = "out/stress")]
        out: PathBuf,
    },
    /// Benchmarks that print tables.
    Bench {
        /// Which benchmark.
        #[command(subcommand)]
        which: BenchKind,
    },
}

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

/// Executes a parsed command line.
pub fn execute(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Run {
            scene,
            mut set,
            out,
            steps,
            vtk,
            processes,
            threads_per_process,
            pin,
            balance,
            interval,
            trace,
            checkpoint_every,
            checkpoint_wall,
            checkpoints_kept,
            restart,
            no_skip,
        } => {
            if vtk == Some(0) {
                return Err(Error::Config("--vtk 0: must be at least 1".into()));
            }
            if let Some(n) = checkpoint_every {
                set.push(format!("run.checkpoint_every={n}"));
            }
            if let Some(w) = checkpoint_wall {
                if !w.is_finite() {
                    return Err(Error::Config(format!(
                        "--checkpoint-wall {w}: must be a finite number of seconds > 0"
                    )));
                }
                set.push(format!("run.checkpoint_wall={w:?}"));
            }
            if let Some(k) = checkpoints_kept {
                set.push(format!("run.checkpoints_kept={k}"));
            }
            if no_skip {
                set.push("run.no_skip=true".into());
            }
            // Command-line options are overrides of the stable keys, checked like the file's values.
            if let Some(p) = processes {
                set.push(format!("processes.count={p}"));
            }
            if let Some(t) = threads_per_process {
                set.push(format!("processes.threads_per_process={t}"));
            }
            if let Some(p) = pin {
                set.push(format!("processes.pin=\"{}\"", p.replace('"', "")));
            }
            if let Some(b) = balance {
                set.push(format!("balance.strategy=\"{}\"", b.replace('"', "")));
            }
            if let Some(i) = interval {
                set.push(format!("balance.interval={i}"));
            }
            let (cfg, restart) = match &restart {
                Some(path) => {
                    let ck = crate::checkpoint::Checkpoint::read(&crate::checkpoint::resolve(path)?)?;
                    let cfg = crate::checkpoint::restart_config(&ck, scene.as_deref(), &set)?;
                    (cfg, Some(std::sync::Arc::new(ck)))
                }
                None => (
                    crate::config::load(scene.as_deref().expect("clap requires SCENE without --restart"), &set)?,
                    None,
                ),
            };
            crate::checkpoint::install_signal_handlers()?;
            let opts = crate::runner::RunOptions {
                steps,
                out,
                vtk_every: vtk,
                progress: true,
                scene_path: scene.clone(),
                trace,
                restart,
            };
            let dir = crate::runner::output_dir(&cfg, &opts);
            let s = crate::runner::run(&cfg, &opts)?;
            let mut text = format!(
                "{}: {} steps, {} fluid cells in {} blocks, {} x {} threads, {:.2} s, {:.1} MLUPS ({})\n",
                s.scene,
                s.steps,
                s.fluid_cells,
                s.blocks,
                s.processes,
                s.threads_per_process,
                s.wall_seconds,
                s.mlups,
                s.precision
            );
            for (k, v) in &s.observables {
                text += &format!("  {k} = {v:.6e}\n");
            }
            let sum = match &s.checksum.particles {
                Some(p) => format!("checksums fluid {} particles {p}", s.checksum.fluid),
                None => format!("checksum {}", s.checksum.fluid),
            };
            text += &format!("  {sum}; results in {}\n", dir.display());
            print_out(&text);
            Ok(())
        }
        Command::Topology {
            processes,
            threads_per_process,
            pin,
        } => {
            use blockflow_scheduler::topology::{describe_placement, placement, PinPolicy, Topology};
            if processes == 0 || threads_per_process == 0 {
                return Err(Error::Config(
                    "--processes and --threads-per-process must be at least 1".into(),
                ));
            }
            let policy: PinPolicy = pin.parse().map_err(|e| Error::Config(format!("--pin {pin}: {e}")))?;
            let topo = Topology::detect();
            let cores = placement(&topo, processes, threads_per_process, &policy)
                .map_err(|e| Error::Config(format!("--pin {pin}: {e}")))?;
            print_out(&format!(
                "{}\n\n{}\n",
                topo.describe(),
                describe_placement(processes, threads_per_process, &cores)
            ));
            Ok(())
        }
        Command::Calibrate {
            scene,
            block_sizes,
            diameters,
            quick,
            paper,
            out,
        } => {
            if block_sizes.contains(&0) || diameters.iter().any(|d| !(d.is_finite() && *d > 0.0)) {
                return Err(Error::Config(
                    "calibrate: --block-sizes and --diameters must be positive".into(),
                ));
            }
            let opts = crate::calibrate::CalibrateOptions {
                scene,
                block_sizes,
                diameters,
                quick,
                paper,
                out: out.clone(),
            };
            let report = crate::calibrate::run(&opts)?;
            let coeffs = crate::estimator::Coefficients::load(&out.join("coefficients.toml"))?;
            print_out(&crate::calibrate::to_markdown(&report, &coeffs));
            print_out(&format!("results in {}\n", out.display()));
            Ok(())
        }
        Command::Study {
            scene,
            processes,
            threads_per_process,
            strategies,
            weights,
            steps,
            interval,
            mut set,
            live,
            record_threads,
            out,
        } => {
            if let Some(i) = interval {
                set.push(format!("balance.interval={i}"));
            }
            let weights = match weights {
                None => None,
                Some(w) => Some(crate::study::run::parse_weights(&w).ok_or_else(|| {
                    Error::Config(format!(
                        "--weights {w}: unknown; use cells, estimator, measured or corrected"
                    ))
                })?),
            };
            let opts = crate::study::run::StudyOptions {
                scene,
                sets: set,
                processes,
                threads_per_process,
                strategies,
                weights,
                steps,
                live,
                out: out.clone(),
                record_threads,
            };
            let r = crate::study::run::study(&opts)?;
            let mut text = crate::study::report::markdown(&r.strategies);
            if !r.live.is_empty() {
                text += "\nLive runs, modeled against measured:\n\n";
                text += &crate::study::run::live_markdown(&r.live);
            }
            text += &format!("results in {}\n", out.display());
            print_out(&text);
            Ok(())
        }
        Command::Sweep {
            scene,
            vary,
            set,
            repeat,
            steps,
            error,
            out,
        } => {
            if repeat == 0 {
                return Err(Error::Config("--repeat 0: must be at least 1".into()));
            }
            let vary = vary
                .iter()
                .map(|v| crate::sweep::parse_vary(v))
                .collect::<Result<Vec<_>>>()?;
            let opts = crate::sweep::SweepOptions {
                scene,
                vary,
                sets: set,
                repeat,
                steps,
                error,
                out: out.clone(),
                record_refused: false,
                repeat_until_seconds: None,
            };
            let r = crate::sweep::sweep(&opts)?;
            print_out(&format!(
                "{}results in {}\n",
                crate::sweep::to_markdown(&r),
                out.display()
            ));
            Ok(())
        }
        Command::Bench {
            which: BenchKind::Accuracy { quick, out },
        } => {
            let cases = crate::bench_accuracy::run(quick, &out, &crate::bench_accuracy::configs_dir())?;
            print_out(&format!(
                "{}results in {}\n",
                crate::bench_accuracy::to_markdown(&cases),
                out.display()
            ));
            Ok(())
        }
        Command::Stress {
            scene,
            vary,
            set,
            steps,
            error,
            max_error,
            out,
        } => {
            let vary = vary
                .iter()
                .map(|v| crate::stress::parse_range(v))
                .collect::<Result<Vec<_>>>()?;
            let opts = crate::stress::StressOptions {
                scene,
                vary,
                sets: set,
                steps,
                error,
                max_error,
                out: out.clone(),
            };
            let r = crate::stress::stress(&opts)?;
            print_out(&format!(
                "{}results in {}\n",
                crate::stress::to_markdown(&r),
                out.display()
            ));
            Ok(())
        }
        Command::Bench {
            which: BenchKind::Skip { quick, out },
        } => {
            let report = crate::bench_skip::run(quick, &out, &crate::bench_accuracy::configs_dir())?;
            print_out(&format!(
                "{}results in {}\n",
                crate::bench_skip::to_markdown(&report),
                out.display()
            ));
            if report.iter().any(|s| !s.checksums_equal()) {
                return Err(Error::Config(
                    "bench skip: the checksums with and without --no-skip differ (see the table)".into(),
                ));
            }
            Ok(())
        }
        Command::Bench {
            which: BenchKind::Balance,
        } => {
            print_out(&crate::balance::strategy::scale_table());
            Ok(())
        }
        Command::Bench {
            which: BenchKind::Scheduler { quick },
        } => {
            let rows = crate::bench_scheduler::run(quick, &[(1, 1), (1, 2), (2, 1)])?;
            print_out(&crate::bench_scheduler::to_markdown(&rows));
            Ok(())
        }
        Command::Bench {
            which: BenchKind::Rigid { quick },
        } => {
            let report = crate::bench_rigid::run(quick)?;
            print_out(&crate::bench_rigid::to_markdown(&report));
            Ok(())
        }
        Command::Bench {
            which: BenchKind::Kernel { quick, size, threads },
        } => {
            if size < 8 || threads.is_empty() || threads.contains(&0) {
                return Err(Error::Config(
                    "bench kernel: --size must be at least 8 and --threads positive".into(),
                ));
            }
            let opts = crate::bench_kernel::KernelBenchOptions { quick, size, threads };
            let report = crate::bench_kernel::run(&opts);
            print_out(&format!("{}\n", report.to_markdown()));
            Ok(())
        }
    }
}

/// Writes to stdout, ignoring a closed pipe (`blockflow run ... | head` must not panic).
fn print_out(text: &str) {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    let _ = out.write_all(text.as_bytes()).and_then(|_| out.flush());
}
