//! Bad input and unstable runs: a one-line message naming the key / file / cell, a non-zero exit, no panic,
//! and never a summary that looks like a result.

use std::path::{Path, PathBuf};
use std::process::Command;

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("blockflow-cli-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn configs() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("configs")
}

/// Runs `blockflow run` and returns (exit code, stderr).
fn run(scene: &Path, args: &[&str], out: &Path) -> (i32, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_blockflow"))
        .arg("run")
        .arg(scene)
        .args(args)
        .arg("--out")
        .arg(out)
        .output()
        .expect("binary runs");
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stderr).to_string(),
    )
}

/// Asserts a clean one-line failure whose message contains every needle.
fn fails_cleanly(scene: &Path, args: &[&str], needles: &[&str]) {
    let out = tmp(&needles.join("-").replace(['/', '.', ' ', '`'], "_"));
    let (code, err) = run(scene, args, &out);
    assert_ne!(code, 0, "expected failure for {args:?}");
    assert!(
        !err.contains("panicked") && !err.contains("RUST_BACKTRACE"),
        "panic: {err}"
    );
    assert_eq!(err.trim_end().lines().count(), 1, "not one line: {err}");
    for n in needles {
        assert!(err.contains(n), "message lacks {n:?}: {err}");
    }
    assert!(!out.join("summary.json").exists(), "a failed run left a summary.json");
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn bad_values_name_their_key() {
    let ch = configs().join("channel.toml");
    fails_cleanly(&ch, &["--set", "fluid.tau=0.5"], &["fluid.tau", "> 0.5"]);
    fails_cleanly(&ch, &["--set", "fluid.tau=0.3"], &["fluid.tau"]);
    fails_cleanly(&ch, &["--set", "domain.blocks=[0,1,1]"], &["domain.blocks"]);
    fails_cleanly(&ch, &["--set", "domain.blocks=[-1,1,1]"], &["domain.blocks"]);
    fails_cleanly(&ch, &["--set", "domain.blocks=[3,1,1]"], &["domain.blocks", "divisor"]);
    fails_cleanly(&ch, &["--set", "scene.resolution=0"], &["scene.resolution"]);
    fails_cleanly(&ch, &["--set", "fluid.taux=0.7"], &["fluid", "taux"]);
    fails_cleanly(&ch, &["--set", "scene.lid_velocity=0.1"], &["lid_velocity"]);
    fails_cleanly(&ch, &["--set", "fluid.tau=fast"], &["fluid.tau", "invalid type"]);
    fails_cleanly(&ch, &["--set", "fluid.precision=f16"], &["fluid.precision", "f16"]);
    fails_cleanly(
        &ch,
        &["--set", "domain.periodic=[false,false,false]"],
        &["domain.periodic"],
    );
    fails_cleanly(&ch, &["--set", "novalue"], &["--set novalue"]);
    fails_cleanly(&ch, &["--processes", "0"], &["processes.count"]);
    fails_cleanly(&ch, &["--threads-per-process", "0"], &["processes.threads_per_process"]);
    fails_cleanly(&ch, &["--interval", "0"], &["balance.interval"]);
    fails_cleanly(&ch, &["--pin", "foo"], &["processes.pin", "foo"]);
    fails_cleanly(&ch, &["--pin", "0,1,99999"], &["processes.pin"]);
    fails_cleanly(&ch, &["--balance", "parmetis"], &["balance.strategy", "parmetis"]);
    fails_cleanly(
        &ch,
        &["--set", "balance.metis_imbalance=0.5"],
        &["balance.metis_imbalance"],
    );
    fails_cleanly(&ch, &["--set", "balance.latency=-1"], &["balance.latency"]);
    fails_cleanly(&ch, &["--set", "balance.bandwidth=0"], &["balance.bandwidth"]);
    fails_cleanly(&ch, &["--set", "processes.steal=\"everywhere\""], &["processes.steal"]);
    fails_cleanly(&ch, &["--png", "0"], &["run.png_every"]);
    fails_cleanly(
        &ch,
        &["--png", "5", "--set", "run.png_normal=\"w\""],
        &["run.png_normal"],
    );
    fails_cleanly(&ch, &["--png", "5", "--set", "run.png_at=999"], &["run.png_at = 999"]);
    fails_cleanly(
        &ch,
        &["--vtk", "5", "--set", "run.vtk_encoding=\"zip\""],
        &["run.vtk_encoding", "base64"],
    );
}

#[test]
fn bad_files_name_the_file() {
    let d = tmp("files");
    let missing = d.join("nope.toml");
    fails_cleanly(&missing, &[], &["nope.toml"]);
    let broken = write(&d, "broken.toml", "[scene\nkind = \"channel\"\n");
    fails_cleanly(&broken, &[], &["broken.toml", "line 1"]);
    let unknown = write(&d, "unknown.toml", "[scene]\nkind = \"channel\"\nresolutoin = 8\n");
    fails_cleanly(&unknown, &[], &["unknown.toml", "resolutoin"]);
    let kind = write(&d, "kind.toml", "[scene]\nkind = \"chanel\"\n");
    fails_cleanly(&kind, &[], &["kind.toml", "chanel"]);
    let noscene = write(&d, "noscene.toml", "[fluid]\ntau = 0.7\n");
    fails_cleanly(&noscene, &[], &["noscene.toml", "scene"]);
    let types = write(&d, "types.toml", "[scene]\nkind = \"channel\"\nresolution = \"big\"\n");
    fails_cleanly(&types, &[], &["types.toml", "scene", "resolution"]);
    let garbage = d.join("garbage.toml");
    std::fs::write(&garbage, [0xffu8, 0xfe, 0x00, 0x13, 0x37]).unwrap();
    fails_cleanly(&garbage, &[], &["garbage.toml"]);
}

#[test]
fn geometry_without_fluid_is_refused() {
    let bx = configs().join("box.toml");
    // the plane's fluid side lies entirely above the box
    fails_cleanly(
        &bx,
        &["--set", "scene.planes=[{point=[0,100,0],normal=[0,1,0]}]"],
        &["no fluid cell"],
    );
    fails_cleanly(
        &bx,
        &["--set", "scene.planes=[{point=[0,1,0],normal=[0,0,0]}]"],
        &["scene.planes[0].normal"],
    );
}

fn read_summary(dir: &Path) -> String {
    std::fs::read_to_string(dir.join("summary.json")).expect("summary written")
}

#[test]
fn unstable_run_is_reported_with_step_block_and_cell() {
    // τ barely above 1/2 and U0 ~ 0.4: blows up within a few dozen steps.
    let tg = configs().join("taylor_green.toml");
    let out = tmp("unstable");
    let (code, err) = run(
        &tg,
        &[
            "--set",
            "scene.resolution=16",
            "--set",
            "scene.reynolds=20000",
            "--set",
            "fluid.tau=0.501",
            "--steps",
            "500",
        ],
        &out,
    );
    assert_eq!(code, 3, "{err}");
    assert_eq!(err.trim_end().lines().count(), 1);
    for n in ["unstable at step", "block", "cell", "density", "velocity"] {
        assert!(err.contains(n), "{n}: {err}");
    }
    let s = read_summary(&out);
    assert!(s.contains("\"status\": \"unstable\""), "{s}");
    assert!(!s.contains("\"status\": \"ok\""));
}

#[test]
fn stable_run_says_ok() {
    let out = tmp("ok");
    let (code, err) = run(&configs().join("couette.toml"), &["--steps", "50"], &out);
    assert_eq!(code, 0, "{err}");
    let s = read_summary(&out);
    assert!(s.contains("\"status\": \"ok\""));
    for key in [
        "\"mlups\"",
        "\"parts_seconds\"",
        "\"checksum\"",
        "\"fluid_cells\"",
        "\"observables\"",
    ] {
        assert!(s.contains(key), "summary lacks {key}");
    }
    let csv = std::fs::read_to_string(out.join("series.csv")).unwrap();
    assert!(csv.starts_with("step,time,mass"));
    assert!(out.join("effective.toml").exists());
}

#[test]
fn vtk_series_is_written() {
    let out = tmp("vtk");
    let (code, err) = run(&configs().join("couette.toml"), &["--steps", "20", "--vtk", "10"], &out);
    assert_eq!(code, 0, "{err}");
    let pvd = std::fs::read_to_string(out.join("fluid.pvd")).unwrap();
    assert_eq!(pvd.matches("<DataSet").count(), 3, "steps 0, 10, 20: {pvd}");
    assert!(out.join("vtk/step_00000020.vtm").exists());
}

#[test]
fn bad_particle_settings_name_their_key() {
    let gb = configs().join("granular_box.toml");
    fails_cleanly(&gb, &["--set", "particles.subcycles=0"], &["particles.subcycles"]);
    fails_cleanly(&gb, &["--set", "particles.rounds=0"], &["particles.rounds"]);
    fails_cleanly(&gb, &["--set", "particles.rounds=13"], &["particles.rounds", "255"]);
    let jacobi = ["--set", "particles.solver=\"jacobi\""];
    fails_cleanly(
        &gb,
        &[&jacobi[..], &["--set", "particles.rounds=2"]].concat(),
        &["particles.rounds", "jacobi"],
    );
    fails_cleanly(
        &gb,
        &[&jacobi[..], &["--set", "particles.iterations=20"]].concat(),
        &["particles.iterations", "255"],
    );
    fails_cleanly(&gb, &["--set", "particles.warm_start=1.5"], &["particles.warm_start"]);
    fails_cleanly(&gb, &["--set", "particles.solver=\"gauss\""], &["gauss"]);
    fails_cleanly(&gb, &["--set", "particles.restitution=1.5"], &["particles.restitution"]);
    fails_cleanly(&gb, &["--set", "particles.friction=-1"], &["particles.friction"]);
    fails_cleanly(&gb, &["--set", "particles.relaxation=2"], &["particles.relaxation"]);
    fails_cleanly(&gb, &["--set", "particles.subcyles=4"], &["subcyles"]);
    fails_cleanly(&gb, &["--set", "fluid.enabled=true"], &["fluid.enabled = false"]);
    fails_cleanly(&gb, &["--set", "scene.count=5000"], &["scene.count", "scene.size"]);
    fails_cleanly(
        &gb,
        &["--set", "domain.blocks=[16,16,32]"],
        &["domain.block_size", "diameter"],
    );
    let inc = configs().join("incline.toml");
    fails_cleanly(&inc, &["--set", "scene.angle_deg=75"], &["scene.angle_deg"]);
}

/// A body pushed through a block in one sub-step stops the run: exit 3, the body and sub-step named,
/// summary.json marked unstable.
#[test]
fn runaway_particles_stop_the_run() {
    let out = tmp("runaway");
    let (code, err) = run(
        &configs().join("granular_box.toml"),
        &["--set", "scene.initial_speed=1000", "--steps", "20"],
        &out,
    );
    assert_eq!(code, 3, "{err}");
    assert!(err.contains("body ") && err.contains("sub-step 1 "), "{err}");
    assert!(!err.contains("panicked"));
    let summary = std::fs::read_to_string(out.join("summary.json")).unwrap();
    assert!(summary.contains("\"status\": \"unstable\""));
}

/// A gravity of 1e300 (found by the fuzzer): the travel bound of the active-block set overflowed the
/// block range and the run hung; now the runaway is reported at sub-step 1 with exit 3.
#[test]
fn astronomical_gravity_is_a_runaway_not_a_hang() {
    let out = tmp("gravity");
    let (code, err) = run(
        &configs().join("calibration.toml"),
        &[
            "--set",
            "particles.gravity=[-0.0017,-1e300,-0.0099]",
            "--steps",
            "2",
            "--processes",
            "3",
        ],
        &out,
    );
    assert_eq!(code, 3, "{err}");
    assert!(
        err.contains("sub-step 1 ") && err.trim_end().lines().count() == 1,
        "{err}"
    );
}

/// A malformed, incomplete or mismatched coefficients file stops `run` with one line naming the file
/// and the key.
#[test]
fn bad_coefficient_files_name_the_key() {
    let dir = tmp("coefficients");
    let good = std::fs::read_to_string(configs().join("coefficients-paper-table2.toml")).unwrap();
    let cal = configs().join("calibration.toml");
    let cases = [
        ("missing.toml", good.replacen("a3 =", "# a3 =", 1), "a3"),
        ("extra.toml", good.replacen("[bh]", "[bh]\na4 = 1.0", 1), "a4"),
        ("nan.toml", good.replacen("floor = ", "floor = nan #", 1), "floor"),
        ("garbage.toml", "\u{1}\u{2} not toml".to_string(), "garbage.toml"),
    ];
    for (name, text, key) in cases {
        let p = write(&dir, name, &text);
        let set = format!("balance.coefficients={}", p.display());
        fails_cleanly(
            &cal,
            &["--set", "balance.weights=estimator", "--set", &set, "--steps", "1"],
            &[name, key],
        );
    }
    fails_cleanly(
        &cal,
        &[
            "--set",
            "balance.weights=estimator",
            "--set",
            "balance.coefficients=/nonexistent/c.toml",
            "--steps",
            "1",
        ],
        &["/nonexistent/c.toml"],
    );
}

/// Runs `blockflow` with `args` (from the crate's root, so `configs/` resolves) and asserts a one-line
/// failure with exit code 1 whose message contains every needle.
fn command_fails_cleanly(args: &[&std::ffi::OsStr], needles: &[&str]) {
    let o = Command::new(env!("CARGO_BIN_EXE_blockflow"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("binary runs");
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
    assert_eq!(err.trim_end().lines().count(), 1, "not one line: {err}");
    for n in needles {
        assert!(err.contains(n), "{args:?}: message lacks {n:?}: {err}");
    }
}

/// `args` as the `OsStr`s a command takes.
fn os<'a>(args: &[&'a str]) -> Vec<&'a std::ffi::OsStr> {
    args.iter().map(|a| std::ffi::OsStr::new(*a)).collect()
}

/// `study --processes` past what `run` accepts (processes.count) recorded the scene at a crawl and
/// replayed it on empty processes, and `--steps 0` failed on a figure with no data: each is refused,
/// naming the flag, before anything runs.
#[test]
fn study_process_counts_are_bounded() {
    let out = tmp("study-processes");
    let out = out.to_str().expect("a UTF-8 temporary path");
    for (p, t, needle) in [
        ("100000", "1", "--processes 100000: must be between 1 and 4096"),
        ("4", "0", "--threads-per-process 0: must be between 1 and 4096"),
    ] {
        command_fails_cleanly(
            &os(&[
                "study",
                "configs/hopper-small.toml",
                "--processes",
                p,
                "--threads-per-process",
                t,
                "--out",
                out,
            ]),
            &[needle],
        );
    }
    command_fails_cleanly(
        &os(&[
            "study",
            "configs/hopper-small.toml",
            "--processes",
            "2",
            "--steps",
            "0",
            "--out",
            out,
        ]),
        &["--steps 0", "record at least one step"],
    );
}

/// A samples file with a NaN time (hand-edited or damaged) reached the fit and failed only when figure 7
/// found nothing to plot: the reader names the line and the column.
#[test]
fn calibrate_refuses_non_finite_samples() {
    let dir = tmp("samples-nan");
    let names = "run,block_size,diameter,step,t_star,block,row,C,F,NB,PL,PS,K,S,runs,breaks,wall_links,\
                 particle_links,link_cells,map_active,map_bodies,box_cells,rows_derived,turned,covered,rb_active,\
                 contacts_seen,scanned,wall_lines,tail_runs,shifted_runs,row_pitch,m_lbm,m_bh,m_coup1,m_coup2,m_rb";
    let n = names.split(',').count();
    let row = |last: &str| {
        let mut v = vec!["1"; n - 1];
        v.push(last);
        v.join(",")
    };
    for bad in ["nan", "inf", "-inf"] {
        let p = write(
            &dir,
            "samples.csv",
            &format!("{names}\n{}\n{}\n", row("1e-6"), row(bad)),
        );
        let out = dir.join("out");
        command_fails_cleanly(
            &[
                "calibrate".as_ref(),
                "--samples".as_ref(),
                p.as_os_str(),
                "--out".as_ref(),
                out.as_os_str(),
            ],
            &["samples.csv:3: column m_rb is not a finite number"],
        );
    }
}

/// A bad value late in a sweep stopped it only after the runs before it: every combination is checked
/// before the first run, so the only line is the error.
#[test]
fn sweeps_check_every_combination_first() {
    let out = tmp("sweep-late-error");
    command_fails_cleanly(
        &[
            "sweep".as_ref(),
            "configs/channel.toml".as_ref(),
            "--vary".as_ref(),
            "fluid.tau=0.6,0.7,abc".as_ref(),
            "--steps".as_ref(),
            "2".as_ref(),
            "--out".as_ref(),
            out.as_os_str(),
        ],
        &["fluid.tau", "abc"],
    );
    assert!(!out.join("sweep.csv").exists(), "a failed sweep wrote sweep.csv");
}

/// Benchmarks sized past the machine: `bench kernel --size 100000` aborted on the allocation and
/// `--threads 1000` was ended by the out-of-memory killer; `bench mpi --max` started a run per rank count
/// up to any number. Each is refused before it starts, naming the flag.
#[test]
fn oversized_benchmarks_are_refused() {
    for (args, needle) in [
        (
            &["bench", "kernel", "--quick", "--size", "100000"][..],
            "--size must be between 8 and 4096",
        ),
        (
            &["bench", "kernel", "--quick", "--size", "1000"][..],
            "lower --size or --threads",
        ),
        (
            &["bench", "kernel", "--quick", "--threads", "100000"][..],
            "lower --size or --threads",
        ),
        (
            &["bench", "mpi", "--max", "100000", "--steps", "1"][..],
            "--max 100000: at most 96",
        ),
    ] {
        command_fails_cleanly(&os(args), &[needle]);
    }
}
