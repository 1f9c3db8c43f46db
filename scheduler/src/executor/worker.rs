//! The worker thread: start-up (pin, create the deque, report to [`Executor::new`](super::Executor::new)),
//! then the loop that finds ready tasks (local deque, own injector, siblings, other processes), runs them
//! and releases their successors, runs broadcasts, and spins, yields and parks when there is nothing to do.

use super::shared::{store_panic, thread_cpu_ns, Shared, AWAKE, SLEEPING, WORKER_OF};
use super::Worker;
use crate::graph::{TaskId, TaskRecord};
use crossbeam::channel;
use crossbeam::deque::{Steal as Grab, Stealer, Worker as Deque};
use std::panic::{self, AssertUnwindSafe};
use std::sync::atomic::{fence, Ordering};
use std::sync::Arc;
use std::thread::{self, Thread};

/// Idle loop: rounds of search + short spin, then rounds of search + `yield_now`, then park.
const SPIN_ROUNDS: u32 = 12;
const YIELD_ROUNDS: u32 = 4;
/// Most finished tasks a worker holds before it writes their records and retires them.
const BATCH: usize = 256;

/// What a starting worker reports: its index and either its stealer and thread handle or why it could not pin.
pub(super) type Hello = (usize, Result<(Stealer<TaskId>, Thread), String>);

/// Body of a worker thread: pin, create the deque, report, wait for the shared state, loop.
pub(super) fn worker_main(
    me: Worker,
    core: Option<usize>,
    hello: channel::Sender<Hello>,
    start: channel::Receiver<Arc<Shared>>,
) {
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
        batch: Vec::with_capacity(BATCH),
        batch_cpu0: 0,
        batch_records: std::ptr::null_mut(),
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
    /// Finished tasks not yet retired, with their wall start and end (see [`WorkerCtx::execute`]).
    batch: Vec<(TaskId, u64, u64)>,
    /// Thread CPU time when the batch began.
    batch_cpu0: u64,
    /// The records of the batch's run.
    batch_records: *mut TaskRecord,
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
                if self.batch.len() >= BATCH {
                    self.close_batch();
                }
                continue;
            }
            self.close_batch();
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
    /// successor. Each finished task joins the worker's *batch*: it stays counted in `pending` (which
    /// keeps the job, its records and its graph alive) until [`WorkerCtx::close_batch`] writes the
    /// batch's records and retires it, when the worker finds no more work or the batch is full.
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
            if self.batch.is_empty() {
                self.batch_cpu0 = thread_cpu_ns();
                self.batch_records = job.records;
            }
            // SAFETY: as above.
            let graph = unsafe { &*job.graph };
            let spec = graph.spec(t);
            let start = job.start.elapsed();
            // SAFETY: `job.ctx` is the `&F` that `job.call` was instantiated for.
            let r = panic::catch_unwind(AssertUnwindSafe(|| unsafe { (job.call)(job.ctx, t, spec, me) }));
            let end = job.start.elapsed();
            if let Err(payload) = r {
                store_panic(&job.panic, payload);
                job.aborted.store(true, Ordering::Release);
                sh.retire();
                return;
            }
            // `t` stays counted until the batch closes.
            self.batch.push((t, start.as_nanos() as u64, end.as_nanos() as u64));
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
                return;
            }
            // Count the new ready tasks before publishing any of them.
            sh.pending.fetch_add(k, Ordering::Release);
            let mut next = None;
            let mut pushed_locally = 0usize;
            for i in 0..k {
                let s = self.ready[i];
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
            // Wake one idle sibling per task left in the deque (stopping at the first that finds nobody
            // to wake).
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

    /// Writes the records of the batch and retires its tasks (after which the job may end).
    fn close_batch(&mut self) {
        if self.batch.is_empty() {
            return;
        }
        // SAFETY: the batch's tasks are still counted in `pending`, so the job and its records are alive;
        // each task runs once, so its slot is written by this worker only.
        unsafe { write_records(&self.batch, self.batch_cpu0, self.batch_records, self.me) };
        let n = self.batch.len();
        self.batch.clear();
        self.shared.retire_many(n);
    }
}

/// Writes the records of a batch of tasks run by worker `me` (task, wall start, wall end in ns since the
/// run began), sharing the thread CPU time since `c0` among them by wall duration: the thread clock is
/// read once per batch, not per task (a read is a system call, ~0.5 µs on a VM, more than a small
/// task). Exact in sum and, for a batch of one task, per task; capped at each task's wall duration.
///
/// # Safety
/// `records` has a slot for every task of the chain, and nobody else writes those slots.
unsafe fn write_records(chain: &[(TaskId, u64, u64)], c0: u64, records: *mut TaskRecord, me: Worker) {
    let cpu = thread_cpu_ns().saturating_sub(c0);
    let wall: u64 = chain.iter().map(|&(_, a, e)| e - a).sum();
    // CPU time per wall nanosecond over the chain (at most 1: one thread cannot run faster than the clock).
    let rate = if wall == 0 {
        1.0
    } else {
        (cpu as f64 / wall as f64).min(1.0)
    };
    for &(t, start_ns, end_ns) in chain {
        // SAFETY: see the function's contract.
        unsafe {
            records.add(t as usize).write(TaskRecord {
                worker: me.index,
                process: me.process,
                start_ns,
                end_ns,
                cpu_ns: ((end_ns - start_ns) as f64 * rate) as u64,
            });
        }
    }
}
