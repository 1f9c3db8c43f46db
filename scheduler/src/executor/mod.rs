//! The executor: `P` virtual processes × `T` pinned worker threads that run a compiled [`TaskGraph`].
//!
//! # Model
//!
//! A pool has `P` *virtual processes* (stand-ins for MPI ranks), each a group of `T` persistent worker
//! threads. Worker `w` belongs to process `w / T` (process-major numbering). Every worker pins itself to its
//! core before it touches anything else, so the memory it allocates (its deque) and the memory its tasks
//! first-touch lands on its own NUMA node.
//!
//! Each process has an [`Injector`] (its shared ready queue) and every worker has a local work-stealing deque.
//! A run re-arms the compiled graph by resetting one atomic in-degree counter per task (the counters vector is
//! cached in the executor, so arming is a plain store per task), pushes the roots into their owners'
//! injectors and wakes workers there. A finishing task decrements its successors' counters; a successor that
//! reaches zero becomes ready *in its owner process*: the finishing worker keeps one such successor for itself
//! (it runs it next without a queue round trip) and pushes the others onto its local deque when it belongs to
//! the owner process; successors owned by another process go to that process's injector and an idle worker
//! there is woken.
//!
//! An idle worker looks, in this order, at: its local deque, its process's injector, the deques of its
//! sibling workers, and with [`Steal::Global`] the injectors and deques of the other processes. If all are
//! empty it spins a little, yields a few times and then parks. Parking uses a per-worker state word checked
//! against the queues in Dekker style (both sides publish, fence, then look), so a wake-up is never lost; a
//! pool worker never blocks waiting on a particular task.
//!
//! The thread calling [`Executor::run`] (the *driver*) is not a worker: it publishes the run, blocks on a
//! condition variable until the count of outstanding tasks reaches zero and returns the records.
//!
//! # Accounting
//!
//! A single counter, `pending`, counts tasks that are ready (in some queue or held as "next"), running, or
//! finished but not yet *retired*. The driver sets it to the number of roots; a finishing task with `k`
//! newly ready successors adds `k` *before* it publishes any of them and joins its worker's batch of
//! finished tasks; a worker retires its batch (subtracts its size) when it finds no more work, or when
//! the batch is full. `pending` reaches zero exactly when every task has finished and been retired (in an
//! acyclic graph the earliest unfinished task would otherwise be ready). If a task panics, the run is
//! *aborted*: tasks popped afterwards are retired without running and without releasing their successors,
//! so `pending` still drains to zero, all queues are empty again, and the panic is resumed on the driver.
//!
//! # Timing
//!
//! Every task execution records its wall interval (ns since the run started, from one [`Instant`]), the
//! worker and its process, and its thread CPU time, into the task's own slot of [`RunRecords::records`].
//! The thread CPU clock (`CLOCK_THREAD_CPUTIME_ID`, a system call) is read once at the start and once at
//! the retirement of each batch; the batch's CPU time is shared among its tasks in proportion to their
//! wall durations (and never above them). A batch's records are written before it is retired, i.e. while
//! the run is still alive.

mod shared;
pub use shared::thread_cpu_ns;
#[cfg(test)]
mod tests;
mod worker;

use self::shared::{call_bcast, call_task, lock, Bcast, Control, Job, Shared, Slot, AWAKE, WORKER_OF};
use self::worker::{worker_main, Hello};
use crate::graph::{GraphBuilder, TaskGraph, TaskId, TaskRecord, TaskSpec};
use crossbeam::channel;
use crossbeam::deque::{Injector, Stealer};
use crossbeam::utils::CachePadded;
use std::fmt;
use std::panic;
use std::sync::atomic::{fence, AtomicBool, AtomicPtr, AtomicU32, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex, PoisonError};
use std::thread::{self, JoinHandle, Thread};
use std::time::Instant;

/// Where idle workers may take ready tasks from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Steal {
    /// Only from their own process (MPI-faithful, the default).
    #[default]
    Process,
    /// From any process (a shared-memory experiment the MPI world cannot run).
    Global,
}

/// Pool shape.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PoolConfig {
    /// Number of virtual processes `P` (at least 1).
    pub processes: usize,
    /// Worker threads per process `T` (at least 1).
    pub threads_per_process: usize,
    /// Core per worker (length `P*T`, process-major: worker `w` belongs to process `w / T`); `None` = not
    /// pinned.
    pub cores: Vec<Option<usize>>,
    /// Where idle workers may take ready tasks from.
    pub steal: Steal,
}

impl PoolConfig {
    /// `P` processes of `T` unpinned threads each, stealing inside a process.
    pub fn unpinned(processes: usize, threads_per_process: usize) -> Self {
        PoolConfig {
            processes,
            threads_per_process,
            cores: vec![None; processes.saturating_mul(threads_per_process)],
            steal: Steal::Process,
        }
    }

    /// The same pool with another stealing policy.
    pub fn with_steal(mut self, steal: Steal) -> Self {
        self.steal = steal;
        self
    }
}

/// Identity of the worker running a task.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Worker {
    /// Worker index, `0 .. P*T`, process-major.
    pub index: u32,
    /// Process of that worker (`index / T`).
    pub process: u32,
}

/// What a run recorded.
#[derive(Clone, Debug, Default)]
pub struct RunRecords {
    /// One record per task, indexed by [`TaskId`].
    pub records: Vec<TaskRecord>,
    /// Wall time of the whole run as the driver saw it (publishing, executing, collecting), nanoseconds.
    pub wall_ns: u64,
    /// Whether the driver's progress function gave the run up ([`Releaser::cancel`]): the tasks not yet
    /// started never ran.
    pub cancelled: bool,
}

/// A pool of `P × T` persistent, pinned worker threads that runs task graphs (see the module docs).
///
/// Runs are serialised: concurrent calls of [`Executor::run`] / [`Executor::on_each_process`] from several
/// threads wait for each other. Calling them from inside a task of the same executor panics (it would
/// deadlock).
pub struct Executor {
    shared: Arc<Shared>,
    handles: Vec<JoinHandle<()>>,
    cores: Vec<Option<usize>>,
    steal: Steal,
    /// Serialises runs and caches what a run needs besides the graph.
    cache: Mutex<RunCache>,
}

impl fmt::Debug for Executor {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Executor")
            .field("processes", &self.shared.processes)
            .field("threads_per_process", &self.shared.tpp)
            .field("steal", &self.steal)
            .field("cores", &self.cores)
            .finish()
    }
}

/// Per-executor buffers reused by every run.
#[derive(Default)]
struct RunCache {
    /// In-degree counters, re-armed from the graph at the start of every run (only the first `n` are used).
    counters: Vec<AtomicU32>,
    /// Roots per process, for the initial wake-ups.
    roots_per_process: Vec<usize>,
}

impl Executor {
    /// Spawns `P*T` persistent worker threads; each pins itself (`core_affinity::set_for_current`) first,
    /// before touching anything else, then creates its deque. Returns `Err(message)` if `P` or `T` is 0,
    /// `cores` has the wrong length, a thread cannot be spawned, or a pin fails (naming the worker and the
    /// core).
    pub fn new(cfg: PoolConfig) -> Result<Executor, String> {
        let (p, t) = (cfg.processes, cfg.threads_per_process);
        if p == 0 || t == 0 {
            return Err(format!(
                "a pool needs at least one process and one thread per process (got {p} x {t})"
            ));
        }
        let n = p.checked_mul(t).ok_or_else(|| format!("pool {p} x {t} is too large"))?;
        if u32::try_from(n).is_err() {
            return Err(format!("pool {p} x {t} is too large"));
        }
        if cfg.cores.len() != n {
            return Err(format!(
                "the pool has {n} workers ({p} processes x {t} threads) but {} cores were given",
                cfg.cores.len()
            ));
        }
        let setsize = libc::CPU_SETSIZE as usize;
        for (w, c) in cfg.cores.iter().enumerate() {
            if let Some(c) = *c {
                if c >= setsize {
                    return Err(format!(
                        "worker {w} (process {}, thread {}) cannot be pinned to core {c}: core ids must be below {setsize}",
                        w / t,
                        w % t
                    ));
                }
            }
        }

        let (hello_tx, hello_rx) = channel::unbounded::<Hello>();
        let (start_tx, start_rx) = channel::unbounded::<Arc<Shared>>();
        let mut handles = Vec::with_capacity(n);
        let mut spawn_error = None;
        for w in 0..n {
            let core = cfg.cores[w];
            let hello = hello_tx.clone();
            let start = start_rx.clone();
            let me = Worker {
                index: w as u32,
                process: (w / t) as u32,
            };
            let spawned = thread::Builder::new()
                .name(format!("blockflow-p{}-t{}", w / t, w % t))
                .spawn(move || worker_main(me, core, hello, start));
            match spawned {
                Ok(h) => handles.push(h),
                Err(e) => {
                    spawn_error = Some(format!("cannot spawn worker {w}: {e}"));
                    break;
                }
            }
        }
        drop(hello_tx);
        drop(start_rx);

        let mut slots: Vec<Option<(Stealer<TaskId>, Thread)>> = (0..n).map(|_| None).collect();
        let mut errors: Vec<(usize, String)> = Vec::new();
        for _ in 0..handles.len() {
            match hello_rx.recv() {
                Ok((w, Ok(x))) => slots[w] = Some(x),
                Ok((w, Err(e))) => errors.push((w, e)),
                Err(_) => {
                    errors.push((usize::MAX, "a worker thread exited before reporting".to_string()));
                    break;
                }
            }
        }
        errors.sort();
        let error = spawn_error.or_else(|| errors.into_iter().next().map(|(_, e)| e));
        if let Some(e) = error {
            // Workers waiting for the start message see the channel close and exit.
            drop(start_tx);
            for h in handles {
                let _ = h.join();
            }
            return Err(e);
        }

        let slots: Box<[CachePadded<Slot>]> = slots
            .into_iter()
            .map(|s| {
                let (stealer, thread) = s.expect("every worker reported");
                CachePadded::new(Slot {
                    stealer,
                    thread,
                    state: AtomicU32::new(AWAKE),
                })
            })
            .collect();
        let shared = Arc::new(Shared {
            processes: p,
            tpp: t,
            global: cfg.steal == Steal::Global,
            injectors: (0..p).map(|_| CachePadded::new(Injector::new())).collect(),
            slots,
            sleeping: (0..p).map(|_| CachePadded::new(AtomicUsize::new(0))).collect(),
            pending: CachePadded::new(AtomicUsize::new(0)),
            ctl: CachePadded::new(Control {
                job: AtomicPtr::new(std::ptr::null_mut()),
                bcast: AtomicPtr::new(std::ptr::null_mut()),
                bcast_epoch: AtomicU64::new(0),
                shutdown: AtomicBool::new(false),
            }),
            done: AtomicBool::new(false),
            done_lock: Mutex::new(()),
            done_cv: Condvar::new(),
            driver: Mutex::new(None),
        });
        for _ in 0..n {
            // Cannot fail: every worker holds a receiver until it gets its message.
            let _ = start_tx.send(shared.clone());
        }
        Ok(Executor {
            shared,
            handles,
            cores: cfg.cores,
            steal: cfg.steal,
            cache: Mutex::new(RunCache::default()),
        })
    }

    /// Number of virtual processes `P`.
    pub fn processes(&self) -> usize {
        self.shared.processes
    }

    /// Worker threads per process `T`.
    pub fn threads_per_process(&self) -> usize {
        self.shared.tpp
    }

    /// Total number of workers `P*T`.
    pub fn workers(&self) -> usize {
        self.shared.processes * self.shared.tpp
    }

    /// The stealing policy.
    pub fn steal(&self) -> Steal {
        self.steal
    }

    /// The core each worker was pinned to (process-major), `None` where it was not pinned.
    pub fn cores(&self) -> &[Option<usize>] {
        &self.cores
    }

    fn assert_not_worker(&self, what: &str) {
        let me = Arc::as_ptr(&self.shared) as usize;
        if WORKER_OF.with(|c| c.get()) == me {
            panic!("Executor::{what} was called from inside a task of the same executor (it would deadlock)");
        }
    }

    /// Runs every task of `graph` exactly once, respecting its edges, and returns when all are done.
    ///
    /// `task(id, spec, worker)` is called on a worker thread. A ready task is queued in its owner process;
    /// with [`Steal::Process`] it runs on a worker of that process, with [`Steal::Global`] possibly elsewhere.
    /// If `task` panics, the rest of the graph is abandoned cleanly (tasks already running finish, the others
    /// are dropped, the workers stay usable) and the first panic is resumed on the caller's thread.
    ///
    /// # Panics
    ///
    /// If `graph.processes()` exceeds the pool's `P`, if called from inside a task of this executor, or
    /// (resumed) if a task panicked.
    pub fn run<F: Fn(TaskId, &TaskSpec, Worker) + Sync>(&self, graph: &TaskGraph, task: F) -> RunRecords {
        assert_eq!(
            graph.external_total(),
            0,
            "a graph with external dependencies runs with Executor::run_with_progress"
        );
        self.run_inner(graph, task, None)
    }

    /// Runs a graph whose tasks may also wait for things outside it ([`crate::GraphBuilder::external`]:
    /// messages from other ranks), like [`Executor::run`]. The calling thread (the driver) calls
    /// `progress` again and again while the run is under way: it completes what it can (receives
    /// messages, sends what tasks queued) and releases each satisfied external dependency through the
    /// [`Releaser`]; it returns whether it did anything (when it did not, the driver backs off: it
    /// yields for 100 µs since it last did something, then parks for at most 50 µs or until the last
    /// running task retires, or until a task or a message unparks it). The run ends when every external dependency was released and every task has
    /// finished; `progress` is called once more after that (to send what the last tasks queued), and
    /// must not release anything then.
    ///
    /// # Panics
    ///
    /// As [`Executor::run`]; also if `progress` releases a task more often than it has external
    /// dependencies, or releases after the end.
    pub fn run_with_progress<F, P>(&self, graph: &TaskGraph, task: F, mut progress: P) -> RunRecords
    where
        F: Fn(TaskId, &TaskSpec, Worker) + Sync,
        P: FnMut(&mut Releaser<'_>) -> bool,
    {
        self.run_inner(graph, task, Some(&mut progress))
    }

    fn run_inner<F: Fn(TaskId, &TaskSpec, Worker) + Sync>(
        &self,
        graph: &TaskGraph,
        task: F,
        progress: Option<&mut dyn FnMut(&mut Releaser<'_>) -> bool>,
    ) -> RunRecords {
        assert!(
            graph.processes() <= self.shared.processes,
            "the task graph has tasks owned by process {} but the pool has only {} processes",
            graph.processes().saturating_sub(1),
            self.shared.processes
        );
        self.assert_not_worker("run");
        let n = graph.len();
        if n == 0 {
            if let Some(p) = progress {
                let mut r = Releaser::idle();
                p(&mut r);
                assert_eq!(r.released, 0, "an empty graph has nothing to release");
            }
            return RunRecords::default();
        }
        let sh = &*self.shared;
        let mut cache = lock(&self.cache);

        // Re-arm the counters (plain stores; the injector pushes below publish them).
        if cache.counters.len() < n {
            let extra = n - cache.counters.len();
            cache.counters.extend((0..extra).map(|_| AtomicU32::new(0)));
        }
        for (c, &d) in cache.counters.iter().zip(graph.indegrees()) {
            c.store(d, Ordering::Relaxed);
        }
        let mut records = vec![TaskRecord::default(); n];
        let start = Instant::now();
        let job = Job {
            graph,
            counters: cache.counters.as_ptr(),
            records: records.as_mut_ptr(),
            ctx: &task as *const F as *const (),
            call: call_task::<F>,
            start,
            aborted: AtomicBool::new(false),
            panic: Mutex::new(None),
        };

        // Publish. SAFETY argument for handing `&job` (and through it `&task`, `graph`, the counters and
        // the records) to the persistent workers: a worker dereferences the job pointer only while it holds a
        // task of this run, and every such task is counted in `pending` until the worker is done with it
        // (the successor release adds to `pending` before publishing any successor; a finished task is
        // retired with its worker's batch, after the batch's records are written). `wait_done` returns only after `pending`
        // reached zero and the worker that brought it there set `done`, so no worker touches any of these
        // after this function returns, and the acquire/release chain on `pending`/`done` makes all record
        // writes visible here.
        sh.done.store(false, Ordering::Relaxed);
        let roots = graph.roots();
        sh.pending.store(roots.len(), Ordering::Relaxed);
        sh.ctl.job.store(&job as *const Job as *mut Job, Ordering::Release);
        cache.roots_per_process.clear();
        cache.roots_per_process.resize(sh.processes, 0);
        for &r in roots {
            let owner = graph.spec(r).owner as usize;
            sh.injectors[owner].push(r);
            // Wake a worker of the owner as its first root arrives, so it starts while we push the rest.
            let count = &mut cache.roots_per_process[owner];
            *count += 1;
            if *count == 1 {
                sh.wake_for(owner);
            }
        }
        // After the last push (a worker woken above may have drained its injector and gone back to sleep
        // before we pushed more): wake up to T workers per process with roots; with global stealing, idle
        // workers elsewhere for the roots nobody was woken for.
        fence(Ordering::SeqCst);
        let mut surplus = 0;
        for (p, &count) in cache.roots_per_process.iter().enumerate() {
            let mut woken = 0;
            while woken < count.min(sh.tpp) && sh.wake_one_in(p) {
                woken += 1;
            }
            surplus += count - woken;
        }
        if sh.global {
            'outer: for p in 0..sh.processes {
                while surplus > 0 {
                    if !sh.wake_one_in(p) {
                        continue 'outer;
                    }
                    surplus -= 1;
                }
            }
        }

        match progress {
            None => sh.wait_done(),
            Some(p) => drive(sh, graph, &cache.counters, &job.aborted, p),
        }
        let wall_ns = start.elapsed().as_nanos() as u64;
        sh.ctl.job.store(std::ptr::null_mut(), Ordering::Relaxed);
        drop(cache);
        let panic = job.panic.into_inner().unwrap_or_else(PoisonError::into_inner);
        if let Some(payload) = panic {
            panic::resume_unwind(payload);
        }
        RunRecords {
            records,
            wall_ns,
            cancelled: job.aborted.into_inner(),
        }
    }

    /// Runs `f(process)` once on the first worker of every process, all processes concurrently, and returns
    /// when all are done (used so block memory is first-touched by a thread of its owner process). A panic
    /// in `f` is resumed on the caller after all processes have finished.
    ///
    /// # Panics
    ///
    /// If called from inside a task of this executor, or (resumed) if `f` panicked.
    pub fn on_each_process<F: Fn(u32) + Sync>(&self, f: F) {
        self.assert_not_worker("on_each_process");
        let sh = &*self.shared;
        let cache = lock(&self.cache);
        let b = Bcast {
            ctx: &f as *const F as *const (),
            call: call_bcast::<F>,
            panic: Mutex::new(None),
        };
        // SAFETY argument as in `run`: each first worker dereferences `b` once, before its decrement of
        // `pending`, and we return only after the last decrement.
        sh.done.store(false, Ordering::Relaxed);
        sh.pending.store(sh.processes, Ordering::Relaxed);
        sh.ctl.bcast.store(&b as *const Bcast as *mut Bcast, Ordering::Release);
        sh.ctl.bcast_epoch.fetch_add(1, Ordering::SeqCst);
        for p in 0..sh.processes {
            sh.notify(p * sh.tpp);
        }
        sh.wait_done();
        sh.ctl.bcast.store(std::ptr::null_mut(), Ordering::Relaxed);
        drop(cache);
        if let Some(payload) = b.panic.into_inner().unwrap_or_else(PoisonError::into_inner) {
            panic::resume_unwind(payload);
        }
    }
}

/// What the driver of a run with external dependencies uses to release them
/// ([`Executor::run_with_progress`]).
pub struct Releaser<'a> {
    shared: Option<&'a Shared>,
    graph: Option<&'a TaskGraph>,
    counters: &'a [AtomicU32],
    aborted: Option<&'a AtomicBool>,
    released: u64,
    left: u64,
}

impl Releaser<'_> {
    fn idle() -> Self {
        Releaser {
            shared: None,
            graph: None,
            counters: &[],
            aborted: None,
            released: 0,
            left: 0,
        }
    }

    /// Gives the run up (e.g. another rank failed, so the messages it waits for will never come): the
    /// tasks running now finish, the others never start, and the run returns with
    /// [`RunRecords::cancelled`] set once no task runs any more.
    pub fn cancel(&mut self) {
        if let Some(a) = self.aborted {
            a.store(true, Ordering::Release);
        }
    }

    /// Satisfies one external dependency of task `t`; when it was the last thing `t` waited for, `t`
    /// becomes ready in its owner process.
    ///
    /// # Panics
    ///
    /// If the run has no external dependency left to release.
    pub fn release(&mut self, t: TaskId) {
        assert!(self.left > 0, "task {t} released after every external dependency was");
        if self.aborted.is_some_and(|a| a.load(Ordering::Acquire)) {
            // Nothing starts in a run given up.
            self.left -= 1;
            return;
        }
        let (sh, graph) = (self.shared.expect("a run"), self.graph.expect("a run"));
        self.left -= 1;
        self.released += 1;
        if self.counters[t as usize].fetch_sub(1, Ordering::AcqRel) == 1 {
            // Counted before it is published, as a successor released by a worker.
            sh.pending.fetch_add(1, Ordering::AcqRel);
            let owner = graph.spec(t).owner as usize;
            sh.injectors[owner].push(t);
            sh.wake_for(owner);
        }
    }

    /// External dependencies not yet released in this run.
    pub fn outstanding(&self) -> u64 {
        self.left
    }
}

/// How long an idle driver yields before it parks: on a machine with fewer cores than threads its
/// messages are taken soon after they arrive, without giving the workers' cores over for long (a parked
/// driver takes a wake-up and a time slice to run again). Measured on 2 cores with 2–3 ranks of one
/// thread each: 50–200 µs best, parking at once or never both slower.
const YIELD_FOR: std::time::Duration = std::time::Duration::from_micros(100);

/// The driver's loop of a run with external dependencies (see [`Executor::run_with_progress`]).
fn drive(
    sh: &Shared,
    graph: &TaskGraph,
    counters: &[AtomicU32],
    aborted: &AtomicBool,
    progress: &mut dyn FnMut(&mut Releaser<'_>) -> bool,
) {
    *lock(&sh.driver) = Some(thread::current());
    let mut r = Releaser {
        shared: Some(sh),
        graph: Some(graph),
        counters,
        aborted: Some(aborted),
        released: 0,
        left: graph.external_total(),
    };
    let mut idle = 0u32;
    let mut since = std::time::Instant::now();
    loop {
        let did = progress(&mut r);
        let idle_pool = sh.pending.load(Ordering::Acquire) == 0;
        if idle_pool && (r.left == 0 || aborted.load(Ordering::Acquire)) {
            // Done, or a task panicked or the run was cancelled: the rest of the graph is abandoned (a
            // panic is resumed).
            break;
        }
        if did {
            idle = 0;
            since = std::time::Instant::now();
            continue;
        }
        idle += 1;
        if idle < 8 {
            std::hint::spin_loop();
        } else if since.elapsed() < YIELD_FOR {
            thread::yield_now();
        } else {
            thread::park_timeout(std::time::Duration::from_micros(50));
        }
    }
    *lock(&sh.driver) = None;
    if !aborted.load(Ordering::Acquire) {
        // What the last tasks queued.
        progress(&mut r);
        assert_eq!(r.left, 0);
    }
}

impl Drop for Executor {
    /// Stops and joins the workers.
    fn drop(&mut self) {
        self.shared.ctl.shutdown.store(true, Ordering::SeqCst);
        for w in 0..self.shared.slots.len() {
            self.shared.notify(w);
        }
        for h in self.handles.drain(..) {
            let _ = h.join();
        }
    }
}

/// Mean wall nanoseconds per empty task on an independent-task graph of `tasks` tasks (owners round-robin
/// over the pool's processes): the best of a few runs of wall time / tasks. This is throughput-based: with
/// `k` busy workers the time one worker spends per task is about `k` times this number.
pub fn empty_task_overhead_ns(pool: &Executor, tasks: usize) -> f64 {
    if tasks == 0 {
        return 0.0;
    }
    let graph = independent_graph(tasks, pool.processes());
    let mut best = f64::INFINITY;
    for _ in 0..7 {
        let r = pool.run(&graph, |_, _, _| {});
        best = best.min(r.wall_ns as f64 / tasks as f64);
    }
    best
}

fn independent_graph(tasks: usize, processes: usize) -> TaskGraph {
    let mut g = GraphBuilder::new();
    for i in 0..tasks {
        g.add(TaskSpec {
            owner: (i % processes.max(1)) as u32,
            part: 0,
            block: i as u32,
            payload: 0,
        });
    }
    g.build().expect("a graph without edges is acyclic")
}
