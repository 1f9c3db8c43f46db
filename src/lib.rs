//! blockflow: geometrically resolved particulate flow on blocks.
//!
//! The library joins the per-block numerics of `blockflow-kernels` with the scheduling of
//! `blockflow-scheduler`: configuration ([`config`]), the block domain and its geometry ([`domain`],
//! [`geometry`], [`block`]), the per-block stages of a time step ([`fluid`]), the time loop ([`sim`]),
//! scenes ([`scenes`]), output ([`io`]) and the command line ([`cli`]).

pub mod balance;
pub mod bench_accuracy;
pub mod bench_kernel;
pub mod bench_rigid;
pub mod bench_scheduler;
pub mod bench_skip;
pub mod block;
pub mod calibrate;
pub mod checkpoint;
pub mod cli;
pub mod config;
pub mod coupling;
pub mod domain;
pub mod error;
pub mod estimator;
pub mod fluid;
pub mod geometry;
pub mod io;
pub mod particles;
pub mod pipeline;
pub mod run_setup;
pub mod runner;
pub mod scenes;
pub mod serialise;
pub mod sim;
pub mod stress;
pub mod study;
pub mod sweep;
