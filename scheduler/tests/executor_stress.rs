//! Stress test of the executor: 1000 random DAGs (1..300 tasks, random edges from lower to higher ids, random
//! owners, tiny random busy durations), each run on two of seven pool shapes / stealing policies and checked
//! for exactly-once execution, edge order and (with process stealing) owner placement; under a watchdog.

use blockflow_scheduler::executor::{Executor, PoolConfig, Steal};
use blockflow_scheduler::{GraphBuilder, TaskGraph, TaskId, TaskSpec};
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::sync::mpsc;
use std::thread;
use std::time::{Duration, Instant};

/// xorshift64*: deterministic, no external crate.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        let mut x = self.0;
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        self.0 = x;
        x.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
}

struct Case {
    graph: TaskGraph,
    edges: Vec<(TaskId, TaskId)>,
    /// Busy time per task, nanoseconds.
    busy_ns: Vec<u64>,
}

fn random_case(rng: &mut Rng, processes: usize) -> Case {
    let n = 1 + rng.below(300) as u32;
    let mut g = GraphBuilder::new();
    let mut busy_ns = Vec::with_capacity(n as usize);
    for i in 0..n {
        g.add(TaskSpec {
            owner: rng.below(processes as u64) as u32,
            part: (i % 6) as u8,
            block: i,
            payload: 0,
        });
        // Most tasks are empty or very short, a few take up to 20 µs.
        busy_ns.push(match rng.below(4) {
            0 => 0,
            1 | 2 => rng.below(2_000),
            _ => rng.below(20_000),
        });
    }
    // Edge density varies per graph: from almost independent tasks to dense, deep DAGs.
    let density = 1 + rng.below(4);
    let mut edges = Vec::new();
    for b in 1..n {
        let k = rng.below(density + 1);
        for _ in 0..k {
            // Mostly near predecessors (deep graphs), sometimes far ones (wide fan-in).
            let a = if rng.below(3) == 0 {
                rng.below(b as u64) as u32
            } else {
                b - 1 - rng.below((b as u64).min(8)) as u32
            };
            edges.push((a, b));
        }
    }
    for &(a, b) in &edges {
        g.edge(a, b);
    }
    edges.sort_unstable();
    edges.dedup();
    Case {
        graph: g.build().expect("edges go from lower to higher ids"),
        edges,
        busy_ns,
    }
}

fn busy(ns: u64) {
    if ns == 0 {
        return;
    }
    let t = Instant::now();
    while (t.elapsed().as_nanos() as u64) < ns {
        std::hint::spin_loop();
    }
}

fn check_case(pool: &Executor, case: &Case, label: &str) {
    let n = case.graph.len();
    let seq = AtomicU64::new(1);
    let runs: Vec<AtomicU32> = (0..n).map(|_| AtomicU32::new(0)).collect();
    let starts: Vec<AtomicU64> = (0..n).map(|_| AtomicU64::new(0)).collect();
    let ends: Vec<AtomicU64> = (0..n).map(|_| AtomicU64::new(0)).collect();
    let misplaced = AtomicU32::new(0);
    let process_steal = pool.steal() == Steal::Process;
    let rec = pool.run(&case.graph, |t, spec, w| {
        starts[t as usize].store(seq.fetch_add(1, Ordering::SeqCst), Ordering::SeqCst);
        runs[t as usize].fetch_add(1, Ordering::SeqCst);
        if process_steal && w.process != spec.owner {
            misplaced.fetch_add(1, Ordering::SeqCst);
        }
        busy(case.busy_ns[t as usize]);
        ends[t as usize].store(seq.fetch_add(1, Ordering::SeqCst), Ordering::SeqCst);
    });
    for (t, r) in runs.iter().enumerate() {
        assert_eq!(
            r.load(Ordering::SeqCst),
            1,
            "{label}: task {t} of {n} ran a wrong number of times"
        );
    }
    for &(a, b) in &case.edges {
        let (ea, sb) = (
            ends[a as usize].load(Ordering::SeqCst),
            starts[b as usize].load(Ordering::SeqCst),
        );
        assert!(ea < sb, "{label}: edge {a} -> {b} violated (end {ea}, start {sb})");
    }
    assert_eq!(
        misplaced.load(Ordering::SeqCst),
        0,
        "{label}: task ran outside its owner process"
    );
    assert_eq!(rec.records.len(), n);
    let tpp = pool.threads_per_process() as u32;
    for (t, r) in rec.records.iter().enumerate() {
        assert!(r.start_ns <= r.end_ns, "{label}: task {t}: {r:?}");
        assert_eq!(r.process, r.worker / tpp, "{label}: task {t}: {r:?}");
        if process_steal {
            assert_eq!(r.process, case.graph.spec(t as TaskId).owner, "{label}: task {t}");
        }
    }
}

fn stress() -> Duration {
    let settings = [
        (1, 1, Steal::Process),
        (2, 1, Steal::Process),
        (3, 2, Steal::Process),
        (5, 2, Steal::Process),
        (2, 2, Steal::Global),
        (5, 2, Steal::Global),
        (8, 1, Steal::Global),
    ];
    let pools: Vec<Executor> = settings
        .iter()
        .map(|&(p, t, s)| Executor::new(PoolConfig::unpinned(p, t).with_steal(s)).expect("valid pool"))
        .collect();
    let mut rng = Rng(0x5EED_B10C_F10Eu64);
    let start = Instant::now();
    for i in 0..1000 {
        // Each graph runs on two pools; its owners are drawn from the smaller one's processes.
        let k = i % settings.len();
        let k2 = (k + 3) % settings.len();
        let case = random_case(&mut rng, settings[k].0.min(settings[k2].0));
        for k in [k, k2] {
            let (p, t, steal) = settings[k];
            let label = format!(
                "graph {i} ({} tasks, {} edges) on {p}x{t} {steal:?}",
                case.graph.len(),
                case.edges.len()
            );
            check_case(&pools[k], &case, &label);
            // Re-arming: every tenth graph runs a second time on the same pool.
            if i % 10 == 0 {
                check_case(&pools[k], &case, &label);
            }
        }
    }
    start.elapsed()
}

#[test]
fn thousand_random_dags_finish_under_a_watchdog() {
    let (tx, rx) = mpsc::channel();
    let worker = thread::spawn(move || {
        let took = stress();
        let _ = tx.send(took);
    });
    match rx.recv_timeout(Duration::from_secs(120)) {
        Ok(took) => {
            eprintln!("1000 random DAGs took {:.2} s", took.as_secs_f64());
            worker.join().expect("stress thread");
        }
        Err(mpsc::RecvTimeoutError::Disconnected) => {
            // The stress thread panicked: report its panic.
            if let Err(e) = worker.join() {
                std::panic::resume_unwind(e);
            }
        }
        Err(mpsc::RecvTimeoutError::Timeout) => panic!("the stress test did not finish within 120 s (deadlock?)"),
    }
}

/// Many short runs of empty tasks back to back: workers go to sleep and are woken at every run start, and a
/// worker that drains its injector may park while the driver is still pushing roots (a lost wake-up there
/// once hung a run after some 30 000 runs).
#[test]
fn many_short_runs_never_lose_a_wake_up() {
    let (tx, rx) = mpsc::channel();
    let worker = thread::spawn(move || {
        for (p, t, steal, runs) in [
            (2, 1, Steal::Process, 15_000),
            (1, 2, Steal::Process, 10_000),
            (3, 2, Steal::Global, 5_000),
        ] {
            let pool = Executor::new(PoolConfig::unpinned(p, t).with_steal(steal)).expect("valid pool");
            let (graph, edges) = TaskGraph::synthetic_stencil(p as u32);
            let done = AtomicU64::new(0);
            for _ in 0..runs {
                pool.run(&graph, |_, _, _| {
                    done.fetch_add(1, Ordering::Relaxed);
                });
            }
            assert_eq!(done.load(Ordering::Relaxed), runs * graph.len() as u64);
            let case = Case {
                busy_ns: vec![0; graph.len()],
                graph,
                edges,
            };
            check_case(&pool, &case, &format!("stencil on {p}x{t} {steal:?}"));
        }
        let _ = tx.send(());
    });
    match rx.recv_timeout(Duration::from_secs(120)) {
        Ok(()) => worker.join().expect("short-run thread"),
        Err(mpsc::RecvTimeoutError::Disconnected) => {
            if let Err(e) = worker.join() {
                std::panic::resume_unwind(e);
            }
        }
        Err(mpsc::RecvTimeoutError::Timeout) => panic!("back-to-back runs did not finish within 120 s (lost wake-up?)"),
    }
}

/// The driver pushes one root of process 1, then many of process 0, then more of process 1: the worker of
/// process 1 runs the first, goes idle and parks while the driver is still busy, and must be woken for the
/// later ones.
#[test]
fn late_roots_wake_a_parked_worker() {
    let (tx, rx) = mpsc::channel();
    let worker = thread::spawn(move || {
        let pool = Executor::new(PoolConfig::unpinned(2, 1)).expect("valid pool");
        let mut g = GraphBuilder::new();
        let owners = std::iter::once(1)
            .chain(std::iter::repeat_n(0, 300_000))
            .chain(std::iter::repeat_n(1, 10));
        for (i, owner) in owners.enumerate() {
            g.add(TaskSpec {
                owner,
                part: 0,
                block: i as u32,
                payload: 0,
            });
        }
        let graph = g.build().expect("no edges");
        for _ in 0..5 {
            let done = AtomicU64::new(0);
            pool.run(&graph, |_, _, _| {
                done.fetch_add(1, Ordering::Relaxed);
            });
            assert_eq!(done.load(Ordering::Relaxed), graph.len() as u64);
        }
        let _ = tx.send(());
    });
    match rx.recv_timeout(Duration::from_secs(60)) {
        Ok(()) => worker.join().expect("late-roots thread"),
        Err(mpsc::RecvTimeoutError::Disconnected) => {
            if let Err(e) = worker.join() {
                std::panic::resume_unwind(e);
            }
        }
        Err(mpsc::RecvTimeoutError::Timeout) => panic!("a worker was not woken for late roots"),
    }
}

#[test]
fn panics_in_random_dags_leave_the_pool_usable() {
    let (tx, rx) = mpsc::channel();
    let worker = thread::spawn(move || {
        let mut rng = Rng(42);
        for (p, t, steal) in [(2, 2, Steal::Process), (3, 1, Steal::Global)] {
            let pool = Executor::new(PoolConfig::unpinned(p, t).with_steal(steal)).expect("valid pool");
            for i in 0..100 {
                let case = random_case(&mut rng, p);
                let victim = rng.below(case.graph.len() as u64) as TaskId;
                let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                    pool.run(&case.graph, |t, _, _| {
                        busy(case.busy_ns[t as usize] / 4);
                        if t == victim {
                            panic!("boom {t}");
                        }
                    })
                }));
                let payload = r.expect_err("the panic must reach the caller");
                assert_eq!(payload.downcast_ref::<String>(), Some(&format!("boom {victim}")));
                check_case(&pool, &case, &format!("after panic {i} on {p}x{t} {steal:?}"));
            }
        }
        let _ = tx.send(());
    });
    match rx.recv_timeout(Duration::from_secs(120)) {
        Ok(()) => worker.join().expect("panic stress thread"),
        Err(mpsc::RecvTimeoutError::Disconnected) => {
            if let Err(e) = worker.join() {
                std::panic::resume_unwind(e);
            }
        }
        Err(mpsc::RecvTimeoutError::Timeout) => panic!("the panic stress test did not finish within 120 s"),
    }
}
