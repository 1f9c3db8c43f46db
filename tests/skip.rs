//! `run.no_skip`: running every task on every block changes no bit of the result, and
//! it really runs more tasks, for every skip rule that applies to the scene (DESIGN.md principle 2).

mod common;
use blockflow::io::summary::Summary;
use std::collections::BTreeMap;

/// Scene, steps, and the skip rules that must find work to skip in it (the others find none or do not
/// apply): channel has walls in every block; calibration has blocks above its top wall and every block
/// near a body; the hopper has blocks without walls and blocks no body reaches; granular_box has no
/// fluid at all.
const SCENES: [(&str, u64, &[&str]); 4] = [
    ("channel.toml", 20, &["static_map", "fused_kernel"]),
    ("calibration.toml", 4, &["outside", "static_map", "fused_kernel"]),
    (
        "hopper-small.toml",
        6,
        &["no_boundary", "no_particles", "static_map", "fused_kernel"],
    ),
    ("granular_box.toml", 6, &["outside", "static_map"]),
];

fn run(file: &str, steps: u64, no_skip: bool, extra: &[&str]) -> Summary {
    let mut sets = vec![format!("run.steps={steps}"), format!("run.no_skip={no_skip}")];
    sets.extend(extra.iter().map(|s| s.to_string()));
    let refs: Vec<&str> = sets.iter().map(|s| s.as_str()).collect();
    let s = common::run(file, &refs);
    assert_eq!(s.status, "ok", "{file}");
    assert_eq!(s.no_skip, no_skip);
    s
}

fn total(m: &BTreeMap<String, u64>) -> u64 {
    m.values().sum()
}

#[test]
fn no_skip_gives_bitwise_the_same_state_and_runs_more_tasks_for_every_rule_that_applies() {
    // Rigid-body tasks count once per block they run (grouped phases too), so granular_box's Jacobi
    // solver and the others' block Gauss–Seidel meet the same rules.
    for (file, steps, applies) in SCENES {
        let a = run(file, steps, false, &[]);
        let b = run(file, steps, true, &[]);
        assert_eq!(a.checksum.fluid, b.checksum.fluid, "{file}: fluid checksum");
        assert_eq!(a.checksum.particles, b.checksum.particles, "{file}: particle checksum");
        assert!(a.unskipped_by_rule.is_none());
        let rules = b
            .unskipped_by_rule
            .clone()
            .expect("no-skip runs report the unskipped work");
        for r in blockflow::pipeline::SkipRule::ALL.map(blockflow::pipeline::SkipRule::name) {
            let n = rules[r];
            if applies.contains(&r) {
                assert!(n > 0, "{file}: rule {r} skipped nothing");
            } else {
                assert_eq!(n, 0, "{file}: rule {r} was not expected to apply");
            }
        }
        // Every task kind runs at least as often without the skip rules, every block runs a sweep, a
        // boundary pass and a static re-mapping every step, and every extra task is owed to one rule.
        let blocks = (a.blocks as u64) * steps;
        for (k, &n) in &a.tasks_by_kind {
            let m = b.tasks_by_kind.get(k).copied().unwrap_or(0);
            assert!(m >= n, "{file}: {k}: {m} tasks with --no-skip, {n} without");
        }
        for k in ["sweep", "boundary", "static_map", "comm"] {
            assert_eq!(b.tasks_by_kind[k], blocks, "{file}: {k}");
        }
        assert_eq!(a.tasks_by_kind.get("static_map"), None, "{file}");
        let extra = total(&b.tasks_by_kind) - total(&a.tasks_by_kind);
        let owed: u64 = rules.iter().filter(|(r, _)| *r != "fused_kernel").map(|(_, n)| n).sum();
        assert_eq!(extra, owed, "{file}: extra tasks against the rules' counts");
        assert!(extra > 0, "{file}");
        // The kinds behind each rule that applies: strictly more tasks.
        let more =
            |k: &str| b.tasks_by_kind.get(k).copied().unwrap_or(0) > a.tasks_by_kind.get(k).copied().unwrap_or(0);
        if applies.contains(&"outside") {
            assert!(
                more("sweep") && more("comm"),
                "{file}: outside blocks got no sweep/comm"
            );
        }
        if applies.contains(&"no_boundary") {
            assert!(more("boundary"), "{file}: no extra boundary tasks");
        }
        if applies.contains(&"no_particles") {
            assert!(
                more("rb") && more("rb_sync") && more("map") && more("forces"),
                "{file}: no extra particle tasks"
            );
        }
        if applies.contains(&"fused_kernel") {
            assert_eq!(
                rules["fused_kernel"], a.tasks_by_kind["sweep"],
                "{file}: every fluid sweep on the general path"
            );
        }
    }
}

/// The no-skip run on two virtual processes (cross-process messages, blocks migrated between them by
/// METIS every two steps, blocks without fluid or body on either side) still ends bitwise where the
/// default run on one process does.
#[test]
fn no_skip_on_two_processes_with_migration_matches_the_default_run() {
    for file in ["hopper-small.toml", "calibration.toml"] {
        let a = run(file, 6, false, &[]);
        let sets = ["processes.count=2", "balance.strategy=\"metis\"", "balance.interval=2"];
        let b = run(file, 6, true, &sets);
        assert_eq!(a.checksum.fluid, b.checksum.fluid, "{file}");
        assert_eq!(a.checksum.particles, b.checksum.particles, "{file}");
        assert!(
            b.tasks_by_kind.get("send").copied().unwrap_or(0) > 0,
            "{file}: two processes exchange messages"
        );
        let moved = b.balance.as_ref().map_or(0, |x| x.migrated_blocks);
        assert!(moved > 0, "{file}: no block migrated");
    }
}
