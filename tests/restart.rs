//! Checkpoints and restart through the `blockflow` binary: a run checkpointed half-way and
//! restarted on another process count (and, for the hopper, another balancing strategy) ends bitwise
//! where the uninterrupted run ends; bad checkpoints are refused with one line naming the file and the
//! reason; SIGTERM stops a run with a checkpoint it can be continued from; the output folder and the
//! memory a scene needs are checked before the first step.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

fn blockflow(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_blockflow"))
        .args(args)
        .output()
        .expect("binary runs")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).to_string()
}

/// Runs `blockflow run ARGS --out OUT` and asserts success.
fn run_ok(args: &[&str], out: &Path) -> serde_json::Value {
    let mut a = vec!["run"];
    a.extend_from_slice(args);
    let o = out.display().to_string();
    a.extend_from_slice(&["--out", &o]);
    let r = blockflow(&a);
    assert!(r.status.success(), "blockflow {a:?} failed: {}", stderr(&r));
    summary(out)
}

fn summary(dir: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("summary.json")).expect("summary.json");
    serde_json::from_str(&text).expect("summary.json parses")
}

fn checksums(s: &serde_json::Value) -> (String, String) {
    (
        s["checksum"]["fluid"].as_str().unwrap().to_string(),
        s["checksum"]["particles"].as_str().unwrap_or("").to_string(),
    )
}

/// Uninterrupted `n` steps with `first` options, against `n / 2` steps with `first` options and a
/// checkpoint, restarted to `n` steps with `second` options: identical checksums, and the restart says
/// where it came from.
fn restart_matches(name: &str, scene: &str, sets: &[&str], n: u64, first: &[&str], second: &[&str]) -> PathBuf {
    let dir = common::fresh_dir(name);
    let scene = common::scene_path(scene);
    let (ns, half) = (n.to_string(), (n / 2).to_string());
    let mut common = vec![scene.as_str()];
    for s in sets {
        common.extend_from_slice(&["--set", s]);
    }
    let mut a: Vec<&str> = common.clone();
    a.extend_from_slice(&["--steps", &ns]);
    a.extend_from_slice(first);
    let want = run_ok(&a, &dir.join("straight"));
    assert_eq!(want["steps"], n);

    let mut b: Vec<&str> = common.clone();
    b.extend_from_slice(&["--steps", &half, "--checkpoint-every", &half]);
    b.extend_from_slice(first);
    let s1 = run_ok(&b, &dir.join("first"));
    let ck = dir.join("first/checkpoints").join(format!("step-{half}"));
    assert!(ck.is_file(), "no checkpoint {}", ck.display());
    assert_eq!(s1["checkpoint"].as_str().unwrap(), ck.display().to_string());

    let ck_s = ck.display().to_string();
    let mut c: Vec<&str> = vec!["--restart", &ck_s, "--steps", &ns];
    c.extend_from_slice(second);
    let got = run_ok(&c, &dir.join("second"));
    assert_eq!(got["status"], "ok");
    assert_eq!(got["steps"], n);
    assert_eq!(got["restart_step"], n / 2);
    assert_eq!(
        checksums(&got),
        checksums(&want),
        "{name}: the restarted run ends elsewhere than the uninterrupted one"
    );
    dir
}

#[test]
fn restart_is_bitwise_taylor_green() {
    let dir = restart_matches(
        "tg",
        "taylor_green.toml",
        &["scene.resolution=16"],
        30,
        // Written under pull after an odd number of steps, continued under AA: the checkpoint holds the
        // physical state, not a pattern's layout.
        &["--processes", "1", "--set", "fluid.streaming=\"pull\""],
        &["--processes", "3", "--threads-per-process", "2", "--pin", "compact"],
    );
    // The effective configuration is written beside the results and reproduces the run.
    let eff = std::fs::read_to_string(dir.join("second/effective.toml")).unwrap();
    assert!(eff.contains("steps = 30") && eff.contains("count = 3"), "{eff}");
    let want = summary(&dir.join("straight"));
    let again = run_ok(
        &[&dir.join("straight/effective.toml").display().to_string()],
        &dir.join("again"),
    );
    assert_eq!(again["steps"], 30);
    assert_eq!(checksums(&again), checksums(&want));
}

#[test]
fn restart_is_bitwise_hopper_small_with_another_strategy() {
    restart_matches(
        "hopper",
        "hopper-small.toml",
        &[],
        40,
        &["--processes", "2", "--balance", "hilbert", "--interval", "15"],
        &[
            "--processes",
            "3",
            "--balance",
            "metis",
            "--interval",
            "10",
            "--set",
            "processes.steps_per_graph=3",
            // Written under AA (the default), continued under pull.
            "--set",
            "fluid.streaming=\"pull\"",
        ],
    );
}

#[test]
fn restart_is_bitwise_granular_box() {
    restart_matches(
        "granular",
        "granular_box.toml",
        &[],
        40,
        &["--processes", "1"],
        &["--processes", "2", "--balance", "diffusive", "--interval", "7"],
    );
}

/// With several rounds of the contact solve per sub-step the state between steps is still just the
/// bodies (the rounds' impulses live inside a sub-step), so a restart continues bitwise.
#[test]
fn restart_is_bitwise_granular_box_with_rounds() {
    restart_matches(
        "granular-rounds",
        "granular_box.toml",
        &[
            "particles.solver=\"block_gauss_seidel\"",
            "particles.rounds=2",
            "particles.iterations=5",
        ],
        40,
        &["--processes", "1"],
        &["--processes", "3", "--balance", "hilbert", "--interval", "7"],
    );
}

/// With the Jacobi solver the state between steps also holds every contact's last impulse (the next
/// sub-step's warm start); the block format carries it, so a restart on another P continues bitwise
/// (at step 120 of the pour, when about 70 contacts touch).
#[test]
fn restart_is_bitwise_granular_box_with_jacobi() {
    restart_matches(
        "granular-jacobi",
        "granular_box.toml",
        &["particles.solver=\"jacobi\"", "particles.iterations=5"],
        240,
        &["--processes", "1"],
        &["--processes", "3", "--balance", "hilbert", "--interval", "7"],
    );
}

/// The blocks of a checkpoint are per block: the same bytes whatever P wrote them; the balancing state
/// of `corrected` weights travels with the file.
#[test]
fn checkpoint_blocks_do_not_depend_on_the_process_count() {
    use blockflow::checkpoint::Checkpoint;
    let dir = common::fresh_dir("per-block");
    let tg = common::scene_path("hopper-small.toml");
    let mut files = Vec::new();
    for p in ["1", "3"] {
        let out = dir.join(p);
        run_ok(
            &[
                &tg,
                "--steps",
                "6",
                "--checkpoint-every",
                "6",
                "--processes",
                p,
                "--balance",
                "hilbert",
                "--interval",
                "4",
                "--set",
                "balance.weights=\"corrected\"",
            ],
            &out,
        );
        files.push(Checkpoint::read(&out.join("checkpoints/step-6")).expect("a valid checkpoint"));
    }
    assert_eq!(files[0].step, 6);
    assert!(files[0].blocks == files[1].blocks, "block bytes depend on P");
    let bal = files[0].balance.as_ref().expect("balancing state");
    assert_eq!(bal.weights, "corrected");
    assert_eq!(bal.steps, 1, "one balancing step at step 4");
    assert_eq!(bal.ratio.len(), 96);
    assert!(
        bal.predicted.iter().any(|&p| p > 0.0),
        "the interval's prediction is stored"
    );
    assert!(files[0].particles.is_some());
    // A restart with the corrector state (another P) continues bitwise.
    let common = [
        tg.as_str(),
        "--steps",
        "10",
        "--balance",
        "hilbert",
        "--interval",
        "4",
        "--set",
        "balance.weights=\"corrected\"",
    ];
    let want = run_ok(&[&common[..], &["--processes", "2"]].concat(), &dir.join("straight"));
    let got = run_ok(
        &[
            "--restart",
            &dir.join("1").display().to_string(),
            "--processes",
            "2",
            "--steps",
            "10",
        ],
        &dir.join("resumed"),
    );
    assert_eq!(checksums(&got), checksums(&want));
    assert_eq!(got["balance"]["strategy"], "hilbert");
}

/// Asserts a clean one-line failure with the exit code, naming every needle, that started nothing.
fn fails_cleanly(args: &[&str], code: i32, needles: &[&str]) {
    let out = common::fresh_dir(&format!(
        "fail-{}",
        needles.join("-").replace(['/', '.', ' ', '"', '='], "_")
    ));
    let o = out.display().to_string();
    let mut a = vec!["run"];
    a.extend_from_slice(args);
    a.extend_from_slice(&["--out", &o]);
    let r = blockflow(&a);
    let err = stderr(&r);
    assert_eq!(r.status.code(), Some(code), "{a:?}: {err}");
    assert!(
        !err.contains("panicked") && !err.contains("RUST_BACKTRACE"),
        "panic: {err}"
    );
    assert_eq!(err.trim_end().lines().count(), 1, "not one line: {err}");
    for n in needles {
        assert!(err.contains(n), "message lacks {n:?}: {err}");
    }
    assert!(!out.join("summary.json").exists(), "a failed run left a summary.json");
    assert!(!out.join("series.csv").exists(), "a refused restart started a run");
}

/// A good checkpoint of a short Taylor–Green run, written once.
fn good_checkpoint(dir: &Path) -> PathBuf {
    run_ok(
        &[
            &common::scene_path("taylor_green.toml"),
            "--set",
            "scene.resolution=16",
            "--steps",
            "4",
            "--checkpoint-every",
            "4",
        ],
        &dir.join("good"),
    );
    dir.join("good/checkpoints/step-4")
}

#[test]
fn bad_checkpoints_are_refused_with_one_line() {
    let dir = common::fresh_dir("bad");
    let good = good_checkpoint(&dir);
    let bytes = std::fs::read(&good).unwrap();
    let n = bytes.len();
    let write = |name: &str, b: &[u8]| {
        let p = dir.join(name);
        std::fs::write(&p, b).unwrap();
        p.display().to_string()
    };
    // Truncated.
    let p = write("truncated", &bytes[..n / 2]);
    fails_cleanly(&["--restart", &p], 4, &[&p, "truncated"]);
    let p = write("truncated-header", &bytes[..10]);
    fails_cleanly(&["--restart", &p], 4, &[&p, "truncated"]);
    // A flipped byte in the blocks, in the config, in the checksum.
    for (i, at) in [n / 2, 200, n - 1].into_iter().enumerate() {
        let mut b = bytes.clone();
        b[at] ^= 0x04;
        let p = write(&format!("flipped-{i}"), &b);
        fails_cleanly(&["--restart", &p], 4, &[&p, "corrupt", "checksum"]);
    }
    // Another format version (a consistent file of a future writer).
    let mut b = bytes.clone();
    b[8..12].copy_from_slice(&2u32.to_le_bytes());
    let sum = blockflow::serialise::checksum(&b[..n - 8]);
    b[n - 8..].copy_from_slice(&sum.to_le_bytes());
    let p = write("version", &b);
    fails_cleanly(&["--restart", &p], 4, &[&p, "format version 2", "reads version 1"]);
    // Not a checkpoint, empty, missing, a folder without checkpoints.
    let p = write("garbage", b"\x00\x01hello");
    fails_cleanly(&["--restart", &p], 4, &[&p, "not a blockflow checkpoint"]);
    let p = write("empty", b"");
    fails_cleanly(&["--restart", &p], 4, &[&p, "empty"]);
    let p = dir.join("missing").display().to_string();
    fails_cleanly(&["--restart", &p], 4, &[&p]);
    fails_cleanly(
        &["--restart", &dir.display().to_string()],
        4,
        &["without any checkpoint"],
    );
    // From another scene: the scene file given beside it has other physics.
    let g = good.display().to_string();
    fails_cleanly(
        &[&common::scene_path("channel.toml"), "--restart", &g],
        4,
        &[&g, "another scene", "channel.toml", "scene.kind"],
    );
    fails_cleanly(
        &[&common::scene_path("taylor_green.toml"), "--restart", &g],
        4,
        &[&g, "another scene", "scene.resolution"],
    );
    // Overrides that would change the physics are refused, naming the key.
    fails_cleanly(
        &["--restart", &g, "--set", "fluid.tau=0.9"],
        1,
        &["fluid.tau", "physics"],
    );
    fails_cleanly(
        &["--restart", &g, "--set", "domain.blocks=[1,1,1]"],
        1,
        &["domain.blocks", "physics"],
    );
    fails_cleanly(&["--restart", &g, "--steps", "2"], 1, &["step 4", "--steps"]);
    // The same scene file is accepted, and so is a folder (newest checkpoint in it).
    let out = dir.join("again");
    let s = run_ok(
        &[
            &common::scene_path("taylor_green.toml"),
            "--set",
            "scene.resolution=16",
            "--restart",
            &dir.join("good").display().to_string(),
            "--steps",
            "6",
        ],
        &out,
    );
    assert_eq!((s["restart_step"].as_u64(), s["steps"].as_u64()), (Some(4), Some(6)));
}

/// A crash mid-write leaves a `.tmp` file that nobody reads; only complete files are named step-<step>;
/// only the newest `run.checkpoints_kept` stay.
#[test]
fn checkpoints_are_kept_and_named_only_when_complete() {
    let dir = common::fresh_dir("kept");
    run_ok(
        &[
            &common::scene_path("taylor_green.toml"),
            "--set",
            "scene.resolution=16",
            "--steps",
            "20",
            "--checkpoint-every",
            "4",
            "--checkpoints-kept",
            "3",
        ],
        &dir,
    );
    let mut names: Vec<String> = std::fs::read_dir(dir.join("checkpoints"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
        .collect();
    names.sort();
    assert_eq!(names, ["step-12", "step-16", "step-20"]);
    // A stale temporary file (a crash mid-write) is not taken for a checkpoint by --restart DIR.
    std::fs::write(dir.join("checkpoints/.step-24.tmp"), b"BFCHKPT\n partial").unwrap();
    let p = blockflow::checkpoint::resolve(&dir).unwrap();
    assert!(p.ends_with("step-20"), "{}", p.display());
}

fn wait_for(what: &str, mut f: impl FnMut() -> bool) {
    let t0 = Instant::now();
    while !f() {
        assert!(t0.elapsed() < Duration::from_secs(120), "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn has_checkpoint(dir: &Path) -> bool {
    !blockflow::checkpoint::list(&dir.join("checkpoints")).is_empty()
}

/// SIGTERM: the run stops at the end of a graph run, writes a checkpoint and summary.json with status
/// "interrupted" and the step reached, exits with 143; restarting from the checkpoint ends where the
/// uninterrupted run ends.
#[test]
fn sigterm_stops_with_a_checkpoint_that_continues_bitwise() {
    let dir = common::fresh_dir("sigterm");
    let tg = common::scene_path("taylor_green.toml");
    let out = dir.join("killed");
    let child = Command::new(env!("CARGO_BIN_EXE_blockflow"))
        .args(["run", &tg, "--set", "scene.resolution=16", "--steps", "1000000"])
        .args(["--checkpoint-every", "8", "--out"])
        .arg(&out)
        .stderr(Stdio::piped())
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    wait_for("the first checkpoint", || has_checkpoint(&out));
    // SAFETY: plain kill(2) of our child.
    assert_eq!(unsafe { libc::kill(child.id() as i32, libc::SIGTERM) }, 0);
    let o = child.wait_with_output().unwrap();
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(143), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(err.contains("interrupted by SIGTERM at step"), "{err}");
    let s = summary(&out);
    assert_eq!(s["status"], "interrupted");
    let step = s["steps"].as_u64().unwrap();
    assert!(
        step > 0 && step.is_multiple_of(4),
        "stops at the end of a graph run of 4 steps: {step}"
    );
    let ck = out.join("checkpoints").join(format!("step-{step}"));
    assert!(ck.is_file(), "no checkpoint of the step reached");
    assert_eq!(s["checkpoint"].as_str().unwrap(), ck.display().to_string());
    assert!(out.join("series.csv").is_file());

    let total = (step + 12).to_string();
    let want = run_ok(
        &[&tg, "--set", "scene.resolution=16", "--steps", &total],
        &dir.join("straight"),
    );
    let got = run_ok(
        &[
            "--restart",
            &ck.display().to_string(),
            "--steps",
            &total,
            "--processes",
            "2",
        ],
        &dir.join("resumed"),
    );
    assert_eq!(checksums(&got), checksums(&want));
}

/// SIGINT without periodic checkpoints: the interruption writes the run's only checkpoint; exit 130.
#[test]
fn sigint_without_periodic_checkpoints_writes_one() {
    let out = common::fresh_dir("sigint");
    let child = Command::new(env!("CARGO_BIN_EXE_blockflow"))
        .args([
            "run",
            &common::scene_path("taylor_green.toml"),
            "--set",
            "scene.resolution=16",
        ])
        .args(["--steps", "1000000", "--out"])
        .arg(&out)
        .stderr(Stdio::piped())
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    wait_for("the run to start", || out.join("series.csv.partial").exists());
    std::thread::sleep(Duration::from_millis(300));
    // SAFETY: plain kill(2) of our child.
    assert_eq!(unsafe { libc::kill(child.id() as i32, libc::SIGINT) }, 0);
    let o = child.wait_with_output().unwrap();
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(130), "{err}");
    assert!(err.contains("interrupted by SIGINT"), "{err}");
    let s = summary(&out);
    assert_eq!(s["status"], "interrupted");
    let ck = out.join("checkpoints").join(format!("step-{}", s["steps"]));
    assert!(ck.is_file(), "{}", ck.display());
    let c = blockflow::checkpoint::Checkpoint::read(&ck).expect("a complete checkpoint");
    assert_eq!(Some(c.step), s["steps"].as_u64());
}

/// A second signal ends the run at once (no hang, no panic), with 128 + the signal.
#[test]
fn second_signal_aborts_at_once() {
    let out = common::fresh_dir("twice");
    let child = Command::new(env!("CARGO_BIN_EXE_blockflow"))
        .args(["run", &common::scene_path("taylor_green.toml"), "--steps", "1000000"])
        .args(["--checkpoint-every", "4", "--out"])
        .arg(&out)
        .stderr(Stdio::piped())
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    wait_for("the first checkpoint", || has_checkpoint(&out));
    let pid = child.id() as i32;
    // SAFETY: plain kill(2) of our child.
    unsafe {
        libc::kill(pid, libc::SIGINT);
        libc::kill(pid, libc::SIGINT);
    }
    let t0 = Instant::now();
    let o = child.wait_with_output().unwrap();
    assert_eq!(o.status.code(), Some(130), "{}", stderr(&o));
    assert!(!stderr(&o).contains("panicked"));
    assert!(t0.elapsed() < Duration::from_secs(30));
    // Whatever was cut short, every file named step-<step> is a complete checkpoint.
    for (_, p) in blockflow::checkpoint::list(&out.join("checkpoints")) {
        blockflow::checkpoint::Checkpoint::read(&p).expect("complete");
    }
}

#[test]
fn output_folder_and_memory_are_checked_before_the_first_step() {
    let dir = common::fresh_dir("resources");
    let file = dir.join("a-file");
    std::fs::write(&file, b"x").unwrap();
    let o = blockflow(&[
        "run",
        &common::scene_path("taylor_green.toml"),
        "--out",
        &file.join("sub").display().to_string(),
    ]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("output folder") && err.contains("a-file/sub"), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    // A huge domain is refused before allocation, with the estimate in bytes.
    fails_cleanly(
        &[
            &common::scene_path("taylor_green.toml"),
            "--set",
            "scene.resolution=40000",
        ],
        1,
        &["needs an estimated", "bytes", "MemAvailable", "domain.blocks"],
    );
}

/// The output folder removed during a run: a clear error naming a file in it, non-zero exit, and no
/// summary that looks like a result.
#[test]
fn a_write_failing_later_is_a_clear_error() {
    let dir = common::fresh_dir("removed");
    let out = dir.join("out");
    let child = Command::new(env!("CARGO_BIN_EXE_blockflow"))
        .args([
            "run",
            &common::scene_path("taylor_green.toml"),
            "--set",
            "scene.resolution=16",
        ])
        .args(["--steps", "1000000", "--checkpoint-every", "8", "--out"])
        .arg(&out)
        .stderr(Stdio::piped())
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    wait_for("the first checkpoint", || has_checkpoint(&out));
    // (A file the run creates meanwhile can make one attempt fail with "directory not empty".)
    wait_for("the folder's removal", || {
        std::fs::remove_dir_all(&out).is_ok() || !out.exists()
    });
    let o = child.wait_with_output().unwrap();
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(err.contains(&out.display().to_string()), "{err}");
    assert!(!err.contains("panicked"));
    assert!(!out.join("summary.json").exists());
}
