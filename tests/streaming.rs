//! In-place (AA) and pull streaming run the same physics: every scene ends with bitwise the same fluid and
//! particle state under both patterns (the collision's arithmetic is the same and every other stage reads
//! and writes the populations through the pattern's slot map), and AA holds one PDF field per block
//! instead of two.

mod common;
use common::{checksums, timeloop};

/// Scenes small enough for a test, each run for an odd number of steps so the final state is in AA's
/// shifted layout (the harder one to read back), on 2 processes with rebalancing where it has blocks to
/// move.
const SCENES: [(&str, &[&str], u64); 12] = [
    ("channel.toml", &[], 301),
    ("couette.toml", &[], 301),
    ("taylor_green.toml", &["scene.resolution=16"], 41),
    ("cavity.toml", &[], 201),
    ("box.toml", &[], 101),
    ("drag_array.toml", &[], 61),
    ("drag_array.toml", &["particles.boundary=\"sbb\""], 41),
    ("settling_sphere.toml", &[], 81),
    ("calibration.toml", &[], 41),
    (
        "hopper-small.toml",
        &["balance.strategy=\"hilbert\"", "balance.interval=20"],
        61,
    ),
    ("hopper-small.toml", &["run.no_skip=true"], 21),
    (
        "taylor_green.toml",
        &["scene.resolution=16", "fluid.precision=\"f32\""],
        41,
    ),
];

#[test]
fn aa_and_pull_end_bitwise_equal_on_every_scene() {
    for (file, sets, steps) in SCENES {
        let run = |streaming: &str| {
            let mut s: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
            s.push(format!("fluid.streaming=\"{streaming}\""));
            s.push("processes.count=2".into());
            let refs: Vec<&str> = s.iter().map(|s| s.as_str()).collect();
            if sets.iter().any(|s| s.contains("f32")) {
                // f32 through the binary's path (the f64 helper below is typed).
                let mut refs = refs.clone();
                let n = format!("run.steps={steps}");
                refs.push(&n);
                let sum = common::run(file, &refs);
                return (
                    sum.checksum.fluid.clone(),
                    sum.checksum.particles.clone().unwrap_or_default(),
                );
            }
            let mut tl = timeloop(file, &refs);
            tl.advance(steps).expect("stable");
            let (f, p) = checksums(tl.sim());
            (format!("{f:016x}"), format!("{p:016x}"))
        };
        let (aa, pull) = (run("aa"), run("pull"));
        assert_eq!(
            aa, pull,
            "{file} {sets:?}: AA and pull streaming end in different states"
        );
    }
}

#[test]
fn aa_holds_one_pdf_field_per_block() {
    let sets = |s: &'static str| vec!["scene.resolution=16", s];
    let aa = common::sim64("taylor_green.toml", &sets("fluid.streaming=\"aa\""));
    let pull = common::sim64("taylor_green.toml", &sets("fluid.streaming=\"pull\""));
    let bytes =
        |s: &blockflow::physics::simulation::Simulation<f64>| s.blocks.iter().map(|b| b.pdf_bytes()).sum::<usize>();
    assert_eq!(2 * bytes(&aa), bytes(&pull));
}
