//! Ranks that share no memory (in-process loopback): each rank holds only its own blocks, everything
//! between ranks is a message, and the final state is bitwise the one of the same scene on one process.

mod common;
use blockflow::config::Config;
use blockflow::physics::serial;
use blockflow::ranks::{run_loopback, World};
use blockflow::scenes;
use blockflow::timeloop::{Recording, TimeLoop};
use blockflow_scheduler::transport::Delays;
use common::{cfg, checksums, sim64, timeloop_of};
use std::sync::Arc;
use std::time::Duration;

/// Both checksums (summed over the ranks) and the total steps after `steps` steps of `c` on `ranks`
/// ranks, with optional message delays.
fn on_ranks(c: &Config, ranks: usize, steps: u64, delays: Option<Delays>) -> (u64, u64) {
    let mut c = c.clone();
    c.processes.count = ranks;
    let out = run_loopback(ranks, delays, |w: World| {
        let w = Arc::new(w);
        let scene = scenes::build(&c).expect("scene");
        let mut tl = TimeLoop::<f64>::on_world(&c, &scene, Recording::default(), w.clone()).expect("time loop");
        tl.advance(steps).expect("stable");
        assert_eq!(tl.sim().step, steps);
        // Each rank holds exactly its own blocks.
        let me = w.rank() as u32;
        for b in &tl.sim().blocks {
            assert_eq!(
                b.is_held(),
                tl.pipeline().owners()[b.id] == me,
                "block {} on rank {me}",
                b.id
            );
        }
        let (f, p) = checksums(tl.sim());
        let mut v = [f, p];
        w.sum(&mut v).expect("sum");
        (v[0], v[1])
    });
    assert!(out.windows(2).all(|w| w[0] == w[1]), "every rank has the same sums");
    out[0]
}

#[test]
fn fluid_scenes_on_ranks_equal_the_serial_loop() {
    let scenes: [(&str, &[&str], u64); 2] = [
        (
            "channel.toml",
            &["scene.length=12", "scene.width=8", "domain.blocks=[3,4,2]"],
            12,
        ),
        (
            "taylor_green.toml",
            &["scene.resolution=24", "domain.blocks=[2,3,4]"],
            9,
        ),
    ];
    for (file, sets, steps) in scenes {
        let mut sim = sim64(file, sets);
        for _ in 0..steps {
            serial::step(&mut sim).expect("stable");
        }
        let want = sim.checksum();
        for ranks in [1, 2, 3, 5] {
            for t in [1, 2] {
                let mut s: Vec<String> = sets.iter().map(|x| x.to_string()).collect();
                s.push(format!("processes.threads_per_process={t}"));
                s.push("processes.steps_per_graph=4".into());
                let refs: Vec<&str> = s.iter().map(|x| x.as_str()).collect();
                let (f, _) = on_ranks(&cfg(file, &refs), ranks, steps, None);
                assert_eq!(f, want, "{file} on {ranks} ranks x {t} threads");
            }
        }
    }
}

#[test]
fn particulate_scenes_on_ranks_equal_one_process() {
    let scenes: [(&str, &[&str], u64); 3] = [
        ("hopper-small.toml", &[], 60),
        ("granular_box.toml", &["particles.solver=\"block_gauss_seidel\""], 80),
        ("granular_box.toml", &["particles.iterations=4"], 80), // Jacobi, as the file sets
    ];
    for (file, sets, steps) in scenes {
        let c = cfg(file, sets);
        let mut tl = timeloop_of(&c);
        tl.advance(steps).expect("stable");
        let want = checksums(tl.sim());
        for ranks in [1, 2, 3] {
            assert_eq!(on_ranks(&c, ranks, steps, None), want, "{file} on {ranks} ranks");
        }
    }
}

#[test]
fn seeded_message_delays_change_nothing() {
    // Block Gauss–Seidel, and Jacobi, whose sweep rounds run grouped on the blocks away from other ranks.
    for sets in [&[][..], &["particles.solver=\"jacobi\""][..]] {
        let c = cfg("hopper-small.toml", sets);
        let mut tl = timeloop_of(&c);
        tl.advance(24).expect("stable");
        let want = checksums(tl.sim());
        for seed in [3, 11] {
            let d = Delays {
                seed,
                max: Duration::from_micros(200),
            };
            assert_eq!(on_ranks(&c, 3, 24, Some(d)), want, "{sets:?}, seed {seed}");
        }
    }
}

#[test]
fn periodic_axes_with_one_or_two_blocks_on_ranks() {
    // Taylor–Green is periodic on every axis: one block along z (a block is its own neighbour) and two
    // along y (the neighbour on both sides is the same block).
    let sets = ["scene.resolution=16", "domain.blocks=[4,2,1]"];
    let mut sim = sim64("taylor_green.toml", &sets);
    for _ in 0..8 {
        serial::step(&mut sim).expect("stable");
    }
    let want = sim.checksum();
    for ranks in [2, 3] {
        assert_eq!(
            on_ranks(&cfg("taylor_green.toml", &sets), ranks, 8, None).0,
            want,
            "{ranks} ranks"
        );
    }
    // Spheres in a box periodic along x and y with two blocks along x.
    let c = cfg(
        "granular_box.toml",
        &["domain.blocks=[2,1,2]", "domain.block_size=[16,32,32]"],
    );
    let mut tl = timeloop_of(&c);
    tl.advance(40).expect("stable");
    let want = checksums(tl.sim());
    assert_eq!(on_ranks(&c, 3, 40, None), want);
}

#[test]
fn blocks_migrate_between_ranks_without_changing_the_result() {
    let base = ["processes.steps_per_graph=4", "balance.interval=20"];
    let c = cfg("hopper-small.toml", &base);
    let mut tl = timeloop_of(&c);
    tl.advance(120).expect("stable");
    let want = checksums(tl.sim());
    for strategy in ["hilbert", "diffusive", "metis"] {
        let mut s: Vec<String> = base.iter().map(|x| x.to_string()).collect();
        s.push(format!("balance.strategy=\"{strategy}\""));
        s.push("balance.weights=\"measured\"".into());
        let refs: Vec<&str> = s.iter().map(|x| x.as_str()).collect();
        let mut c = cfg("hopper-small.toml", &refs);
        c.processes.count = 3;
        let out = run_loopback(3, None, |w: World| {
            let w = Arc::new(w);
            let scene = scenes::build(&c).expect("scene");
            let mut tl = TimeLoop::<f64>::on_world(&c, &scene, Recording::default(), w.clone()).expect("time loop");
            tl.advance(120).expect("stable");
            let moved = tl.balancer().map_or(0, |b| b.migrated);
            let me = w.rank() as u32;
            for b in &tl.sim().blocks {
                assert_eq!(b.is_held(), tl.pipeline().owners()[b.id] == me);
            }
            let (f, p) = checksums(tl.sim());
            let mut v = [f, p];
            w.sum(&mut v).expect("sum");
            (moved, (v[0], v[1]), tl.pipeline().owners().to_vec())
        });
        assert!(out.windows(2).all(|w| w[0] == w[1]), "{strategy}: every rank agrees");
        let (moved, sums, _) = &out[0];
        assert!(*moved > 0, "{strategy}: blocks moved");
        assert_eq!(*sums, want, "{strategy} on 3 ranks");
    }
}

// Through the binary: `blockflow run --ranks R`.

fn blockflow(args: &[&str]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_blockflow"))
        .args(args)
        .output()
        .expect("binary runs")
}

fn run_ok(args: &[&str]) {
    let mut a = vec!["run"];
    a.extend_from_slice(args);
    let r = blockflow(&a);
    assert!(
        r.status.success(),
        "blockflow {a:?}: {}",
        String::from_utf8_lossy(&r.stderr)
    );
}

fn read(p: &std::path::Path) -> Vec<u8> {
    std::fs::read(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

#[test]
fn a_run_on_ranks_writes_the_outputs_and_checkpoint_of_the_same_run_on_processes() {
    let dir = common::tmp("ranks-outputs");
    let hopper = common::scene_path("hopper-small.toml");
    // The same output folder for both, so that the checkpoints' configurations agree.
    let out = dir.join("run");
    let o = out.display().to_string();
    let args = [
        "--steps",
        "120",
        "--vtk",
        "60",
        "--checkpoint-every",
        "120",
        "--balance",
        "none",
        "--out",
        &o,
    ];
    let mut saved = Vec::new();
    for layout in [["--processes", "3"], ["--ranks", "3"]] {
        let mut a = vec![hopper.as_str()];
        a.extend_from_slice(&layout);
        a.extend_from_slice(&args);
        run_ok(&a);
        let s: serde_json::Value = serde_json::from_slice(&read(&out.join("summary.json"))).unwrap();
        let files: Vec<Vec<u8>> = [
            "checkpoints/step-120",
            "series.csv",
            "particles.csv",
            "vtk/step_00000120/block_00037.vti",
            "vtk/step_00000120.vtm",
            "particles.pvd",
        ]
        .iter()
        .map(|f| read(&out.join(f)))
        .collect();
        saved.push((
            s["checksum"].clone(),
            s["observables"].clone(),
            s["fluid_cells"].clone(),
            files,
        ));
    }
    assert_eq!(saved[0].0, saved[1].0, "checksums");
    assert_eq!(saved[0].1, saved[1].1, "observables");
    assert_eq!(saved[0].2, saved[1].2, "fluid cells");
    for (k, (a, b)) in saved[0].3.iter().zip(&saved[1].3).enumerate() {
        assert!(a == b, "output file {k} differs between 3 processes and 3 ranks");
    }
    let s: serde_json::Value = serde_json::from_slice(&read(&out.join("summary.json"))).unwrap();
    assert_eq!((s["ranks"].as_u64(), s["processes"].as_u64()), (Some(3), Some(3)));
    assert!(s["balance"]["remote_messages"].as_u64().unwrap() > 0);
}

#[test]
fn checkpoints_restart_on_any_number_of_ranks_or_processes() {
    let dir = common::tmp("ranks-restart");
    let hopper = common::scene_path("hopper-small.toml");
    let straight = dir.join("straight").display().to_string();
    let base = ["--set", "balance.strategy=\"hilbert\"", "--interval", "40"];
    let mut a = vec![
        hopper.as_str(),
        "--steps",
        "160",
        "--processes",
        "2",
        "--out",
        &straight,
    ];
    a.extend_from_slice(&base);
    run_ok(&a);
    let want: serde_json::Value = serde_json::from_slice(&read(&dir.join("straight").join("summary.json"))).unwrap();
    for (first, second) in [
        (["--ranks", "3"], ["--ranks", "2"]),
        (["--ranks", "2"], ["--processes", "3"]),
        (["--processes", "1"], ["--ranks", "3"]),
    ] {
        let half = dir.join(format!("half-{}", first.join("")));
        let h = half.display().to_string();
        let mut a = vec![
            hopper.as_str(),
            "--steps",
            "80",
            "--checkpoint-every",
            "80",
            "--out",
            &h,
        ];
        a.extend_from_slice(&first);
        a.extend_from_slice(&base);
        run_ok(&a);
        let end = dir.join(format!("end-{}-{}", first.join(""), second.join("")));
        let e = end.display().to_string();
        let ck = half.join("checkpoints").join("step-80").display().to_string();
        let mut b = vec!["--restart", ck.as_str(), "--steps", "160", "--out", &e];
        b.extend_from_slice(&second);
        run_ok(&b);
        let got: serde_json::Value = serde_json::from_slice(&read(&end.join("summary.json"))).unwrap();
        assert_eq!(got["checksum"], want["checksum"], "{first:?} then {second:?}");
    }
}

#[test]
fn a_bad_key_under_ranks_is_one_line_and_exit_1() {
    let r = blockflow(&[
        "run",
        &common::scene_path("hopper-small.toml"),
        "--ranks",
        "3",
        "--set",
        "fluid.taux=0.6",
    ]);
    assert_eq!(r.status.code(), Some(1));
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(err.contains("taux"), "{err}");
}
