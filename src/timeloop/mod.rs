//! The time loop of a run ([`TimeLoop`]): it owns the simulation, the pipeline that runs its task graphs,
//! the live balancer and the observers, and drives them graph run by graph run:
//!
//! 1. the next stop: `processes.steps_per_graph` steps on, or earlier the first step an observer asked to
//!    see ([`Observer::next_stop`]), or the end;
//! 2. graph runs up to the stop, one unless the end of a balancing interval falls before it (a graph run
//!    never crosses one); after each, its task times into the interval under way (per-block loads,
//!    modeled times, wall time), the corrector's bookkeeping and observers' [`Observer::after_run`]; at
//!    the end of an interval (`balance.interval` steps) the interval closed ([`IntervalLog`]), the
//!    balancing step (block weights, the strategy's new owners, migration) and observers'
//!    [`Observer::interval_closed`];
//! 3. observers' [`Observer::at_stop`], which may end the run.
//!
//! `blockflow run`, `study`, `calibrate`, the benches and the tests drive runs through it; the commands
//! attach their outputs as observers. [`setup`] builds what a configuration asks for.

mod observer;
pub mod setup;

pub use observer::{Flow, Handle, Observer, RunContext, RunEnd};

use crate::balance::Balancer;
use crate::config::Config;
use crate::error::Result;
use crate::metrics::cost_model::{CommModel, Machine};
use crate::metrics::interval::{IntervalLog, IntervalStats};
use crate::metrics::load::predicted_imbalance;
use crate::physics::parts::{ByPart, Part};
use crate::physics::simulation::Simulation;
use crate::pipeline::{Pipeline, PipelineConfig};
use crate::scenes::Scene;
use blockflow_kernels::Real;
use blockflow_scheduler::executor::{Executor, Steal};
use setup::{build_sim, coefficients, make_executor, InitialAssignment};
use std::marker::PhantomData;
use std::time::Instant;

/// What a run records beyond its totals and intervals.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Recording {
    /// A Chrome trace of every task (`--trace`).
    pub trace: bool,
    /// The CPU time of every (step, block, part): the per-block part timings of calibration.
    pub block_parts: bool,
}

/// A run: simulation, pipeline, balancer, interval log and observers (see the module docs).
pub struct TimeLoop<T: Real> {
    sim: Simulation<T>,
    pipe: Pipeline<T>,
    balancer: Option<Balancer>,
    log: IntervalLog,
    /// Workload per block over the interval under way.
    block_load: Vec<f64>,
    interval: u64,
    observers: Vec<Box<dyn Observer<T>>>,
    /// Wall seconds spent stepping (graph runs, their accounting, balancing), outputs at stops excluded.
    stepping_seconds: f64,
    /// The pipeline's CPU seconds per part after the last recorded graph run.
    parts_before: ByPart<f64>,
}

impl<T: Real> TimeLoop<T> {
    /// The run of a configuration: the scene's simulation, the executor of `[processes]`, the initial
    /// assignment by `balance.weights` (and the load imbalance those weights predict for the first
    /// interval), the pipeline, the balancer of `balance.strategy`, and the first touch of every block by
    /// its owner.
    pub fn from_config(cfg: &Config, scene: &Scene, recording: Recording) -> Result<Self> {
        let sim = build_sim::<T>(cfg, scene)?;
        let exec = make_executor(cfg)?;
        let coeffs = coefficients(cfg)?;
        let init = InitialAssignment::of(cfg, &sim, coeffs.as_ref());
        let machine = Self::machine_of(&exec, CommModel::of(&cfg.balance));
        let predicted = predicted_imbalance(&init.weights, &init.owners, machine.processes);
        let settings = PipelineConfig {
            block_parts: recording.block_parts,
            ..PipelineConfig::of(cfg)
        };
        let mut pipe = Pipeline::new(&sim, exec, init.owners.clone(), settings);
        if recording.trace {
            pipe.enable_trace();
        }
        let balancer = Balancer::of(&cfg.balance, cfg.processes.count, coeffs, &sim.domain);
        pipe.first_touch(&sim);
        Ok(TimeLoop {
            block_load: vec![0.0; sim.blocks.len()],
            sim,
            pipe,
            balancer,
            log: IntervalLog::new(init.owners, machine, predicted),
            interval: cfg.balance.interval.max(1),
            observers: Vec::new(),
            stepping_seconds: 0.0,
            parts_before: ByPart::default(),
        })
    }

    /// The machine an executor's run is modeled on.
    fn machine_of(exec: &Executor, comm: CommModel) -> Machine {
        Machine {
            processes: exec.processes(),
            threads: exec.threads_per_process(),
            global: exec.steal() == Steal::Global,
            comm,
        }
    }

    /// The simulation.
    pub fn sim(&self) -> &Simulation<T> {
        &self.sim
    }

    /// The simulation for changes between runs (tests inject faults; a restart decodes its blocks).
    pub fn sim_mut(&mut self) -> &mut Simulation<T> {
        &mut self.sim
    }

    /// The pipeline (executor, owners, totals, trace).
    pub fn pipeline(&self) -> &Pipeline<T> {
        &self.pipe
    }

    /// The live balancer (absent: the assignment never changes).
    pub fn balancer(&self) -> Option<&Balancer> {
        self.balancer.as_ref()
    }

    /// The simulation, the pipeline and the balancer at once (a restart puts its state into all three).
    pub fn parts_mut(&mut self) -> (&mut Simulation<T>, &Pipeline<T>, Option<&mut Balancer>) {
        (&mut self.sim, &self.pipe, self.balancer.as_mut())
    }

    /// The finished intervals of the live assignment.
    pub fn intervals(&self) -> &[IntervalStats] {
        self.log.intervals()
    }

    /// Starts the interval under way at the current step (a run restarted from a checkpoint: its first
    /// interval covers the steps after it up to the next multiple of `balance.interval`).
    pub fn resume(&mut self) {
        self.log.resume_at(self.sim.step);
    }

    /// Tasks of the one-step graph for the bodies where they are now (the blocks with rigid-body tasks are
    /// chosen for one step first).
    pub fn tasks_per_step(&mut self) -> usize {
        if let Some(p) = self.sim.particles.as_mut() {
            let bodies = p.bodies(self.sim.step);
            p.update_active(1, &bodies);
        }
        self.pipe.tasks_per_step(&self.sim)
    }

    /// Adds an observer; its handle reads it back ([`TimeLoop::observer`]).
    pub fn add_observer<O: Observer<T>>(&mut self, o: O) -> Handle<O> {
        self.observers.push(Box::new(o));
        Handle {
            index: self.observers.len() - 1,
            marker: PhantomData,
        }
    }

    /// The observer of a handle.
    pub fn observer<O: Observer<T>>(&self, h: Handle<O>) -> &O {
        observer::downcast(self.observers[h.index].as_ref())
    }

    /// Advances by `steps` steps (see [`TimeLoop::run_to`]).
    pub fn advance(&mut self, steps: u64) -> Result<Flow> {
        self.run_to(self.sim.step + steps)
    }

    /// Advances to step `end` stop by stop (module docs); returns [`Flow::Stop`] when an observer stopped
    /// the run first. On an unstable run the error names the first step and cell (the state is the one
    /// after the graph run that found it).
    pub fn run_to(&mut self, end: u64) -> Result<Flow> {
        while self.sim.step < end {
            let step = self.sim.step;
            let mut stop = (step + self.pipe.settings().steps_per_graph as u64).min(end);
            for o in &self.observers {
                if let Some(s) = o.next_stop(step).filter(|&s| s > step) {
                    stop = stop.min(s);
                }
            }
            let t0 = Instant::now();
            let stepped = self.run_stretch(stop);
            self.stepping_seconds += t0.elapsed().as_secs_f64();
            stepped?;
            if self.at_stop()? == Flow::Stop {
                return Ok(Flow::Stop);
            }
        }
        Ok(Flow::Continue)
    }

    /// Wall seconds spent stepping so far: graph runs, their accounting and the balancing steps (what
    /// MLUPS are measured over; the observers' work at stops is not included).
    pub fn stepping_seconds(&self) -> f64 {
        self.stepping_seconds
    }

    /// The graph runs up to `stop` (one per balancing interval the stretch touches).
    fn run_stretch(&mut self, stop: u64) -> Result<()> {
        while self.sim.step < stop {
            let s = self.sim.step;
            let k = (stop - s).min(self.interval - s % self.interval);
            let ran = self.pipe.run(&mut self.sim, k as usize);
            self.record_run(k as usize);
            ran?;
            self.notify(|o, cx| o.after_run(cx), true)?;
            if self.sim.step.is_multiple_of(self.interval) {
                self.close_interval(true)?;
            }
        }
        Ok(())
    }

    /// Ends the run: closes the partial interval under way and calls every observer's
    /// [`Observer::finish`].
    pub fn finish(&mut self, end: &RunEnd<'_>) -> Result<()> {
        self.close_interval(false)?;
        self.notify(|o, cx| o.finish(cx, end), false)
    }

    /// The last graph run's times into the interval under way, and the corrector's bookkeeping.
    fn record_run(&mut self, k: usize) {
        let Some(run) = self.pipe.last_run() else { return };
        self.log.add_run(&run.recorded());
        let cur = self.log.current_mut();
        cur.wall_seconds += run.wall_seconds;
        cur.message_bytes += run.message_bytes;
        let parts = self.pipe.totals().part_cpu;
        for part in Part::ALL {
            cur.part_seconds[part] += parts[part] - self.parts_before[part];
        }
        self.parts_before = parts;
        for (acc, x) in self.block_load.iter_mut().zip(run.block_load) {
            *acc += x;
        }
        if let Some(b) = self.balancer.as_mut() {
            b.after_run(&self.sim, k);
        }
    }

    /// Closes the interval under way (nothing when no step was taken since the last one); with
    /// `balance`, the balancing step follows: weights, the strategy's owners, migration, re-arm.
    fn close_interval(&mut self, balance: bool) -> Result<()> {
        let step = self.sim.step;
        if self.log.close(step, &self.block_load, &self.sim.domain).is_none() {
            return Ok(());
        }
        self.block_load.iter_mut().for_each(|x| *x = 0.0);
        if balance {
            if let Some(bal) = self.balancer.as_mut() {
                let t0 = Instant::now();
                let load = &self.log.intervals().last().expect("closed above").block_load;
                let dist = bal.rebalance(&self.sim, load, self.log.owners());
                let predicted = predicted_imbalance(bal.last_weights(), &dist.owners, self.log.machine().processes);
                let (moved, bytes) = self.pipe.set_owners(&self.sim, dist.owners.clone());
                let secs = t0.elapsed().as_secs_f64();
                bal.migrated += moved as u64;
                bal.seconds += secs;
                self.log.reassign(dist.owners, predicted);
                let iv = self.log.last_mut().expect("closed above");
                iv.migrated_blocks = moved as u64;
                iv.migrated_bytes = bytes;
                iv.balance_seconds = secs;
            }
        }
        let iv = self.log.intervals().last().expect("closed above").clone();
        self.notify(|o, cx| o.interval_closed(cx, &iv, balance), balance)
    }

    fn at_stop(&mut self) -> Result<Flow> {
        let mut flow = Flow::Continue;
        self.notify(
            |o, cx| {
                if o.at_stop(cx)? == Flow::Stop {
                    flow = Flow::Stop;
                }
                Ok(())
            },
            false,
        )?;
        Ok(flow)
    }

    /// Calls `f` on every observer in the order they were added, with the context of now (`with_run`:
    /// the last graph run's record included).
    fn notify(
        &mut self,
        mut f: impl FnMut(&mut dyn Observer<T>, &RunContext<'_, T>) -> Result<()>,
        with_run: bool,
    ) -> Result<()> {
        let mut observers = std::mem::take(&mut self.observers);
        let cx = RunContext {
            sim: &self.sim,
            owners: self.pipe.owners(),
            balancer: self.balancer.as_ref(),
            run: if with_run { self.pipe.last_run() } else { None },
            intervals: self.log.intervals(),
        };
        let r = observers.iter_mut().try_for_each(|o| f(o.as_mut(), &cx));
        self.observers = observers;
        r
    }
}
