//! blockflow-scheduler: virtual processes of pinned worker threads that run a task graph.
//!
//! Knows nothing of fluids: tasks are opaque ids with an owner process, a part label and a block label.
//! The caller builds a [`graph::TaskGraph`] once per block layout and runs it as often as it likes; every
//! task execution is timed ([`graph::TaskRecord`]).

pub mod executor;
pub mod graph;
pub mod replay;
pub mod topology;
pub mod trace;
pub mod transport;

pub use graph::{GraphBuilder, TaskGraph, TaskId, TaskRecord, TaskSpec};
