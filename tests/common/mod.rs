//! Helpers shared by the integration tests.
#![allow(dead_code)]

use blockflow::config::{self, Config, Precision};
use blockflow::runner::{self, RunOptions};
use blockflow::scenes;
use blockflow::sim::Simulation;
use std::path::PathBuf;

/// Parses a scene file from configs/ with overrides.
pub fn cfg(file: &str, sets: &[&str]) -> Config {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("configs").join(file);
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    config::load(&path, &sets).expect("valid scene")
}

/// A fresh output folder under the system temp dir.
pub fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("blockflow-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// Runs a scene to the end through the same path as `blockflow run`; returns its summary.
pub fn run(file: &str, sets: &[&str]) -> blockflow::io::summary::Summary {
    let c = cfg(file, sets);
    let opts = RunOptions {
        out: Some(tmp(&format!(
            "{file}-{}",
            sets.join("_").replace(['/', '[', ']', ',', '='], "-")
        ))),
        ..Default::default()
    };
    runner::run(&c, &opts).expect("run succeeds")
}

/// Builds an f64 simulation of a scene without running it.
pub fn sim64(file: &str, sets: &[&str]) -> Simulation<f64> {
    let c = cfg(file, sets);
    assert_eq!(c.fluid.precision, Precision::F64);
    let s = scenes::build(&c).expect("scene");
    runner::build_sim::<f64>(&c, &s).expect("sim")
}
