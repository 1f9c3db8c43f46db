//! Unit tests of the executor: graph shapes under both stealing policies, bad pool shapes, panics in tasks
//! and broadcasts, parking hand-overs between processes, timing records and pinning.

use super::shared::lock;
use super::*;
use std::panic::{self, AssertUnwindSafe};
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::sync::Mutex;
use std::thread;
use std::time::Instant;

/// Runs `graph` and checks: every task exactly once, edges respected (sequence numbers), owner process
/// respected under process stealing, records consistent.
fn check(pool: &Executor, graph: &TaskGraph, edges: &[(TaskId, TaskId)]) {
    let n = graph.len();
    let seq = AtomicU64::new(1);
    let count: Vec<AtomicU32> = (0..n).map(|_| AtomicU32::new(0)).collect();
    let starts: Vec<AtomicU64> = (0..n).map(|_| AtomicU64::new(0)).collect();
    let ends: Vec<AtomicU64> = (0..n).map(|_| AtomicU64::new(0)).collect();
    let wrong_process = AtomicU32::new(0);
    let tpp = pool.threads_per_process() as u32;
    let rec = pool.run(graph, |t, s, w| {
        starts[t as usize].store(seq.fetch_add(1, Ordering::SeqCst), Ordering::SeqCst);
        count[t as usize].fetch_add(1, Ordering::SeqCst);
        assert_eq!(w.process, w.index / tpp);
        if pool.steal() == Steal::Process && w.process != s.owner {
            wrong_process.fetch_add(1, Ordering::SeqCst);
        }
        ends[t as usize].store(seq.fetch_add(1, Ordering::SeqCst), Ordering::SeqCst);
    });
    assert_eq!(rec.records.len(), n);
    for (t, c) in count.iter().enumerate() {
        assert_eq!(c.load(Ordering::SeqCst), 1, "task {t} ran a wrong number of times");
    }
    for &(a, b) in edges {
        assert!(
            ends[a as usize].load(Ordering::SeqCst) < starts[b as usize].load(Ordering::SeqCst),
            "edge {a} -> {b} violated"
        );
        assert!(rec.records[a as usize].end_ns <= rec.records[b as usize].start_ns);
    }
    assert_eq!(wrong_process.load(Ordering::SeqCst), 0);
    for r in &rec.records {
        assert!(r.start_ns <= r.end_ns && r.end_ns <= rec.wall_ns);
        assert!((r.worker as usize) < pool.workers());
        assert_eq!(r.process, r.worker / tpp);
    }
}

fn build(owners: &[u32], edges: &[(TaskId, TaskId)]) -> TaskGraph {
    TaskGraph::from_edges(owners, edges).unwrap()
}

fn chain(n: u32, p: u32) -> (TaskGraph, Vec<(TaskId, TaskId)>) {
    let owners: Vec<u32> = (0..n).map(|i| (i * 7 / 3) % p).collect();
    let edges: Vec<_> = (1..n).map(|i| (i - 1, i)).collect();
    (build(&owners, &edges), edges)
}

fn fork_join(width: u32, p: u32) -> (TaskGraph, Vec<(TaskId, TaskId)>) {
    // 0 -> 1..=width -> width+1, twice in a row.
    let mut owners = vec![0];
    let mut edges = Vec::new();
    let mut src = 0;
    for _ in 0..2 {
        let base = owners.len() as u32;
        for i in 0..width {
            owners.push(i % p);
            edges.push((src, base + i));
        }
        let join = owners.len() as u32;
        owners.push(p - 1);
        for i in 0..width {
            edges.push((base + i, join));
        }
        src = join;
    }
    (build(&owners, &edges), edges)
}

fn diamond(p: u32) -> (TaskGraph, Vec<(TaskId, TaskId)>) {
    let owners = [0, 1 % p, 2 % p, 3 % p];
    let edges = vec![(0, 1), (0, 2), (1, 3), (2, 3)];
    (build(&owners, &edges), edges)
}

const SHAPES: [(usize, usize); 5] = [(1, 1), (2, 1), (3, 2), (8, 1), (5, 2)];

fn all_graphs(p: u32) -> Vec<(TaskGraph, Vec<(TaskId, TaskId)>)> {
    vec![chain(200, p), fork_join(50, p), diamond(p), chain(1, p)]
}

#[test]
fn shapes_with_process_stealing() {
    for (p, t) in SHAPES {
        let pool = Executor::new(PoolConfig::unpinned(p, t)).unwrap();
        assert_eq!((pool.processes(), pool.threads_per_process()), (p, t));
        for (g, e) in all_graphs(p as u32) {
            for _ in 0..3 {
                check(&pool, &g, &e);
            }
        }
    }
}

#[test]
fn shapes_with_global_stealing() {
    for (p, t) in SHAPES {
        let pool = Executor::new(PoolConfig::unpinned(p, t).with_steal(Steal::Global)).unwrap();
        assert_eq!(pool.steal(), Steal::Global);
        for (g, e) in all_graphs(p as u32) {
            for _ in 0..3 {
                check(&pool, &g, &e);
            }
        }
    }
}

#[test]
fn graph_with_fewer_processes_and_empty_graph() {
    let pool = Executor::new(PoolConfig::unpinned(3, 1)).unwrap();
    let (g, e) = chain(20, 1);
    check(&pool, &g, &e);
    let empty = GraphBuilder::new().build().unwrap();
    let r = pool.run(&empty, |_, _, _| unreachable!());
    assert!(r.records.is_empty());
}

#[test]
#[should_panic(expected = "only 2 processes")]
fn too_many_processes_in_graph() {
    let pool = Executor::new(PoolConfig::unpinned(2, 1)).unwrap();
    let (g, _) = chain(5, 3);
    pool.run(&g, |_, _, _| {});
}

#[test]
fn executor_is_send_and_sync() {
    fn assert_send_sync<T: Send + Sync>() {}
    assert_send_sync::<Executor>();
    assert_send_sync::<RunRecords>();
}

#[test]
fn bad_shapes_are_errors() {
    assert!(Executor::new(PoolConfig::unpinned(0, 1))
        .unwrap_err()
        .contains("at least one"));
    assert!(Executor::new(PoolConfig::unpinned(1, 0))
        .unwrap_err()
        .contains("at least one"));
    let mut cfg = PoolConfig::unpinned(2, 2);
    cfg.cores.pop();
    assert!(Executor::new(cfg).unwrap_err().contains("3 cores were given"));
    let mut cfg = PoolConfig::unpinned(1, 2);
    cfg.cores[1] = Some(1 << 20);
    let e = Executor::new(cfg).unwrap_err();
    assert!(e.contains("worker 1") && e.contains("core 1048576"), "{e}");
    // A core that exists in no cpu set of this machine: the pin itself fails.
    let available = core_affinity::get_core_ids().map(|c| c.len()).unwrap_or(0);
    if available < 512 {
        let cfg = PoolConfig {
            processes: 2,
            threads_per_process: 1,
            cores: vec![Some(0), Some(600)],
            steal: Steal::Process,
        };
        let e = Executor::new(cfg).unwrap_err();
        assert!(e.contains("worker 1") && e.contains("core 600"), "{e}");
    }
}

#[test]
fn panic_is_resumed_and_pool_stays_usable() {
    for (p, t, steal) in [(1, 1, Steal::Process), (2, 2, Steal::Process), (3, 1, Steal::Global)] {
        let pool = Executor::new(PoolConfig::unpinned(p, t).with_steal(steal)).unwrap();
        let (g, e) = fork_join(40, p as u32);
        let r = panic::catch_unwind(AssertUnwindSafe(|| {
            pool.run(&g, |id, _, _| {
                if id == 7 {
                    panic!("task seven failed");
                }
            })
        }));
        let payload = r.expect_err("the panic must reach the caller");
        assert_eq!(payload.downcast_ref::<&str>(), Some(&"task seven failed"));
        for _ in 0..3 {
            check(&pool, &g, &e);
        }
        let (g, e) = chain(100, p as u32);
        check(&pool, &g, &e);
    }
}

#[test]
fn nested_run_panics_instead_of_deadlocking() {
    let pool = Executor::new(PoolConfig::unpinned(1, 1)).unwrap();
    let (g, _) = chain(2, 1);
    let r = panic::catch_unwind(AssertUnwindSafe(|| {
        pool.run(&g, |_, _, _| pool.on_each_process(|_| {}))
    }));
    assert!(r.is_err());
    let (g, e) = chain(10, 1);
    check(&pool, &g, &e);
}

#[test]
fn ping_pong_between_parked_processes() {
    // Every task hands over to another process, and every so often a task is slow enough that the other
    // workers give up spinning and park: each hand-over must wake the right process.
    for (p, t, steal) in [(2, 1, Steal::Process), (3, 2, Steal::Process), (4, 1, Steal::Global)] {
        let pool = Executor::new(PoolConfig::unpinned(p, t).with_steal(steal)).unwrap();
        let owners: Vec<u32> = (0..300).map(|i| i % p as u32).collect();
        let edges: Vec<_> = (1..300).map(|i| (i - 1, i)).collect();
        let g = build(&owners, &edges);
        let seen = AtomicU32::new(0);
        pool.run(&g, |id, s, w| {
            if steal == Steal::Process {
                assert_eq!(w.process, s.owner);
            }
            if id % 50 == 0 {
                thread::sleep(std::time::Duration::from_millis(2));
            }
            seen.fetch_add(1, Ordering::SeqCst);
        });
        assert_eq!(seen.load(Ordering::SeqCst), 300);
        check(&pool, &g, &edges);
    }
}

#[test]
fn on_each_process_runs_on_first_workers() {
    let pool = Executor::new(PoolConfig::unpinned(3, 2)).unwrap();
    for _ in 0..20 {
        let hits: Vec<AtomicU32> = (0..3).map(|_| AtomicU32::new(0)).collect();
        let names: Mutex<Vec<(u32, String)>> = Mutex::new(Vec::new());
        pool.on_each_process(|p| {
            hits[p as usize].fetch_add(1, Ordering::SeqCst);
            let name = thread::current().name().unwrap_or("").to_string();
            lock(&names).push((p, name));
        });
        assert!(hits.iter().all(|h| h.load(Ordering::SeqCst) == 1));
        let mut names = names.into_inner().unwrap();
        names.sort();
        let expect: Vec<(u32, String)> = (0..3).map(|p| (p, format!("blockflow-p{p}-t0"))).collect();
        assert_eq!(names, expect);
    }
    let (g, e) = fork_join(30, 3);
    check(&pool, &g, &e);
    let r = panic::catch_unwind(AssertUnwindSafe(|| {
        pool.on_each_process(|p| assert_ne!(p, 1, "process one refuses"));
    }));
    assert!(r.is_err());
    check(&pool, &g, &e);
}

#[test]
fn records_time_busy_tasks() {
    let pool = Executor::new(PoolConfig::unpinned(1, 1)).unwrap();
    let (g, _) = chain(3, 1);
    let r = pool.run(&g, |_, _, _| {
        let t = Instant::now();
        while t.elapsed().as_micros() < 2000 {
            std::hint::spin_loop();
        }
    });
    for rec in &r.records {
        let wall = rec.end_ns - rec.start_ns;
        assert!(wall >= 2_000_000, "{rec:?}");
        // CPU time is at most the wall time (plus clock granularity) and most of it on an idle machine.
        assert!(rec.cpu_ns <= wall + 100_000, "{rec:?}");
        assert!(rec.cpu_ns > 0, "{rec:?}");
    }
    assert!(r.wall_ns >= 6_000_000);
}

#[test]
fn pinned_workers_run_on_their_cores() {
    let available = core_affinity::get_core_ids().map(|c| c.len()).unwrap_or(0);
    if available < 2 {
        eprintln!("skipping: fewer than 2 cores available");
        return;
    }
    let cfg = PoolConfig {
        processes: 2,
        threads_per_process: 1,
        cores: vec![Some(0), Some(1)],
        steal: Steal::Process,
    };
    let pool = Executor::new(cfg).unwrap();
    assert_eq!(pool.cores(), &[Some(0), Some(1)]);
    let bad = AtomicU32::new(0);
    let (g, _) = fork_join(50, 2);
    pool.run(&g, |_, _, w| {
        // SAFETY: sched_getcpu has no preconditions.
        let cpu = unsafe { libc::sched_getcpu() };
        if cpu != w.index as i32 {
            bad.fetch_add(1, Ordering::SeqCst);
        }
    });
    assert_eq!(bad.load(Ordering::SeqCst), 0);
    pool.on_each_process(|p| {
        // SAFETY: as above.
        assert_eq!(unsafe { libc::sched_getcpu() }, p as i32);
    });
}

#[test]
fn overhead_is_measured() {
    let pool = Executor::new(PoolConfig::unpinned(1, 1)).unwrap();
    let ns = empty_task_overhead_ns(&pool, 2000);
    assert!(ns > 0.0 && ns.is_finite());
    assert_eq!(empty_task_overhead_ns(&pool, 0), 0.0);
}

/// External dependencies: a task waits for its predecessors and for the driver's releases; the run ends
/// only when every release was made and every task ran.
#[test]
fn external_dependencies_wait_for_the_driver() {
    let pool = Executor::new(PoolConfig::unpinned(2, 2)).unwrap();
    // a → b; c waits for one release, d for c and two releases.
    let mut g = GraphBuilder::new();
    let a = g.add(TaskSpec::for_owner(0));
    let b = g.add(TaskSpec::for_owner(1));
    let c = g.add(TaskSpec::for_owner(1));
    let d = g.add(TaskSpec::for_owner(0));
    g.edge(a, b);
    g.edge(c, d);
    g.external(c, 1);
    g.external(d, 2);
    let g = g.build().unwrap();
    for round in 0..50 {
        let seq = AtomicU64::new(1);
        let at: Vec<AtomicU64> = (0..4).map(|_| AtomicU64::new(0)).collect();
        let mut releases: Vec<(u64, TaskId)> = Vec::new();
        let rec = pool.run_with_progress(
            &g,
            |t, _, _| {
                at[t as usize].store(seq.fetch_add(1, Ordering::SeqCst), Ordering::SeqCst);
            },
            |r| {
                // Release c once a has run, then d twice once c has run (one per call).
                if at[a as usize].load(Ordering::SeqCst) > 0 && !releases.iter().any(|x| x.1 == c) {
                    releases.push((seq.fetch_add(1, Ordering::SeqCst), c));
                    r.release(c);
                    return true;
                }
                if at[c as usize].load(Ordering::SeqCst) > 0 && releases.iter().filter(|x| x.1 == d).count() < 2 {
                    releases.push((seq.fetch_add(1, Ordering::SeqCst), d));
                    r.release(d);
                    return true;
                }
                false
            },
        );
        assert_eq!(rec.records.len(), 4);
        let when = |t: TaskId| at[t as usize].load(Ordering::SeqCst);
        assert!((0..4).all(|t| when(t) > 0), "round {round}: every task ran");
        assert!(when(a) < when(b), "edge a -> b");
        let rel_c = releases.iter().find(|x| x.1 == c).unwrap().0;
        let last_d = releases.iter().filter(|x| x.1 == d).map(|x| x.0).max().unwrap();
        assert!(
            rel_c < when(c) && when(c) < when(d) && last_d < when(d),
            "round {round}"
        );
    }
    // A graph with external dependencies refuses the plain run.
    let r = panic::catch_unwind(AssertUnwindSafe(|| pool.run(&g, |_, _, _| {})));
    assert!(r.is_err());
}

/// Two pools in two threads (two "ranks") passing a token through 200 tasks that each wait for the
/// other rank's previous task: every task runs once, in token order, and both runs end.
#[test]
fn two_drivers_pass_messages_between_their_graphs() {
    use crossbeam::channel::{unbounded, Receiver, Sender};
    const N: u32 = 100;
    let rank = |me: u32, tx: Sender<u32>, rx: Receiver<u32>, log: &Mutex<Vec<(u32, u32)>>| {
        let pool = Executor::new(PoolConfig::unpinned(1, 2)).unwrap();
        let mut g = GraphBuilder::new();
        let ids: Vec<TaskId> = (0..N).map(|_| g.add(TaskSpec::for_owner(0))).collect();
        for (i, &t) in ids.iter().enumerate() {
            // Rank 0's first task starts the chain; every other waits for the token.
            if !(me == 0 && i == 0) {
                g.external(t, 1);
            }
        }
        let g = g.build().unwrap();
        let driver = thread::current();
        let outbox: Mutex<Vec<u32>> = Mutex::new(Vec::new());
        pool.run_with_progress(
            &g,
            |t, _, _| {
                log.lock().unwrap().push((me, t));
                outbox.lock().unwrap().push(t);
                driver.unpark();
            },
            |r| {
                let mut did = false;
                for t in outbox.lock().unwrap().drain(..) {
                    // The last token finds the other rank gone (its run ended): nothing waits for it.
                    let _ = tx.send(t);
                    did = true;
                }
                while let Ok(t) = rx.try_recv() {
                    // The other rank's task t releases this rank's task t (rank 0) or t (rank 1).
                    let next = if me == 0 { t + 1 } else { t };
                    if next < N {
                        r.release(ids[next as usize]);
                    }
                    did = true;
                }
                did
            },
        );
    };
    let log = Mutex::new(Vec::new());
    let (t01, r01) = unbounded();
    let (t10, r10) = unbounded();
    thread::scope(|s| {
        s.spawn(|| rank(0, t01, r10, &log));
        s.spawn(|| rank(1, t10, r01, &log));
    });
    let log = log.into_inner().unwrap();
    let want: Vec<(u32, u32)> = (0..N).flat_map(|t| [(0, t), (1, t)]).collect();
    assert_eq!(log, want);
}

/// A run whose driver gives up (the message a task waits for will never come) ends: the tasks already
/// ready run or are dropped, the waiting one never runs, and the pool stays usable.
#[test]
fn a_cancelled_run_ends_without_its_waiting_tasks() {
    let pool = Executor::new(PoolConfig::unpinned(1, 2)).unwrap();
    let mut g = GraphBuilder::new();
    let a = g.add(TaskSpec::for_owner(0));
    let b = g.add(TaskSpec::for_owner(0));
    let c = g.add(TaskSpec::for_owner(0));
    g.edge(a, b);
    g.external(c, 1);
    let g = g.build().unwrap();
    let ran: Vec<AtomicU32> = (0..3).map(|_| AtomicU32::new(0)).collect();
    let mut calls = 0;
    let rec = pool.run_with_progress(
        &g,
        |t, _, _| {
            ran[t as usize].fetch_add(1, Ordering::SeqCst);
        },
        |r| {
            calls += 1;
            if ran[b as usize].load(Ordering::SeqCst) == 1 {
                r.cancel();
            }
            false
        },
    );
    assert!(rec.cancelled && calls > 0);
    assert_eq!(ran[c as usize].load(Ordering::SeqCst), 0);
    let (g2, e2) = chain(20, 1);
    check(&pool, &g2, &e2);
}
