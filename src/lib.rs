//! blockflow: geometrically resolved particulate flow on blocks.
//!
//! The library joins the per-block numerics of `blockflow-kernels` with the scheduling of
//! `blockflow-scheduler`, in layers that import only downwards (the folder tree shows them):
//!
//! 1. vocabulary: [`util`] (hashing, atomic files, byte codecs, statistics), [`error`], [`config`];
//! 2. state and scenes: [`physics`] (domain, geometry, blocks, fluid stages, rigid bodies, coupling, the
//!    simulation), [`scenes`] (what each scene builds and observes);
//! 3. mechanics and models: [`ranks`] (the ranks a run is spread over and their block-ordered
//!    collectives), [`pipeline`] (the time step as a task graph), [`metrics`] (loads, edge cut, modeled
//!    time, intervals), [`estimator`] (the workload model of section 3), [`balance`] (strategies and the
//!    balancing step of section 4), [`serialise`] (the one block format), [`io`] (outputs);
//! 4. a run: [`timeloop`] (the time loop that owns simulation, pipeline, balancer and observers),
//!    [`study`] (the counterfactual replay of section 4.3), [`checkpoint`];
//! 5. [`app`]: the commands; nothing imports it.

#![warn(missing_docs)]

pub mod config;
pub mod error;
pub mod util;

pub mod physics;
pub mod scenes;

pub mod ranks;

pub mod balance;
pub mod estimator;
pub mod io;
pub mod metrics;
pub mod pipeline;
pub mod serialise;

pub mod checkpoint;
pub mod study;
pub mod timeloop;

pub mod app;
