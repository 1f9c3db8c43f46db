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

use crate::balance::weights::BlockState;
use crate::balance::Balancer;
use crate::config::Config;
use crate::error::Result;
use crate::estimator::Quantities;
use crate::metrics::cost_model::{CommModel, Machine, Modeler};
use crate::metrics::interval::{IntervalLog, IntervalStats};
use crate::metrics::load::predicted_imbalance;
use crate::physics::parts::{ByPart, Part};
use crate::physics::simulation::Simulation;
use crate::pipeline::{Pipeline, PipelineConfig};
use crate::ranks::World;
use crate::scenes::Scene;
use blockflow_kernels::Real;
use blockflow_scheduler::executor::Steal;
use setup::{build_state, coefficients, make_executor, make_rank_executor, InitialAssignment};
use std::marker::PhantomData;
use std::sync::Arc;
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
    /// The ranks the run is spread over (one, under virtual processes).
    world: Arc<World>,
    /// Models the recorded graph runs while the next ones execute (one rank only).
    modeler: Option<Modeler>,
    /// The blocks' state at the last balancing step, taken before its migration (what observers that
    /// balance the same interval another way weigh the blocks by; a migrated block's mapping averages
    /// start again after the move).
    balance_state: Option<BlockState>,
}

impl<T: Real> TimeLoop<T> {
    /// The run of a configuration: the scene's simulation, the executor of `[processes]`, the initial
    /// assignment by `balance.weights` (and the load imbalance those weights predict for the first
    /// interval), the pipeline, the balancer of `balance.strategy`, and the first touch of every block by
    /// its owner.
    pub fn from_config(cfg: &Config, scene: &Scene, recording: Recording) -> Result<Self> {
        Self::on_world(cfg, scene, recording, Arc::new(World::single()))
    }

    /// The run of a configuration on this rank of `world` ([`TimeLoop::from_config`] when the world has
    /// one rank). With several, `processes.count` must be the number of ranks (each rank is one
    /// process of `processes.threads_per_process` threads), every rank builds the same block structure
    /// and initial assignment, holds only its own blocks' data, and every rank calls every method of the
    /// time loop in the same order.
    pub fn on_world(cfg: &Config, scene: &Scene, recording: Recording, world: Arc<World>) -> Result<Self> {
        let mut sim = build_state::<T>(cfg, scene)?;
        let exec = if world.is_single() {
            make_executor(cfg)?
        } else {
            make_rank_executor(cfg, &world)?
        };
        let coeffs = coefficients(cfg)?;
        let init = InitialAssignment::of(cfg, &sim, coeffs.as_ref());
        if !world.is_single() {
            let me = world.rank();
            for b in sim.blocks.iter().filter(|b| init.owners[b.id] != me as u32) {
                // SAFETY: nothing runs yet.
                unsafe { b.release() };
            }
            if let Some(parts) = sim.particles.as_mut() {
                // SAFETY: as above.
                unsafe { parts.hold_only(init.owners.iter().map(|&o| o as usize == me).collect()) };
            }
        }
        sim.init(&scene.init);
        let settings = PipelineConfig {
            block_parts: recording.block_parts,
            ..PipelineConfig::of(cfg)
        };
        let mut pipe = Pipeline::new(&sim, exec, init.owners.clone(), settings, world.clone());
        let machine = Machine {
            processes: pipe.processes(),
            threads: pipe.executor().threads_per_process(),
            global: pipe.executor().steal() == Steal::Global,
            comm: CommModel::of(&cfg.balance),
        };
        let predicted = predicted_imbalance(&init.weights, &init.owners, machine.processes);
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
            modeler: world.is_single().then(Modeler::new),
            world,
            balance_state: None,
        })
    }

    /// The ranks the run is spread over.
    pub fn world(&self) -> &Arc<World> {
        &self.world
    }

    /// Every block's state the block weights are computed from: this process's blocks, or under ranks
    /// every rank's gathered in block-id order.
    fn block_state(&self) -> Result<BlockState> {
        if self.world.is_single() {
            return Ok(BlockState::of(&self.sim));
        }
        let held = self.sim.blocks.iter().filter(|b| b.is_held());
        let mine = held
            .map(|b| {
                let q = Quantities::for_weights(&self.sim, b.id);
                (b.id, serde_json::to_vec(&q).expect("quantities serialise"))
            })
            .collect();
        let all = self.world.all_blocks(self.sim.blocks.len(), mine)?;
        Ok(BlockState {
            quantities: all
                .iter()
                .map(|b| serde_json::from_slice(b).expect("quantities from a rank of this run"))
                .collect(),
            dry: self.sim.fluid_cells() == 0,
        })
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
    /// chosen for one step first); under ranks, this rank's tasks (a collective).
    pub fn tasks_per_step(&mut self) -> Result<usize> {
        if self.world.is_single() {
            if let Some(p) = self.sim.particles.as_mut() {
                let bodies = p.bodies(self.sim.step);
                p.update_active(1, &bodies);
            }
        } else {
            self.pipe.agree(&mut self.sim, 1)?;
        }
        Ok(self.pipe.tasks_per_step(&self.sim))
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
            if !matches!(ran, Err(crate::error::Error::Aborted { .. })) {
                self.record_run(k as usize)?;
            }
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

    /// The last graph run's times into the interval under way, and the corrector's bookkeeping. (Under
    /// ranks the modeled times are not computed: each rank knows only its share of the graph.)
    fn record_run(&mut self, k: usize) -> Result<()> {
        let Some(run) = self.pipe.last_run() else { return Ok(()) };
        if let Some(m) = self.modeler.as_mut() {
            m.submit(run.owned(), self.log.owners().to_vec(), *self.log.machine());
        }
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
        if self.balancer.as_ref().is_some_and(|b| b.needs_state_after_runs()) {
            let state = self.block_state()?;
            self.balancer.as_mut().expect("checked").after_run(&state, k);
        }
        Ok(())
    }

    /// Closes the interval under way (nothing when no step was taken since the last one); with
    /// `balance`, the balancing step follows: weights, the strategy's owners, migration, the graph recompiled.
    fn close_interval(&mut self, balance: bool) -> Result<()> {
        let step = self.sim.step;
        if step <= self.log.current_mut().start {
            return Ok(());
        }
        if !self.world.is_single() {
            self.gather_interval()?;
        }
        if let Some(m) = self.modeler.as_mut() {
            for t in m.collect() {
                self.log.add_times(t);
            }
        }
        if self.log.close(step, &self.block_load, &self.sim.domain).is_none() {
            return Ok(());
        }
        self.block_load.iter_mut().for_each(|x| *x = 0.0);
        if balance && self.balancer.is_some() {
            let t0 = Instant::now();
            // One rank: the state is kept for the observers too. Under ranks it is a collective, taken
            // only where the live weights need it (the same on every rank).
            let state = if self.balancer.as_ref().is_some_and(|b| b.needs_state()) || self.world.is_single() {
                self.block_state()?
            } else {
                BlockState {
                    quantities: Vec::new(),
                    dry: false,
                }
            };
            if let Some(bal) = self.balancer.as_mut() {
                let load = &self.log.intervals().last().expect("closed above").block_load;
                let dist = bal.rebalance(&state, load, self.log.owners());
                let predicted = predicted_imbalance(bal.last_weights(), &dist.owners, self.log.machine().processes);
                let (moved, bytes) = self.pipe.set_owners(&mut self.sim, dist.owners.clone())?;
                let secs = t0.elapsed().as_secs_f64();
                bal.migrated += moved as u64;
                bal.seconds += secs;
                self.log.reassign(dist.owners, predicted);
                let iv = self.log.last_mut().expect("closed above");
                iv.migrated_blocks = moved as u64;
                iv.migrated_bytes = bytes;
                iv.balance_seconds = secs;
            }
            self.balance_state = Some(state);
        }
        let iv = self.log.intervals().last().expect("closed above").clone();
        let r = self.notify(|o, cx| o.interval_closed(cx, &iv, balance), balance);
        // Only `interval_closed` of this interval sees it.
        self.balance_state = None;
        r
    }

    /// Under ranks: every rank's loads of its own blocks over the interval under way, in block-id order,
    /// and the ranks' task seconds per part, message bytes (summed in rank order) and wall seconds (the
    /// longest), so that every rank closes the same interval and takes the same balancing decision.
    fn gather_interval(&mut self) -> Result<()> {
        let nb = self.sim.blocks.len();
        let held = |b: usize| self.sim.blocks[b].is_held();
        let mine = (0..nb).filter(|&b| held(b)).map(|b| (b, self.block_load[b])).collect();
        self.block_load = self.world.all_block_values(nb, mine)?;
        let cur = self.log.current_mut();
        let mut mine: Vec<f64> = Part::ALL.iter().map(|&p| cur.part_seconds[p]).collect();
        mine.push(cur.message_bytes as f64);
        mine.push(cur.wall_seconds);
        let bytes: Vec<u8> = mine.iter().flat_map(|x| x.to_bits().to_le_bytes()).collect();
        let all: Vec<Vec<f64>> = self
            .world
            .allgather(&bytes)?
            .iter()
            .map(|r| {
                r.chunks_exact(8)
                    .map(|c| f64::from_bits(u64::from_le_bytes(c.try_into().expect("8"))))
                    .collect()
            })
            .collect();
        let n = Part::ALL.len();
        for (i, &p) in Part::ALL.iter().enumerate() {
            cur.part_seconds[p] = all.iter().map(|r| r[i]).sum();
        }
        cur.message_bytes = all.iter().map(|r| r[n] as u64).sum();
        cur.wall_seconds = all.iter().map(|r| r[n + 1]).fold(0.0, f64::max);
        Ok(())
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
            world: &self.world,
            owners: self.pipe.owners(),
            balancer: self.balancer.as_ref(),
            run: if with_run { self.pipe.last_run() } else { None },
            intervals: self.log.intervals(),
            balance_state: self.balance_state.as_ref(),
        };
        let r = observers.iter_mut().try_for_each(|o| f(o.as_mut(), &cx));
        self.observers = observers;
        r
    }
}
