//! The task-graph pipeline on virtual processes gives bitwise the same final state as the serial loop,
//! for every process/thread count, pinning, stealing policy and curve assignment (DESIGN.md principle 1).

mod common;
use blockflow::physics::serial;
use common::{sim64, timeloop};

/// Scene settings with at least 24 blocks.
const SCENES: [(&str, &[&str], u64); 2] = [
    (
        "channel.toml",
        &["scene.length=12", "scene.width=8", "domain.blocks=[3,4,2]"],
        24,
    ),
    (
        "taylor_green.toml",
        &["scene.resolution=24", "domain.blocks=[2,3,4]"],
        12,
    ),
];

fn serial_checksum(file: &str, sets: &[&str], steps: u64) -> u64 {
    let mut sim = sim64(file, sets);
    for _ in 0..steps {
        serial::step(&mut sim).expect("stable");
    }
    sim.checksum()
}

#[test]
fn checksums_identical_for_every_process_layout_pinning_stealing_curve_and_pattern() {
    for (file, base, steps) in SCENES {
        // The serial loop under pull streaming is the reference; under AA it gives the same bits.
        let mut pull: Vec<&str> = base.to_vec();
        pull.push("fluid.streaming=\"pull\"");
        let want = serial_checksum(file, &pull, steps);
        assert_eq!(
            serial_checksum(file, base, steps),
            want,
            "{file}: AA serial differs from pull"
        );
        for (k, (p, t)) in [(1, 1), (2, 1), (3, 2), (8, 1), (5, 2)].into_iter().enumerate() {
            for pin in ["none", "compact"] {
                for steal in ["process", "global"] {
                    for curve in ["hilbert", "morton"] {
                        // Both patterns over every combination: the pattern alternates with the process
                        // layout, pinning and stealing, so each pattern meets each value of each option.
                        let aa = (k + usize::from(pin == "none") + usize::from(steal == "global")) % 2 == 0;
                        let streaming = if aa { "aa" } else { "pull" };
                        let mut sets: Vec<String> = base.iter().map(|s| s.to_string()).collect();
                        sets.push(format!("fluid.streaming=\"{streaming}\""));
                        sets.push(format!("processes.count={p}"));
                        sets.push(format!("processes.threads_per_process={t}"));
                        sets.push(format!("processes.pin=\"{pin}\""));
                        sets.push(format!("processes.steal=\"{steal}\""));
                        sets.push(format!("balance.strategy=\"{curve}\""));
                        sets.push("processes.steps_per_graph=5".into());
                        sets.push("balance.interval=10".into());
                        // Weights from the blocks' quantities alone: every run gets the same owners, so
                        // the tasks per step stay those counted before the run.
                        sets.push("balance.weights=\"estimator\"".into());
                        let refs: Vec<&str> = sets.iter().map(|s| s.as_str()).collect();
                        let mut tl = timeloop(file, &refs);
                        assert!(tl.pipeline().owners().iter().all(|&o| (o as usize) < p));
                        let per_step = tl.tasks_per_step().expect("one process") as u64;
                        tl.advance(steps).expect("stable");
                        assert_eq!(tl.sim().step, steps);
                        // every task ran exactly once per step
                        assert_eq!(tl.pipeline().totals().tasks, per_step * steps, "{file} P={p} T={t}");
                        assert_eq!(
                            tl.sim().checksum(),
                            want,
                            "{file}: P={p} T={t} pin={pin} steal={steal} curve={curve} {streaming} differs from the serial loop"
                        );
                    }
                }
            }
        }
    }
}

#[test]
fn cross_process_messages_are_counted() {
    let sets = ["scene.resolution=24", "domain.blocks=[2,3,4]", "processes.count=4"];
    let mut tl = timeloop("taylor_green.toml", &sets);
    tl.advance(4).unwrap();
    let t = tl.pipeline().totals();
    assert!(t.remote_messages > 0 && t.local_copies > 0);
    assert!(t.message_bytes > 0);
}
