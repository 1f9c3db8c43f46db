//! Workload estimator: the Table 1 quantities the engine keeps agree with a brute-force
//! recount; `blockflow calibrate --quick` runs end to end and `blockflow run` loads what it wrote.

mod common;
use blockflow::estimator::Quantities;
use common::{timeloop, tmp};
use glam::DVec3;
use std::process::Command;

fn min_image(mut d: DVec3, len: [f64; 3], periodic: [bool; 3]) -> DVec3 {
    for a in 0..3 {
        if periodic[a] {
            d[a] -= len[a] * (d[a] / len[a]).round();
        }
    }
    d
}

/// C, F, NB, the particle links and link cells, P_L, P_S, K and S of every block of the calibration
/// scene equal a brute-force recount from the body positions at the start of the last step (one
/// sub-step per step, so the rigid-body quantities of that step come from those positions too); the
/// contacts seen are at least the owned ones.
#[test]
fn block_quantities_match_a_brute_force_recount() {
    let sets = [
        "domain.block_size=[12,12,12]",
        "scene.diameter=4",
        "particles.subcycles=1",
        "processes.steps_per_graph=1",
        "scene.duration=0.1",
    ];
    let mut tl = timeloop("calibration.toml", &sets);
    tl.advance(29).unwrap();
    let parts = tl.sim().particles.as_ref().unwrap();
    let bodies = parts.bodies(29);
    let halo = parts.halo();
    tl.advance(1).unwrap();
    let sim = tl.sim();
    let d = sim.domain;
    let n = d.cells();
    let len = [n[0] as f64, n[1] as f64, n[2] as f64];
    let parts = sim.particles.as_ref().unwrap();
    let covered = |g: [i64; 3]| {
        let x = DVec3::new(g[0] as f64 + 0.5, g[1] as f64 + 0.5, g[2] as f64 + 0.5);
        bodies
            .iter()
            .any(|b| min_image(x - b.position, len, d.periodic).length_squared() <= b.radius * b.radius)
    };
    let mut total_k = 0.0;
    for blk in &sim.blocks {
        let q = Quantities::of(sim, blk.id);
        let l = blk.layout;
        let (mut f, mut nb, mut links, mut link_cells) = (0.0, 0.0, 0.0, 0.0);
        let fluid_at = |x: usize, y: usize, z: usize| {
            let i = l.idx(x, y, z);
            let g = d.wrap([
                (blk.origin[0] + x) as i64 - 1,
                (blk.origin[1] + y) as i64 - 1,
                (blk.origin[2] + z) as i64 - 1,
            ]);
            blk.flags[i] & blockflow::physics::geometry::flags::FLUID != 0 && !covered(g)
        };
        for z in 1..=l.size[2] {
            for y in 1..=l.size[1] {
                for x in 1..=l.size[0] {
                    if !fluid_at(x, y, z) {
                        continue;
                    }
                    f += 1.0;
                    let near = blockflow_kernels::d3q19::C.iter().skip(1).any(|c| {
                        !fluid_at(
                            (x as i64 + c[0] as i64) as usize,
                            (y as i64 + c[1] as i64) as usize,
                            (z as i64 + c[2] as i64) as usize,
                        )
                    });
                    if near {
                        nb += 1.0;
                    }
                    // Particle links: neighbours that are static fluid but covered by a body.
                    let mut here = 0.0;
                    for c in blockflow_kernels::d3q19::C.iter().skip(1) {
                        let (nx, ny, nz) = (
                            (x as i64 + c[0] as i64) as usize,
                            (y as i64 + c[1] as i64) as usize,
                            (z as i64 + c[2] as i64) as usize,
                        );
                        let static_fluid =
                            blk.flags[l.idx(nx, ny, nz)] & blockflow::physics::geometry::flags::FLUID != 0;
                        if static_fluid && !fluid_at(nx, ny, nz) {
                            here += 1.0;
                        }
                    }
                    links += here;
                    if here > 0.0 {
                        link_cells += 1.0;
                    }
                }
            }
        }
        assert_eq!(q.c, (l.size[0] * l.size[1] * l.size[2]) as f64);
        assert_eq!(q.f, f, "F of block {}", blk.id);
        assert_eq!(q.nb, nb, "NB of block {}", blk.id);
        assert_eq!(q.particle_links, links, "particle links of block {}", blk.id);
        assert_eq!(q.link_cells, link_cells, "link cells of block {}", blk.id);
        assert_eq!(
            q.wall_links,
            (blk.links.noslip.len() + blk.links.moving.len()) as f64,
            "wall links of block {}",
            blk.id
        );
        assert_eq!(q.wall_lines, blk.links.lines() as f64, "wall lines of block {}", blk.id);
        if !parts.active[blk.id] {
            assert_eq!((q.pl, q.ps, q.k, q.s), (0.0, 0.0, 0.0, 0.0));
            continue;
        }
        let pb = &parts.blocks[blk.id];
        let home = |p: DVec3| parts.home(p) == blk.id;
        let pl = bodies.iter().filter(|b| home(b.position)).count() as f64;
        let mut ps = 0.0;
        for b in &bodies {
            for sx in [-1.0, 0.0, 1.0] {
                for sy in [-1.0, 0.0, 1.0] {
                    let shift = DVec3::new(sx * len[0], sy * len[1], 0.0);
                    let p = b.position + shift;
                    let dist = (pb.lo - p).max(p - pb.hi).max(DVec3::ZERO).length();
                    if dist <= b.radius + halo && !(shift == DVec3::ZERO && home(b.position)) {
                        ps += 1.0;
                    }
                }
            }
        }
        // Owned contacts: pairs whose lower-id body is homed here, and plane contacts of local bodies.
        let mut k = 0.0;
        for (i, a) in bodies.iter().enumerate() {
            if !home(a.position) {
                continue;
            }
            for b in &bodies[i + 1..] {
                let dist = min_image(a.position - b.position, len, d.periodic).length();
                if a.radius + b.radius - dist > 0.0 {
                    k += 1.0;
                }
            }
            for pl in &pb.planes {
                if a.radius - pl.distance(a.position) > 0.0 {
                    k += 1.0;
                }
            }
        }
        assert_eq!(q.pl, pl, "P_L of block {}", blk.id);
        assert_eq!(q.ps, ps, "P_S of block {}", blk.id);
        assert_eq!(q.k, k, "K of block {}", blk.id);
        assert_eq!(q.s, 1.0);
        assert!(
            q.contacts_seen >= q.k,
            "block {}: seen {} < owned {}",
            blk.id,
            q.contacts_seen,
            q.k
        );
        assert!(
            q.scanned >= q.pl + q.ps,
            "block {}: scanned {} lists entries",
            blk.id,
            q.scanned
        );
        assert_eq!(q.rb_active, 1.0);
        total_k += k;
    }
    assert!(total_k > 0.0, "the recount saw contacts");
}

fn blockflow(args: &[&str]) -> (i32, String, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_blockflow"))
        .args(args)
        .output()
        .unwrap();
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stdout).to_string(),
        String::from_utf8_lossy(&o.stderr).to_string(),
    )
}

/// `calibrate --quick` writes its files with the stable names, and `blockflow run` with
/// `balance.weights = "estimator"` loads the coefficients it wrote.
#[test]
fn calibrate_quick_end_to_end_and_run_loads_the_file() {
    let out = tmp("calibrate-quick");
    let scene = format!("{}/configs/calibration.toml", env!("CARGO_MANIFEST_DIR"));
    let channel = format!("{}/configs/channel.toml", env!("CARGO_MANIFEST_DIR"));
    // Two pinned workers where the machine has two cores: the thread count reaches the provenance.
    let threads = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .min(2)
        .to_string();
    let (code, stdout, stderr) = blockflow(&[
        "calibrate",
        &scene,
        "--quick",
        "--threads",
        &threads,
        "--with",
        &channel,
        "--with-steps",
        "60",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{stderr}");
    // The scene given with --with is the campaign's third run: one sample per block (the channel's two,
    // both fluid) per step after the 50-step warm-up.
    let csv = std::fs::read_to_string(out.join("samples.csv")).unwrap();
    assert_eq!(csv.lines().filter(|l| l.starts_with("2,")).count(), 2 * (60 - 50));
    assert!(
        stdout.contains("step_in_sample") && stdout.contains("interval_held_out"),
        "{stdout}"
    );
    for f in [
        "samples.csv",
        "coefficients.toml",
        "calibration.json",
        "figure6.png",
        "figure7.png",
        "figure8.png",
    ] {
        assert!(out.join(f).exists(), "{f}");
    }
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("calibration.json")).unwrap()).unwrap();
    for model in ["paper", "blockflow"] {
        for k in [
            "step_in_sample",
            "step_held_out",
            "interval_in_sample",
            "interval_held_out",
            "interval_predictive",
            "interval_predictive_plain",
        ] {
            let v = json["models"][model]["share_within_10pct"][k].as_f64().unwrap();
            assert!((0.0..=1.0).contains(&v), "{model} {k} = {v}");
        }
    }
    assert_eq!(json["model"], "blockflow");
    assert_eq!(json["threads"].to_string(), threads);
    assert!(json["never_fluid_samples"].as_u64().is_some());
    // One row of interval statistics per run, named by the scene it recorded (the --with scene last).
    let by_run = json["by_run"].as_array().unwrap();
    assert_eq!(by_run.len(), 3, "{by_run:?}");
    assert!(by_run[2]["scene"].as_str().unwrap().contains("channel.toml"));
    for (i, r) in by_run.iter().enumerate() {
        for k in ["interval_in_sample", "interval_held_out", "interval_predictive"] {
            match r[k].as_f64() {
                Some(v) => assert!((0.0..=1.0).contains(&v), "{r} {k}"),
                // The channel's 10 samples fill no 100-step interval: nothing to score (null).
                None => assert!(i == 2 && r[k].is_null(), "{r} {k}"),
            }
        }
        // Held out by kind of block: the calibration scene's blocks all hold bodies at first, so its
        // runs score block intervals of that kind.
        let kinds = &r["interval_held_out_by_kind"];
        for k in ["with bodies", "walls, no bodies", "fluid only"] {
            assert!(kinds[k]["intervals"].as_u64().is_some(), "{r} {k}");
        }
        if i < 2 {
            assert!(kinds["with bodies"]["intervals"].as_u64().unwrap() > 0, "{r}");
        }
    }
    assert!(json["noise_floor"]["between_blocks_by_kind"]["fluid only"]["intervals"].is_u64());
    for key in ["interval_held_out_by_kind", "interval_predictive_by_kind"] {
        assert!(
            json["models"]["blockflow"][key]["with bodies"]["intervals"]
                .as_u64()
                .unwrap()
                > 0,
            "{key}"
        );
    }
    // A refit of the campaign's samples names the scenes its calibration.json recorded.
    let refit = tmp("calibrate-refit");
    let samples = out.join("samples.csv");
    let (code, _, stderr) = blockflow(&[
        "calibrate",
        "--samples",
        samples.to_str().unwrap(),
        "--out",
        refit.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{stderr}");
    let c = blockflow::estimator::Coefficients::load(&refit.join("coefficients.toml")).unwrap();
    assert_eq!(c.provenance.scenes.len(), 3, "{:?}", c.provenance.scenes);
    assert!(
        c.provenance.scenes[2].contains("channel.toml"),
        "{:?}",
        c.provenance.scenes
    );
    assert_eq!(c.provenance.threads.to_string(), threads);
    // The written coefficients are the blockflow model's, all costs ≥ 0.
    let c = blockflow::estimator::Coefficients::load(&out.join("coefficients.toml")).unwrap();
    assert_eq!(c.model, blockflow::estimator::Model::Blockflow);
    assert!(c.parts.iter().flatten().all(|&a| a >= 0.0), "{:?}", c.parts);
    for part in ["lbm", "bh", "coup1", "coup2", "rb", "total"] {
        assert!(
            json["median"][part].is_number() && json["mad"][part].is_number(),
            "{part}"
        );
    }
    let coeffs = out.join("coefficients.toml");
    let run_out = tmp("run-estimator");
    let set = format!("balance.coefficients={}", coeffs.display());
    let (code, _, stderr) = blockflow(&[
        "run",
        &scene,
        "--set",
        "domain.block_size=[12,12,12]",
        "--set",
        "scene.diameter=4",
        "--set",
        "balance.weights=estimator",
        "--set",
        &set,
        "--processes",
        "2",
        "--steps",
        "3",
        "--out",
        run_out.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{stderr}");
    assert!(run_out.join("summary.json").exists());
}

/// The default campaign run where its hopper scenes are not at hand stops at once with one line that
/// names the missing file and the ways out, and exit code 1.
#[test]
fn default_campaign_without_its_scenes_is_a_one_line_error() {
    let dir = tmp("calibrate-elsewhere");
    std::fs::create_dir_all(&dir).unwrap();
    let scene = format!("{}/configs/calibration.toml", env!("CARGO_MANIFEST_DIR"));
    let o = Command::new(env!("CARGO_BIN_EXE_blockflow"))
        .current_dir(&dir)
        .args(["calibrate", &scene, "--out", "cal"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(
        err.contains("configs/hopper.toml") && err.contains("--calibration-only"),
        "{err}"
    );
    assert!(!dir.join("cal").join("samples.csv").exists());
}
