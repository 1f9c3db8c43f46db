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
//! A single counter, `pending`, counts tasks that are ready (in some queue or held as "next") or running. The
//! driver sets it to the number of roots; a finishing task with `k` newly ready successors adds `k - 1`
//! (nothing at all on a chain) *before* it publishes any of them; a task without newly ready successors
//! subtracts one. `pending` reaches zero exactly when every task has finished (in an acyclic graph the
//! earliest unfinished task would otherwise be ready). If a task panics, the run is *aborted*: tasks popped
//! afterwards are retired without running and without releasing their successors, so `pending` still drains
//! to zero, all queues are empty again, and the panic is resumed on the driver.
//!
//! # Timing
//!
//! Every task execution records its wall interval (ns since the run started, from one [`Instant`]) and its
//! thread CPU time (`CLOCK_THREAD_CPUTIME_ID`, read before and after the task), plus the worker and its
//! process, into the task's own slot of [`RunRecords::records`].

use crate::graph::{GraphBuilder, TaskGraph, TaskId, TaskRecord, TaskSpec};
use crossbeam::channel;
use crossbeam::deque::{Injector, Steal as Grab, Stealer, Worker as Deque};
use crossbeam::utils::CachePadded;
use std::any::Any;
use std::cell::Cell;
use std::fmt;
use std::panic::{self, AssertUnwindSafe};
use std::sync::atomic::{fence, AtomicBool, AtomicPtr, AtomicU32, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError};
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

/// Worker states for parking.
const AWAKE: u32 = 0;
const SLEEPING: u32 = 1;
const NOTIFIED: u32 = 2;

/// Idle loop: rounds of search + short spin, then rounds of search + `yield_now`, then park.
const SPIN_ROUNDS: u32 = 12;
const YIELD_ROUNDS: u32 = 4;

/// State shared by the driver and all workers; lives as long as the longest of them.
struct Shared {
    processes: usize,
    tpp: usize,
    global: bool,
    /// Ready queue of each process.
    injectors: Box<[CachePadded<Injector<TaskId>>]>,
    /// Per worker: stealer of its deque, its thread handle and its parking state.
    slots: Box<[CachePadded<Slot>]>,
    /// Number of parked (or about to park) workers per process.
    sleeping: Box<[CachePadded<AtomicUsize>]>,
    /// Tasks ready or running in the current run (see the module docs), or first workers still to run the
    /// current broadcast.
    pending: CachePadded<AtomicUsize>,
    /// Read-mostly control words.
    ctl: CachePadded<Control>,
    /// Set by the worker that brings `pending` to zero; the driver waits for it.
    done: AtomicBool,
    done_lock: Mutex<()>,
    done_cv: Condvar,
}

struct Control {
    /// The current run (points into the driver's stack frame; valid while `pending > 0`).
    job: AtomicPtr<Job>,
    /// The current broadcast (points into the driver's stack frame; valid while `pending > 0`).
    bcast: AtomicPtr<Bcast>,
    /// Incremented once per broadcast; first workers compare it with the last one they ran.
    bcast_epoch: AtomicU64,
    shutdown: AtomicBool,
}

struct Slot {
    stealer: Stealer<TaskId>,
    thread: Thread,
    state: AtomicU32,
}

/// Type-erased description of one run. Lives in `Executor::run`'s frame.
struct Job {
    graph: *const TaskGraph,
    counters: *const AtomicU32,
    records: *mut TaskRecord,
    ctx: *const (),
    call: unsafe fn(*const (), TaskId, &TaskSpec, Worker),
    start: Instant,
    aborted: AtomicBool,
    panic: Mutex<Option<Box<dyn Any + Send>>>,
}

/// Type-erased description of one broadcast. Lives in `Executor::on_each_process`'s frame.
struct Bcast {
    ctx: *const (),
    call: unsafe fn(*const (), u32),
    panic: Mutex<Option<Box<dyn Any + Send>>>,
}

/// # Safety
/// `ctx` must point to a live `F`.
unsafe fn call_task<F: Fn(TaskId, &TaskSpec, Worker) + Sync>(ctx: *const (), t: TaskId, spec: &TaskSpec, w: Worker) {
    // SAFETY: the caller guarantees `ctx` is the `&F` that `run` erased, and `run` is still waiting.
    let f = unsafe { &*(ctx as *const F) };
    f(t, spec, w)
}

/// # Safety
/// `ctx` must point to a live `F`.
unsafe fn call_bcast<F: Fn(u32) + Sync>(ctx: *const (), process: u32) {
    // SAFETY: as in `call_task`.
    let f = unsafe { &*(ctx as *const F) };
    f(process)
}

thread_local! {
    /// Address of the `Shared` of the executor this thread works for (0 on non-worker threads).
    static WORKER_OF: Cell<usize> = const { Cell::new(0) };
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

fn store_panic(slot: &Mutex<Option<Box<dyn Any + Send>>>, payload: Box<dyn Any + Send>) {
    let mut g = lock(slot);
    if g.is_none() {
        *g = Some(payload);
    }
}

/// Thread CPU time of the calling thread, nanoseconds.
#[inline]
fn thread_cpu_ns() -> u64 {
    // SAFETY: an all-zero timespec is valid; clock_gettime only writes into it.
    let mut ts: libc::timespec = unsafe { std::mem::zeroed() };
    // SAFETY: valid clock id and a valid out pointer.
    unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

impl Shared {
    /// Marks one task (or one process's part of a broadcast) as finished; the last one wakes the driver.
    /// After this call the caller must not touch the job any more.
    #[inline]
    fn retire(&self) {
        if self.pending.fetch_sub(1, Ordering::AcqRel) == 1 {
            self.done.store(true, Ordering::SeqCst);
            let _g = lock(&self.done_lock);
            self.done_cv.notify_all();
        }
    }

    /// Wakes worker `w` if it is parked. Returns whether it was.
    fn notify(&self, w: usize) -> bool {
        let slot = &self.slots[w];
        if slot
            .state
            .compare_exchange(SLEEPING, NOTIFIED, Ordering::SeqCst, Ordering::Relaxed)
            .is_ok()
        {
            slot.thread.unpark();
            true
        } else {
            false
        }
    }

    /// Wakes one parked worker of process `p`. Call after publishing work that process may take.
    fn wake_one_in(&self, p: usize) -> bool {
        if self.sleeping[p].load(Ordering::SeqCst) == 0 {
            return false;
        }
        (p * self.tpp..(p + 1) * self.tpp).any(|w| self.notify(w))
    }

    /// Wakes one parked worker that may take work just published for process `p`: one of `p`, or with global
    /// stealing any one.
    fn wake_for(&self, p: usize) -> bool {
        // Pairs with the fence in `WorkerCtx::sleep`: either we see the sleeper or it sees our push.
        fence(Ordering::SeqCst);
        if self.wake_one_in(p) {
            return true;
        }
        self.global && (0..self.processes).any(|q| q != p && self.wake_one_in(q))
    }

    /// Waits (on the driver) until the worker that retires the last pending item has set `done`.
    fn wait_done(&self) {
        for _ in 0..256 {
            if self.done.load(Ordering::Acquire) {
                return;
            }
            std::hint::spin_loop();
        }
        let mut g = lock(&self.done_lock);
        while !self.done.load(Ordering::SeqCst) {
            g = self.done_cv.wait(g).unwrap_or_else(PoisonError::into_inner);
        }
    }
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
        assert!(
            graph.processes() <= self.shared.processes,
            "the task graph has tasks owned by process {} but the pool has only {} processes",
            graph.processes().saturating_sub(1),
            self.shared.processes
        );
        self.assert_not_worker("run");
        let n = graph.len();
        if n == 0 {
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
        // (the successor release adds to `pending` before publishing any successor; the finishing task's
        // own decrement comes after its last use of the job). `wait_done` returns only after `pending`
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

        sh.wait_done();
        let wall_ns = start.elapsed().as_nanos() as u64;
        sh.ctl.job.store(std::ptr::null_mut(), Ordering::Relaxed);
        drop(cache);
        let panic = job.panic.into_inner().unwrap_or_else(PoisonError::into_inner);
        if let Some(payload) = panic {
            panic::resume_unwind(payload);
        }
        RunRecords { records, wall_ns }
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

/// What a starting worker reports: its index and either its stealer and thread handle or why it could not pin.
type Hello = (usize, Result<(Stealer<TaskId>, Thread), String>);

/// Body of a worker thread: pin, create the deque, report, wait for the shared state, loop.
fn worker_main(me: Worker, core: Option<usize>, hello: channel::Sender<Hello>, start: channel::Receiver<Arc<Shared>>) {
    let w = me.index as usize;
    if let Some(id) = core {
        if !core_affinity::set_for_current(core_affinity::CoreId { id }) {
            let _ = hello.send((
                w,
                Err(format!(
                    "worker {w} (process {}) could not be pinned to core {id}",
                    me.process
                )),
            ));
            return;
        }
    }
    let deque = Deque::new_lifo();
    if hello.send((w, Ok((deque.stealer(), thread::current())))).is_err() {
        return;
    }
    drop(hello);
    let Ok(shared) = start.recv() else {
        return;
    };
    drop(start);
    WORKER_OF.with(|c| c.set(Arc::as_ptr(&shared) as usize));
    let tpp = shared.tpp;
    let mut ctx = WorkerCtx {
        me,
        first_of_process: w.is_multiple_of(tpp),
        bcast_seen: 0,
        deque,
        ready: Vec::with_capacity(64),
        rng: 0x9E37_79B9_7F4A_7C15 ^ (w as u64 + 1).wrapping_mul(0xBF58_476D_1CE4_E5B9),
        shares_locally: tpp > 1 || shared.global,
        shared,
    };
    ctx.main_loop();
}

struct WorkerCtx {
    shared: Arc<Shared>,
    me: Worker,
    first_of_process: bool,
    bcast_seen: u64,
    deque: Deque<TaskId>,
    /// Successors made ready by the task just finished (reused buffer).
    ready: Vec<TaskId>,
    rng: u64,
    /// Whether anyone else can take tasks from this worker's deque.
    shares_locally: bool,
}

impl WorkerCtx {
    fn main_loop(&mut self) {
        let mut idle = 0u32;
        loop {
            if let Some(t) = self.find_task() {
                idle = 0;
                self.execute(t);
                continue;
            }
            if self.try_bcast() {
                idle = 0;
                continue;
            }
            if self.shared.ctl.shutdown.load(Ordering::Acquire) {
                return;
            }
            if idle < SPIN_ROUNDS {
                for _ in 0..(4u32 << idle.min(5)) {
                    std::hint::spin_loop();
                }
            } else if idle < SPIN_ROUNDS + YIELD_ROUNDS {
                thread::yield_now();
            } else {
                self.sleep();
                idle = 0;
                continue;
            }
            idle += 1;
        }
    }

    fn next_rand(&mut self) -> usize {
        let mut x = self.rng;
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        self.rng = x;
        x as usize
    }

    /// Local deque, own injector, siblings, then (global stealing) other processes.
    fn find_task(&mut self) -> Option<TaskId> {
        if let Some(t) = self.deque.pop() {
            return Some(t);
        }
        let r = if self.shares_locally { self.next_rand() } else { 0 };
        let sh = &*self.shared;
        let p = self.me.process as usize;
        let tpp = sh.tpp;
        let me = self.me.index as usize;
        loop {
            let mut retry = false;
            match sh.injectors[p].steal_batch_and_pop(&self.deque) {
                Grab::Success(t) => return Some(t),
                Grab::Retry => retry = true,
                Grab::Empty => {}
            }
            for i in 0..tpp {
                let w = p * tpp + (r + i) % tpp;
                if w == me {
                    continue;
                }
                match sh.slots[w].stealer.steal_batch_and_pop(&self.deque) {
                    Grab::Success(t) => return Some(t),
                    Grab::Retry => retry = true,
                    Grab::Empty => {}
                }
            }
            if sh.global {
                let np = sh.processes;
                for i in 1..np {
                    let q = (p + i) % np;
                    match sh.injectors[q].steal_batch_and_pop(&self.deque) {
                        Grab::Success(t) => return Some(t),
                        Grab::Retry => retry = true,
                        Grab::Empty => {}
                    }
                }
                let nw = sh.slots.len();
                for i in 0..nw {
                    let w = (r + i) % nw;
                    if w / tpp == p {
                        continue;
                    }
                    match sh.slots[w].stealer.steal_batch_and_pop(&self.deque) {
                        Grab::Success(t) => return Some(t),
                        Grab::Retry => retry = true,
                        Grab::Empty => {}
                    }
                }
            }
            if !retry {
                return None;
            }
            std::hint::spin_loop();
        }
    }

    /// Whether any queue this worker may take from is non-empty (its own deque is empty when it asks).
    fn has_work(&self) -> bool {
        let sh = &*self.shared;
        let p = self.me.process as usize;
        if sh.global {
            sh.injectors.iter().any(|q| !q.is_empty()) || sh.slots.iter().any(|s| !s.stealer.is_empty())
        } else {
            !sh.injectors[p].is_empty()
                || sh.slots[p * sh.tpp..(p + 1) * sh.tpp]
                    .iter()
                    .any(|s| !s.stealer.is_empty())
        }
    }

    fn bcast_due(&self) -> bool {
        self.first_of_process && self.shared.ctl.bcast_epoch.load(Ordering::SeqCst) != self.bcast_seen
    }

    /// Parks until notified. Never loses a wake-up: the state and the sleeper count are published before
    /// the final look at the queues, and wakers publish work before they look at the state.
    fn sleep(&mut self) {
        let sh = &*self.shared;
        let p = self.me.process as usize;
        let slot = &sh.slots[self.me.index as usize];
        slot.state.store(SLEEPING, Ordering::SeqCst);
        sh.sleeping[p].fetch_add(1, Ordering::SeqCst);
        fence(Ordering::SeqCst);
        if self.has_work() || self.bcast_due() || sh.ctl.shutdown.load(Ordering::SeqCst) {
            slot.state.store(AWAKE, Ordering::SeqCst);
            sh.sleeping[p].fetch_sub(1, Ordering::SeqCst);
            return;
        }
        while slot.state.load(Ordering::Acquire) == SLEEPING {
            thread::park();
        }
        slot.state.store(AWAKE, Ordering::Relaxed);
        sh.sleeping[p].fetch_sub(1, Ordering::SeqCst);
    }

    /// Runs the current broadcast if this is a first worker and it has not run it yet.
    fn try_bcast(&mut self) -> bool {
        if !self.first_of_process {
            return false;
        }
        let sh = &*self.shared;
        let epoch = sh.ctl.bcast_epoch.load(Ordering::Acquire);
        if epoch == self.bcast_seen {
            return false;
        }
        self.bcast_seen = epoch;
        let bp = sh.ctl.bcast.load(Ordering::Acquire);
        // SAFETY: the broadcast is counted in `pending` until our `retire`, so it is alive.
        let b = unsafe { &*bp };
        let process = self.me.process;
        // SAFETY: `b.ctx` is the driver's `&F`, alive until `pending` reaches zero.
        let r = panic::catch_unwind(AssertUnwindSafe(|| unsafe { (b.call)(b.ctx, process) }));
        if let Err(payload) = r {
            store_panic(&b.panic, payload);
        }
        sh.retire();
        true
    }

    /// Runs `first` and then, as long as a finishing task leaves a ready successor for this worker, that
    /// successor.
    fn execute(&mut self, first: TaskId) {
        let sh = &*self.shared;
        let jp = sh.ctl.job.load(Ordering::Acquire);
        let me = self.me;
        let mut t = first;
        loop {
            // SAFETY: `t` is counted in `pending`, so the driver is still inside `run` and the job, the graph,
            // the counters, the records and the closure are alive (see the argument in `Executor::run`).
            let job = unsafe { &*jp };
            if job.aborted.load(Ordering::Relaxed) {
                sh.retire();
                return;
            }
            // SAFETY: as above.
            let graph = unsafe { &*job.graph };
            let spec = graph.spec(t);
            let start = job.start.elapsed();
            let c0 = thread_cpu_ns();
            // SAFETY: `job.ctx` is the `&F` that `job.call` was instantiated for.
            let r = panic::catch_unwind(AssertUnwindSafe(|| unsafe { (job.call)(job.ctx, t, spec, me) }));
            let c1 = thread_cpu_ns();
            let end = job.start.elapsed();
            if let Err(payload) = r {
                store_panic(&job.panic, payload);
                job.aborted.store(true, Ordering::Release);
                sh.retire();
                return;
            }
            // SAFETY: `t < n` and each task runs once, so this slot is written by this worker only.
            unsafe {
                job.records.add(t as usize).write(TaskRecord {
                    worker: me.index,
                    process: me.process,
                    start_ns: start.as_nanos() as u64,
                    end_ns: end.as_nanos() as u64,
                    cpu_ns: c1.saturating_sub(c0),
                });
            }
            self.ready.clear();
            for &s in graph.successors(t) {
                // SAFETY: successor ids are < n, the counters slice has at least n entries.
                let c = unsafe { &*job.counters.add(s as usize) };
                if c.fetch_sub(1, Ordering::AcqRel) == 1 {
                    self.ready.push(s);
                }
            }
            let k = self.ready.len();
            if k == 0 {
                sh.retire();
                return;
            }
            if k > 1 {
                // Count the new ready tasks before publishing any of them.
                sh.pending.fetch_add(k - 1, Ordering::Release);
            }
            let mut next = None;
            let mut pushed_locally = 0usize;
            for i in 0..k {
                let s = self.ready[i];
                // Unpublished successors are still counted, so the graph is alive here.
                let owner = graph.spec(s).owner;
                if owner == me.process {
                    if next.is_none() {
                        next = Some(s);
                    } else {
                        self.deque.push(s);
                        pushed_locally += 1;
                    }
                } else {
                    sh.injectors[owner as usize].push(s);
                    sh.wake_for(owner as usize);
                }
            }
            // From here on the job may be gone unless `next` is Some. Wake one idle sibling per task left in
            // the deque (stopping at the first that finds nobody to wake).
            if self.shares_locally {
                for _ in 0..pushed_locally {
                    if !sh.wake_for(me.process as usize) {
                        break;
                    }
                }
            }
            match next {
                Some(s) => t = s,
                None => return,
            }
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

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::AtomicU64;

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
}
