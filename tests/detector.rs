//! The instability detector: a NaN injected at a known cell and step is reported at
//! exactly that step and cell, through the task graph on any number of processes; a known-unstable
//! setting ends `"unstable"`, a stable setting near the edge ends `"ok"`.
//! Run with `cargo test --release --test detector`.

mod common;

use blockflow::app::run::{self, RunOptions};
use blockflow::error::Error;
use common::{cfg, timeloop};

/// Runs taylor_green 10 steps, writes NaN into every population of global cell `cell` of the state, and
/// advances again: the detector must name step 11, the block holding the cell and the cell itself.
fn inject(sets: &[&str], cell: [usize; 3]) {
    let mut tl = timeloop("taylor_green.toml", sets);
    tl.advance(10).expect("stable before the injection");
    let sim = tl.sim();
    let block = (0..sim.blocks.len())
        .find(|&b| {
            let o = sim.blocks[b].origin;
            let s = sim.blocks[b].layout.size;
            (0..3).all(|a| cell[a] >= o[a] && cell[a] < o[a] + s[a])
        })
        .unwrap();
    let b = &sim.blocks[block];
    let l = [0, 1, 2].map(|a| cell[a] - b.origin[a] + 1);
    // SAFETY: no task runs between graph runs.
    let f = unsafe { b.field_mut(sim.parity()) };
    let i = b.layout.idx(l[0], l[1], l[2]);
    for q in 0..blockflow_kernels::d3q19::Q {
        f.set(q, i, f64::NAN);
    }
    match tl.advance(20) {
        Err(Error::Unstable(e)) => {
            assert_eq!(e.step, 11, "{sets:?}: {e}");
            assert_eq!(e.block, block, "{sets:?}: {e}");
            assert_eq!(e.cell, cell, "{sets:?}: {e}");
            assert!(e.density.is_nan(), "{sets:?}: {e}");
        }
        other => panic!("{sets:?}: the NaN went unreported: {:?}", other.err()),
    }
}

#[test]
fn injected_nan_is_reported_at_its_step_and_cell() {
    for sets in [
        &["processes.steps_per_graph=1"][..],
        &["processes.steps_per_graph=1", "processes.count=3"][..],
        &[
            "processes.steps_per_graph=1",
            "processes.count=2",
            "processes.threads_per_process=2",
        ][..],
    ] {
        // Cells well inside a block (the 32³ box has 16³ blocks) and one in the last block.
        for cell in [[5, 7, 3], [20, 25, 9], [27, 18, 28]] {
            inject(sets, cell);
        }
    }
}

/// τ = 0.5001 with a fast vortex (Re = 10 000 at N = 32) blows up and is reported `"unstable"`; the same
/// vortex at τ = 0.51 with Re = 50 (ν = 0.0033, u0 = 0.0052) stays `"ok"` over the whole decay time.
#[test]
fn unstable_settings_are_unstable_and_stable_ones_ok() {
    let out = std::env::temp_dir().join(format!("blockflow-detector-{}", std::process::id()));
    let bad = cfg(
        "taylor_green.toml",
        &["fluid.tau=0.5001", "scene.reynolds=100000.0", "run.steps=3000"],
    );
    let opts = RunOptions {
        out: Some(out.join("bad")),
        ..Default::default()
    };
    let r = run::run(&bad, &opts);
    assert!(matches!(r, Err(Error::Unstable(_))), "{:?}", r.map(|s| s.status));
    let s = std::fs::read_to_string(out.join("bad/summary.json")).unwrap();
    assert!(s.contains("\"status\": \"unstable\"") && !s.contains("\"status\": \"ok\""));
    let good = cfg("taylor_green.toml", &["fluid.tau=0.51", "scene.reynolds=50.0"]);
    let opts = RunOptions {
        out: Some(out.join("good")),
        ..Default::default()
    };
    let s = run::run(&good, &opts).expect("stable");
    assert_eq!(s.status, "ok");
    std::fs::remove_dir_all(&out).ok();
}

/// A stability map keeps the three outcomes apart: the cavity at N = 8 is stable at Re = 100, blows up at
/// Re = 10⁵ (τ − ½ = 2.4e-5) with the step named, and a lid speed the scene refuses (0.45 ≥ 0.4) is drawn
/// `refused` instead of stopping the map.
#[test]
fn stress_map_tells_stable_unstable_and_refused_apart() {
    use blockflow::app::stress::{stress, StressOptions};
    use blockflow::io::plots::scan::Outcome;
    let out = std::env::temp_dir().join(format!("blockflow-stress-{}", std::process::id()));
    let opts = StressOptions {
        scene: std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("configs/cavity.toml"),
        vary: vec![
            ("scene.reynolds".into(), vec!["100".into(), "100000".into()]),
            ("scene.lid_velocity".into(), vec!["0.1".into(), "0.45".into()]),
        ],
        sets: vec!["scene.resolution=8".into()],
        steps: Some(400),
        out: out.clone(),
        ..Default::default()
    };
    let r = stress(&opts).expect("map");
    // Rows run the first key slowest: (100, 0.1), (100, 0.45), (1e5, 0.1), (1e5, 0.45).
    assert_eq!(r.outcomes[0], Outcome::Stable);
    assert_eq!(r.outcomes[1], Outcome::Refused);
    assert!(
        matches!(r.outcomes[2], Outcome::Unstable(Some(s)) if s <= 400),
        "{:?}",
        r.outcomes[2]
    );
    assert_eq!(r.outcomes[3], Outcome::Refused);
    assert!(r.scan.rows[1]
        .message
        .as_deref()
        .is_some_and(|m| m.contains("lid_velocity")));
    assert!(out.join("stress.png").exists() && out.join("stress.csv").exists());
    std::fs::remove_dir_all(&out).ok();
}
