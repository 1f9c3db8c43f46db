//! Helpers shared by the integration tests.
#![allow(dead_code)]

use blockflow::app::run::{self, RunOptions};
use blockflow::config::{self, Config, Precision};
use blockflow::physics::simulation::Simulation;
use blockflow::scenes;
use blockflow::timeloop::setup::build_sim;
use blockflow::timeloop::{Recording, TimeLoop};
use std::path::PathBuf;

/// Parses a scene file from configs/ with overrides.
pub fn cfg(file: &str, sets: &[&str]) -> Config {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("configs").join(file);
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    config::load(&path, &sets).expect("valid scene")
}

/// The path of a scene file in configs/, as a command-line argument.
pub fn scene_path(file: &str) -> String {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("configs")
        .join(file)
        .display()
        .to_string()
}

/// A fresh, empty, existing folder under the system temp dir.
pub fn fresh_dir(name: &str) -> PathBuf {
    let d = tmp(name);
    std::fs::create_dir_all(&d).unwrap();
    d
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
    run::run(&c, &opts).expect("run succeeds")
}

/// Builds an f64 simulation of a scene without running it.
pub fn sim64(file: &str, sets: &[&str]) -> Simulation<f64> {
    let c = cfg(file, sets);
    assert_eq!(c.fluid.precision, Precision::F64);
    let s = scenes::build(&c).expect("scene");
    build_sim::<f64>(&c, &s).expect("sim")
}

/// The time loop of a configuration (f64), as `blockflow run` builds it.
pub fn timeloop_of(c: &Config) -> TimeLoop<f64> {
    let s = scenes::build(c).expect("scene");
    TimeLoop::<f64>::from_config(c, &s, Recording::default()).expect("time loop")
}

/// The time loop of a scene file from configs/ with overrides (f64).
pub fn timeloop(file: &str, sets: &[&str]) -> TimeLoop<f64> {
    timeloop_of(&cfg(file, sets))
}

/// Both checksums of a simulation (particles: 0 without bodies).
pub fn checksums(sim: &Simulation<f64>) -> (u64, u64) {
    (
        sim.checksum(),
        sim.particles.as_ref().map_or(0, |p| p.checksum(sim.step)),
    )
}
