//! State shared by the driver and the workers of one executor: the queues and per-worker slots, the
//! `pending` counter and done signal, the type-erased descriptions of the current run and broadcast, the
//! parking states and the wake-up side of parking, plus small helpers (poison-tolerant locking, panic
//! capture, thread CPU time).

use super::Worker;
use crate::graph::{TaskGraph, TaskId, TaskRecord, TaskSpec};
use crossbeam::deque::{Injector, Stealer};
use crossbeam::utils::CachePadded;
use std::any::Any;
use std::cell::Cell;
use std::sync::atomic::{fence, AtomicBool, AtomicPtr, AtomicU32, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Condvar, Mutex, MutexGuard, PoisonError};
use std::thread::Thread;
use std::time::Instant;

/// Worker states for parking.
pub(super) const AWAKE: u32 = 0;
pub(super) const SLEEPING: u32 = 1;
const NOTIFIED: u32 = 2;

/// State shared by the driver and all workers; lives as long as the longest of them.
pub(super) struct Shared {
    pub(super) processes: usize,
    pub(super) tpp: usize,
    pub(super) global: bool,
    /// Ready queue of each process.
    pub(super) injectors: Box<[CachePadded<Injector<TaskId>>]>,
    /// Per worker: stealer of its deque, its thread handle and its parking state.
    pub(super) slots: Box<[CachePadded<Slot>]>,
    /// Number of parked (or about to park) workers per process.
    pub(super) sleeping: Box<[CachePadded<AtomicUsize>]>,
    /// Tasks ready or running in the current run (see the module docs), or first workers still to run the
    /// current broadcast.
    pub(super) pending: CachePadded<AtomicUsize>,
    /// Read-mostly control words.
    pub(super) ctl: CachePadded<Control>,
    /// Set by the worker that brings `pending` to zero; the driver waits for it.
    pub(super) done: AtomicBool,
    pub(super) done_lock: Mutex<()>,
    pub(super) done_cv: Condvar,
    /// The driver of a run with external dependencies, unparked whenever `pending` reaches zero (it
    /// may have releases to make or be waiting for the end).
    pub(super) driver: Mutex<Option<Thread>>,
}

pub(super) struct Control {
    /// The current run (points into the driver's stack frame; valid while `pending > 0`).
    pub(super) job: AtomicPtr<Job>,
    /// The current broadcast (points into the driver's stack frame; valid while `pending > 0`).
    pub(super) bcast: AtomicPtr<Bcast>,
    /// Incremented once per broadcast; first workers compare it with the last one they ran.
    pub(super) bcast_epoch: AtomicU64,
    pub(super) shutdown: AtomicBool,
}

pub(super) struct Slot {
    pub(super) stealer: Stealer<TaskId>,
    pub(super) thread: Thread,
    pub(super) state: AtomicU32,
}

/// Type-erased description of one run. Lives in `Executor::run`'s frame.
pub(super) struct Job {
    pub(super) graph: *const TaskGraph,
    pub(super) counters: *const AtomicU32,
    pub(super) records: *mut TaskRecord,
    pub(super) ctx: *const (),
    pub(super) call: unsafe fn(*const (), TaskId, &TaskSpec, Worker),
    pub(super) start: Instant,
    pub(super) aborted: AtomicBool,
    pub(super) panic: Mutex<Option<Box<dyn Any + Send>>>,
}

/// Type-erased description of one broadcast. Lives in `Executor::on_each_process`'s frame.
pub(super) struct Bcast {
    pub(super) ctx: *const (),
    pub(super) call: unsafe fn(*const (), u32),
    pub(super) panic: Mutex<Option<Box<dyn Any + Send>>>,
}

/// # Safety
/// `ctx` must point to a live `F`.
pub(super) unsafe fn call_task<F: Fn(TaskId, &TaskSpec, Worker) + Sync>(
    ctx: *const (),
    t: TaskId,
    spec: &TaskSpec,
    w: Worker,
) {
    // SAFETY: the caller guarantees `ctx` is the `&F` that `run` erased, and `run` is still waiting.
    let f = unsafe { &*(ctx as *const F) };
    f(t, spec, w)
}

/// # Safety
/// `ctx` must point to a live `F`.
pub(super) unsafe fn call_bcast<F: Fn(u32) + Sync>(ctx: *const (), process: u32) {
    // SAFETY: as in `call_task`.
    let f = unsafe { &*(ctx as *const F) };
    f(process)
}

thread_local! {
    /// Address of the `Shared` of the executor this thread works for (0 on non-worker threads).
    pub(super) static WORKER_OF: Cell<usize> = const { Cell::new(0) };
}

pub(super) fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

pub(super) fn store_panic(slot: &Mutex<Option<Box<dyn Any + Send>>>, payload: Box<dyn Any + Send>) {
    let mut g = lock(slot);
    if g.is_none() {
        *g = Some(payload);
    }
}

/// Thread CPU time of the calling thread, nanoseconds.
#[inline]
pub fn thread_cpu_ns() -> u64 {
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
    pub(super) fn retire(&self) {
        self.retire_many(1);
    }

    /// Marks `n ≥ 1` items as finished (see [`Shared::retire`]).
    #[inline]
    pub(super) fn retire_many(&self, n: usize) {
        if self.pending.fetch_sub(n, Ordering::AcqRel) == n {
            self.done.store(true, Ordering::SeqCst);
            {
                let _g = lock(&self.done_lock);
                self.done_cv.notify_all();
            }
            if let Some(t) = lock(&self.driver).as_ref() {
                t.unpark();
            }
        }
    }

    /// Wakes worker `w` if it is parked. Returns whether it was.
    pub(super) fn notify(&self, w: usize) -> bool {
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
    pub(super) fn wake_one_in(&self, p: usize) -> bool {
        if self.sleeping[p].load(Ordering::SeqCst) == 0 {
            return false;
        }
        (p * self.tpp..(p + 1) * self.tpp).any(|w| self.notify(w))
    }

    /// Wakes one parked worker that may take work just published for process `p`: one of `p`, or with global
    /// stealing any one.
    pub(super) fn wake_for(&self, p: usize) -> bool {
        // Pairs with the fence in `WorkerCtx::sleep`: either we see the sleeper or it sees our push.
        fence(Ordering::SeqCst);
        if self.wake_one_in(p) {
            return true;
        }
        self.global && (0..self.processes).any(|q| q != p && self.wake_one_in(q))
    }

    /// Waits (on the driver) until the worker that retires the last pending item has set `done`.
    pub(super) fn wait_done(&self) {
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
