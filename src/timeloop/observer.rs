//! Observers of a run: what the time loop calls between graph runs (waLBerla's after-functions,
//! taskflow's `ObserverInterface`). Outputs, checkpoints, progress, calibration samples and the study's
//! counterfactual replay are observers; none of them can change a number of the simulation.

use crate::balance::weights::BlockState;
use crate::balance::Balancer;
use crate::error::{Error, Result};
use crate::metrics::interval::IntervalStats;
use crate::physics::simulation::Simulation;
use crate::pipeline::RunRecord;
use blockflow_kernels::Real;
use std::any::Any;
use std::marker::PhantomData;

/// What an observer sees: the state, the assignment, the balancer, the finished intervals and, after a
/// graph run, that run's record.
pub struct RunContext<'a, T: Real> {
    /// The simulation (the state after the last graph run; under ranks, this rank's blocks of it).
    pub sim: &'a Simulation<T>,
    /// The ranks the run is spread over: a view of the whole state under ranks is a collective (every
    /// rank's observer calls it at the same point; [`crate::ranks`]).
    pub world: &'a crate::ranks::World,
    /// The owner process of every block now.
    pub owners: &'a [u32],
    /// The live balancer (absent: the assignment never changes).
    pub balancer: Option<&'a Balancer>,
    /// The graph run that just ended (in [`Observer::after_run`] and [`Observer::interval_closed`]).
    pub run: Option<RunRecord<'a>>,
    /// The finished intervals of the live assignment.
    pub intervals: &'a [IntervalStats],
    /// In [`Observer::interval_closed`] after a balancing step: the blocks' state the live balancer
    /// weighed them by, taken before its migration (a migrated block's mapping averages start again
    /// after the move, so the state after it is not the one the decision saw).
    pub balance_state: Option<&'a BlockState>,
}

/// Whether the time loop goes on after an observer was called.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Flow {
    /// Go on.
    Continue,
    /// Stop after this graph run (e.g. a signal asked for it).
    Stop,
}

/// How a run ended, for [`Observer::finish`].
#[derive(Debug)]
pub enum RunEnd<'a> {
    /// Every step asked for was taken.
    Done,
    /// An observer stopped the run before its end ([`Flow::Stop`]).
    Stopped,
    /// A graph run failed (unstable fluid or bodies); the state is the one after that run.
    Failed(&'a Error),
}

/// An observer of a run. Every method has a default that does nothing.
///
/// Per graph run the time loop calls [`Observer::after_run`] (the run's records) and, at the end of a
/// balancing interval, after the live balancing step, [`Observer::interval_closed`]; at every stop (a
/// step some observer asked for, [`Observer::next_stop`], or `processes.steps_per_graph` steps after the
/// last stop) [`Observer::at_stop`]. [`Observer::finish`] comes once at the end, after the last (partial)
/// interval was closed.
pub trait Observer<T: Real>: Any {
    /// The first step after `step` at which this observer needs to see the state: the time loop stops
    /// there ([`Observer::at_stop`]; `None`: any stop will do).
    fn next_stop(&self, _step: u64) -> Option<u64> {
        None
    }
    /// A graph run ended: `cx.run` holds its records, `cx.sim` the state after it; the interval it
    /// belongs to is still open.
    fn after_run(&mut self, _cx: &RunContext<'_, T>) -> Result<()> {
        Ok(())
    }
    /// An interval was closed (`interval` is its record, the live migration included). `balanced`: a
    /// balancing step follows it (false for the partial interval closed when the run ends).
    fn interval_closed(&mut self, _cx: &RunContext<'_, T>, _interval: &IntervalStats, _balanced: bool) -> Result<()> {
        Ok(())
    }
    /// The time loop stopped (after any balancing step): the state the next graph run starts from.
    /// Return [`Flow::Stop`] to end the run here.
    fn at_stop(&mut self, _cx: &RunContext<'_, T>) -> Result<Flow> {
        Ok(Flow::Continue)
    }
    /// The run ended (`end` says how).
    fn finish(&mut self, _cx: &RunContext<'_, T>, _end: &RunEnd<'_>) -> Result<()> {
        Ok(())
    }
}

/// A typed handle of an observer added to a time loop, to read it back after the run.
pub struct Handle<O> {
    pub(super) index: usize,
    pub(super) marker: PhantomData<fn() -> O>,
}

impl<O> Clone for Handle<O> {
    fn clone(&self) -> Self {
        *self
    }
}

impl<O> Copy for Handle<O> {}

/// Downcasts an observer to its type.
pub(super) fn downcast<T: Real, O: Observer<T>>(o: &dyn Observer<T>) -> &O {
    let any: &dyn Any = o;
    any.downcast_ref::<O>().expect("a handle names an observer of its type")
}
