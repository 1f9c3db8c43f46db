//! Dynamic load balancing: every strategy keeps the result bitwise, blocks really move, the
//! counterfactual replay of the live strategy reproduces the live run's load imbalance series exactly,
//! and a test-sized `blockflow study` writes its table and figures.
//! Run with `cargo test --release --test balancing`.

mod common;

use blockflow::app::study::{study, StudyOptions};
use blockflow::balance::Balancer;
use blockflow::metrics::cost_model::Machine;
use blockflow::study::{Candidate, Counterfactual};
use blockflow::timeloop::setup::{coefficients, InitialAssignment};
use common::{cfg, timeloop_of, tmp};

/// Runs hopper-small with `sets` through the time loop of `blockflow run`, with a counterfactual of the
/// run's own strategy attached; returns the checksums, the live LI series, the replayed LI series and the
/// blocks moved.
fn live(sets: &[&str], steps: u64) -> ((u64, u64), Vec<f64>, Vec<f64>, u64) {
    let c = cfg("hopper-small.toml", sets);
    let mut tl = timeloop_of(&c);
    let name = format!("{:?}", c.balance.strategy).to_lowercase();
    let coeffs = coefficients(&c).unwrap();
    let init = InitialAssignment::of(&c, tl.sim(), coeffs.as_ref());
    let machine = Machine {
        processes: c.processes.count,
        threads: c.processes.threads_per_process,
        global: false,
        comm: Default::default(),
    };
    let balancer = Balancer::of(&c.balance, c.processes.count, coeffs, &tl.sim().domain);
    let cf = tl.add_observer(Counterfactual::new(
        vec![Candidate::new(&name, balancer, init.owners, &init.weights, machine)],
        &c,
    ));
    tl.advance(steps).expect("stable");
    tl.finish(&blockflow::timeloop::RunEnd::Done).unwrap();
    let li: Vec<f64> = tl.intervals().iter().map(|i| i.imbalance).collect();
    let replayed: Vec<f64> = tl.observer(cf).candidates[0]
        .intervals()
        .iter()
        .map(|i| i.imbalance)
        .collect();
    let moved = tl.intervals().iter().map(|i| i.migrated_blocks).sum();
    (common::checksums(tl.sim()), li, replayed, moved)
}

/// For every strategy, hopper-small rebalanced every 50 steps on P = 9 gives the checksums of the static
/// run, blocks did move (migrated through the block serialisation), and the replay of the strategy on
/// the run's own task times gives its load-imbalance series bit for bit.
#[test]
fn every_strategy_moves_blocks_and_keeps_the_result_bitwise() {
    let steps = 200;
    let base = [
        "processes.count=9",
        "balance.interval=50",
        "processes.steps_per_graph=5",
    ];
    let mut sets = base.to_vec();
    sets.push("balance.strategy=\"none\"");
    let (want, li0, replay0, moved0) = live(&sets, steps);
    assert_eq!(moved0, 0);
    assert_eq!(li0.len(), 4);
    assert_eq!(
        li0.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
        replay0.iter().map(|x| x.to_bits()).collect::<Vec<_>>()
    );
    for (strategy, weights) in [
        ("hilbert", "measured"),
        ("morton", "measured"),
        ("diffusive", "measured"),
        ("metis", "measured"),
        ("hilbert", "corrected"),
    ] {
        let st = format!("balance.strategy=\"{strategy}\"");
        let w = format!("balance.weights=\"{weights}\"");
        let mut sets = base.to_vec();
        sets.push(&st);
        sets.push(&w);
        let (got, li, replayed, moved) = live(&sets, steps);
        assert_eq!(got, want, "{strategy}/{weights}: checksums differ from the static run");
        assert!(moved > 0, "{strategy}/{weights}: no block moved");
        assert_eq!(
            li.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
            replayed.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
            "{strategy}/{weights}: replayed LI {replayed:?} vs live {li:?}"
        );
    }
}

/// A test-sized study: every strategy gets a row, `none` is the reference (0 %), the strategies see the
/// same per-block work (the sum of the per-process loads is identical), and the table, CSV, JSON and both
/// figures are written.
#[test]
fn test_sized_study_writes_table_and_figures() {
    let out = tmp("study");
    let opts = StudyOptions {
        scene: std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("configs/hopper-small.toml"),
        sets: vec!["balance.interval=25".into()],
        processes: 6,
        threads_per_process: 1,
        strategies: ["none", "hilbert", "morton", "diffusive", "metis", "steal-global"]
            .iter()
            .map(|s| s.to_string())
            .collect(),
        weights: Some(blockflow::config::Weights::Measured),
        steps: Some(100),
        live: false,
        live_rounds: 1,
        out: out.clone(),
        record_threads: Some(2),
    };
    let r = study(&opts).unwrap();
    assert_eq!(r.strategies.len(), 6);
    assert_eq!(r.strategies[0].name, "none");
    assert_eq!(r.strategies[0].relative_runtime, 0.0);
    let total = |i: usize, k: usize| r.strategies[k].intervals[i].process_load.iter().sum::<f64>();
    for (k, s) in r.strategies.iter().enumerate() {
        assert_eq!(s.intervals.len(), 4, "{}", s.name);
        for i in 0..4 {
            let (a, b) = (total(i, 0), total(i, k));
            // The same block loads summed in another grouping: equal to rounding.
            assert!((a - b).abs() <= 1e-12 * a, "{} interval {i}: {a} vs {b}", s.name);
        }
        assert!(s.graph_seconds > 0.0 && s.bsp_seconds > 0.0, "{}", s.name);
    }
    let moved: u64 = r.strategies.iter().map(|s| s.migrated_blocks).sum();
    assert!(moved > 0, "no strategy moved a block");
    // A balancing step is its partition, its graph recompile (exactly when blocks moved: compiling a
    // graph takes CPU time) and its migration, and nothing else.
    for s in &r.strategies {
        for iv in &s.intervals {
            assert_eq!(iv.recompile_seconds > 0.0, iv.migrated_blocks > 0, "{}", s.name);
            let parts = iv.partition_seconds + iv.recompile_seconds + iv.migration_seconds;
            assert!((iv.balance_seconds - parts).abs() <= 1e-15 * parts, "{}", s.name);
        }
    }
    for f in [
        "table3.md",
        "table3.csv",
        "study.json",
        "study_intervals.csv",
        "figure10.png",
        "figure11.png",
    ] {
        let p = out.join(f);
        assert!(
            std::fs::metadata(&p).is_ok_and(|m| m.len() > 0),
            "{} missing",
            p.display()
        );
    }
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("study.json")).unwrap()).unwrap();
    for key in [
        "relative_runtime",
        "balance_fraction",
        "edge_cut_mean",
        "imbalance_median",
        "migrated_blocks",
    ] {
        assert!(json["strategies"][1][key].is_number(), "study.json: {key}");
    }
}

/// The measured block loads (eq. 16) account for every task's CPU time exactly once: under Jacobi one
/// `rb` task runs the sweep round of a group of blocks and its time is shared among them (by each
/// member's time on the monotonic clock), so the loads of all blocks sum to the CPU time of the run's
/// workload tasks, to rounding (1e-12 relative).
#[test]
fn block_loads_share_grouped_rounds_without_loss() {
    use blockflow::physics::parts::Part;
    let c = cfg(
        "hopper-small.toml",
        &["processes.steps_per_graph=4", "particles.solver=\"jacobi\""],
    );
    let mut tl = timeloop_of(&c);
    tl.advance(40).expect("stable");
    let run = tl.pipeline().last_run().expect("a graph ran");
    let tasks: f64 = run
        .graph
        .specs()
        .iter()
        .zip(run.durations_ns)
        .filter(|(s, _)| Part::from_index(s.part).is_workload())
        .map(|(_, &ns)| ns as f64 * 1e-9)
        .sum();
    let rb_tasks = run
        .graph
        .specs()
        .iter()
        .filter(|s| Part::from_index(s.part) == Part::RigidBody)
        .count();
    let phases = tl.sim().particles.as_ref().unwrap().phases() as usize;
    let active = tl
        .sim()
        .particles
        .as_ref()
        .unwrap()
        .active
        .iter()
        .filter(|&&a| a)
        .count();
    assert!(rb_tasks < run.steps * phases * active, "some sweep rounds run grouped");
    let loads: f64 = run.block_load.iter().sum();
    assert!(
        (loads - tasks).abs() <= 1e-12 * tasks,
        "block loads {loads} s, tasks {tasks} s"
    );
}
