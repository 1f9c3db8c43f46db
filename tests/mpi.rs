//! The same scene on `mpirun -np N blockflow run ...` (a build with `--features mpi`, Open MPI) gives the
//! checksums of one process: on 1–3 ranks, with 2 threads per rank, with blocks migrating between ranks;
//! a rank killed after a checkpoint is restarted on another rank count and as virtual processes; a bad
//! key is one line and exit 1 on every rank; SIGUSR1 to mpirun checkpoints and stops.
#![cfg(feature = "mpi")]

mod common;

use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_blockflow");

/// `mpirun -np N BIN ARGS` as root on an oversubscribed 2-core machine.
fn mpirun(np: usize) -> Command {
    let mut c = Command::new("mpirun");
    c.args(blockflow_scheduler::transport::MPIRUN_SMALL_MACHINE)
        .arg("-np")
        .arg(np.to_string())
        .arg(BIN)
        .env("OMPI_MCA_rmaps_base_oversubscribe", "1");
    c
}

/// Runs a command with a time limit (no MPI test may hang CI).
fn finish(mut c: Command, limit: Duration) -> Output {
    let mut child = c
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("mpirun runs");
    let start = Instant::now();
    loop {
        if child.try_wait().expect("wait").is_some() {
            return child.wait_with_output().expect("output");
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            panic!("{c:?} did not end within {limit:?}");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn ok(o: &Output) {
    assert!(o.status.success(), "failed: {}", String::from_utf8_lossy(&o.stderr));
}

fn summary(dir: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(dir.join("summary.json")).expect("summary.json")).unwrap()
}

/// A one-process run of the same scene (the MPI build without mpirun is a plain single process).
fn single(args: &[&str], out: &Path) -> serde_json::Value {
    let o = Command::new(BIN)
        .arg("run")
        .args(args)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap();
    ok(&o);
    summary(out)
}

fn on_ranks(np: usize, args: &[&str], out: &Path) -> serde_json::Value {
    let mut c = mpirun(np);
    c.arg("run").args(args).arg("--out").arg(out);
    ok(&finish(c, Duration::from_secs(120)));
    summary(out)
}

#[test]
fn ranks_of_an_mpi_job_give_the_checksums_of_one_process() {
    let dir = common::fresh_dir("checksums");
    let hopper = common::scene_path("hopper-small.toml");
    let args = [hopper.as_str(), "--steps", "120"];
    let want = single(&args, &dir.join("one"))["checksum"].clone();
    for np in [1, 2, 3] {
        let s = on_ranks(np, &args, &dir.join(format!("np{np}")));
        assert_eq!(s["checksum"], want, "-np {np}");
        assert_eq!(s["ranks"], np, "-np {np}");
    }
    let mut two = args.to_vec();
    two.extend_from_slice(&["--threads-per-process", "2"]);
    let s = on_ranks(2, &two, &dir.join("np2t2"));
    assert_eq!(s["checksum"], want, "-np 2 with 2 threads per rank");
    assert_eq!(s["threads_per_process"], 2);
}

#[test]
fn blocks_migrate_between_mpi_ranks() {
    let dir = common::fresh_dir("migrate");
    let hopper = common::scene_path("hopper-small.toml");
    let args = [
        hopper.as_str(),
        "--steps",
        "200",
        "--balance",
        "hilbert",
        "--interval",
        "50",
    ];
    let want = single(&args, &dir.join("one"))["checksum"].clone();
    let s = on_ranks(4, &args, &dir.join("np4"));
    assert_eq!(s["checksum"], want);
    assert!(s["balance"]["migrated_blocks"].as_u64().unwrap() > 0, "blocks moved");
    assert!(s["rank_messages"]["send"]["bytes"].as_u64().unwrap() > 0);
}

#[test]
fn a_killed_rank_restarts_from_its_checkpoint_on_other_ranks_and_processes() {
    let dir = common::fresh_dir("kill");
    let hopper = common::scene_path("hopper-small.toml");
    let out = dir.join("killed");
    let base = ["--balance", "hilbert", "--interval", "50"];
    let mut c = mpirun(3);
    c.args(["run", &hopper, "--steps", "4000", "--checkpoint-every", "100", "--out"])
        .arg(&out)
        .args(base);
    let mut child = c.stdout(Stdio::null()).stderr(Stdio::piped()).spawn().unwrap();
    let ck = out.join("checkpoints").join("step-100");
    let start = Instant::now();
    while !ck.exists() {
        assert!(start.elapsed() < Duration::from_secs(60), "no checkpoint");
        std::thread::sleep(Duration::from_millis(20));
    }
    // SIGKILL to one rank (a process of the binary, not mpirun): the launcher ends the job.
    let pattern = format!("^{BIN} run .*--steps 4000 --checkpoint-every 100");
    let ranks = Command::new("pgrep").args(["-f", &pattern]).output().unwrap();
    let pid: i32 = String::from_utf8_lossy(&ranks.stdout)
        .lines()
        .next()
        .expect("a rank")
        .trim()
        .parse()
        .unwrap();
    // SAFETY: kill has no memory effects.
    unsafe { libc::kill(pid, libc::SIGKILL) };
    let start = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "the job did not end after a rank was killed"
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    assert!(!status.success());
    let straight = single(
        &[&hopper, "--steps", "300", base[0], base[1], base[2], base[3]],
        &dir.join("straight"),
    );
    let ck = ck.display().to_string();
    let restart = [ck.as_str(), "--steps", "300"];
    let mut r = vec!["--restart"];
    r.extend_from_slice(&restart);
    let s = on_ranks(2, &r, &dir.join("np2"));
    assert_eq!(s["checksum"], straight["checksum"], "restarted on 2 ranks");
    let mut p = r.clone();
    p.extend_from_slice(&["--processes", "3"]);
    assert_eq!(
        single(&p, &dir.join("p3"))["checksum"],
        straight["checksum"],
        "restarted on 3 processes"
    );
}

#[test]
fn a_bad_key_is_one_line_and_exit_1_on_every_rank() {
    let mut c = mpirun(3);
    c.args([
        "run",
        &common::scene_path("hopper-small.toml"),
        "--set",
        "fluid.taux=0.6",
    ]);
    let o = finish(c, Duration::from_secs(60));
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
    assert_eq!(lines.len(), 1, "{err}");
    assert!(lines[0].contains("taux"), "{err}");
}

#[test]
fn sigusr1_to_mpirun_checkpoints_and_stops_every_rank() {
    let dir = common::fresh_dir("usr1");
    let out = dir.join("run");
    let mut c = mpirun(2);
    c.args([
        "run",
        &common::scene_path("hopper-small.toml"),
        "--steps",
        "100000",
        "--out",
    ])
    .arg(&out);
    let child = c.stdout(Stdio::null()).stderr(Stdio::piped()).spawn().unwrap();
    let start = Instant::now();
    while !out.join("series.csv.partial").exists() {
        assert!(start.elapsed() < Duration::from_secs(60), "the run did not start");
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(500));
    // SAFETY: kill has no memory effects.
    unsafe { libc::kill(child.id() as i32, libc::SIGUSR1) };
    let o = child.wait_with_output().unwrap();
    assert_eq!(
        o.status.code(),
        Some(128 + libc::SIGUSR1),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let s = summary(&out);
    assert_eq!(s["status"], "interrupted");
    let ck = s["checkpoint"].as_str().expect("a checkpoint");
    assert!(Path::new(ck).exists());
}

#[test]
fn a_failure_on_one_rank_ends_every_rank_with_its_code_and_one_line() {
    let dir = common::fresh_dir("one-fails");
    let trace = dir.join("trace.json");
    // Rank 1 writes its trace to trace.rank1.json: a folder there makes that write fail on rank 1 only.
    std::fs::create_dir_all(dir.join("trace.rank1.json")).unwrap();
    let mut c = mpirun(2);
    c.args([
        "run",
        &common::scene_path("hopper-small.toml"),
        "--steps",
        "20",
        "--trace",
    ])
    .arg(&trace)
    .arg("--out")
    .arg(dir.join("run"));
    let o = finish(c, Duration::from_secs(60));
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
    assert_eq!(lines.len(), 1, "{err}");
    assert!(
        lines[0].contains("rank 1") && lines[0].contains("trace.rank1.json"),
        "{err}"
    );
}
