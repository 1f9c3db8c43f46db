//! Ranks in separate OS processes, on MPI (`--features mpi`): the transport over a small C shim
//! (`mpi_shim.c`, compiled with `mpicc` by `build.rs`), so that no MPI type or ABI reaches Rust.
//!
//! - MPI is initialised for funnelled threads: only the thread that called [`Mpi::init`] (the rank's
//!   driver) calls MPI; [`Transport::sends_from_any_thread`] is false, so workers queue their messages.
//! - Every message class has its own duplicated communicator; a tag is the [`Tag`]'s value, checked
//!   against `MPI_TAG_UB`.
//! - Sends are `MPI_Isend`s of owned buffers, kept until a [`Transport::poll`] finds them complete;
//!   receives are probed (`MPI_Iprobe`, then `MPI_Recv` of the exact source, tag and size).
//! - Collectives are non-blocking (`MPI_Iallgather(v)`), waited for while watching an abort channel, and
//!   combine the ranks' values in rank order as the other transports do (so a float extreme propagates
//!   NaN and every rank gets the same bits).
//! - [`Transport::abort`] sends a notice (exit code, message) to every other rank on the abort channel;
//!   every call on every rank checks that channel first and fails with [`TransportError::Aborted`], so a
//!   rank that fails never leaves the others waiting in a collective.

use super::{combine_float, combine_int, FloatOp, IntOp, Rank, Tag, Transport, TransportError};
use std::ffi::c_void;
use std::sync::Mutex;
use std::time::{Duration, Instant};

extern "C" {
    fn bf_mpi_init(
        rank: *mut i32,
        size: *mut i32,
        local_rank: *mut i32,
        local_size: *mut i32,
        tag_ub: *mut i32,
        provided: *mut i32,
    ) -> i32;
    fn bf_mpi_finalize() -> i32;
    fn bf_mpi_isend(cls: i32, to: i32, tag: i32, buf: *const c_void, len: i64, req: *mut *mut c_void) -> i32;
    fn bf_mpi_test(req: *mut c_void, done: *mut i32) -> i32;
    fn bf_mpi_iprobe(
        cls: i32,
        from: i32,
        tag: i32,
        flag: *mut i32,
        source: *mut i32,
        tag_out: *mut i32,
        len: *mut i64,
    ) -> i32;
    fn bf_mpi_recv(cls: i32, from: i32, tag: i32, buf: *mut c_void, len: i64) -> i32;
    fn bf_mpi_iallgather_len(len: *const i64, all: *mut i64, req: *mut *mut c_void) -> i32;
    fn bf_mpi_iallgatherv(
        mine: *const c_void,
        len: i64,
        all: *mut c_void,
        counts: *const i32,
        displs: *const i32,
        req: *mut *mut c_void,
    ) -> i32;
    fn bf_mpi_abort(code: i32) -> i32;
}

/// Message classes the shim has communicators for.
const CLASSES: u8 = 8;
/// The abort channel's class in the shim.
const ABORT: i32 = -1;
/// `MPI_THREAD_FUNNELED`'s rank among the thread levels (single, funneled, serialized, multiple).
const FUNNELED: i32 = 1;

/// An MPI request the shim allocated.
struct Request(*mut c_void);

// SAFETY: a request is only ever touched by the thread that may call MPI (checked on every call).
unsafe impl Send for Request {}

/// This process's rank of the MPI job (see the module docs).
pub struct Mpi {
    rank: Rank,
    ranks: usize,
    node: (usize, usize),
    tag_ub: u32,
    thread: std::thread::ThreadId,
    sends: Mutex<Vec<(Request, Vec<u8>)>>,
    aborted: Mutex<Option<TransportError>>,
}

impl std::fmt::Debug for Mpi {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Mpi(rank {} of {})", self.rank, self.ranks)
    }
}

impl Mpi {
    /// Initialises MPI (once per process, from the thread that will drive the rank) and returns this
    /// rank; fails when MPI cannot give funnelled threads.
    pub fn init() -> Result<Mpi, String> {
        let (mut rank, mut size, mut lr, mut ls, mut ub, mut provided) = (0, 0, 0, 0, 0, 0);
        // SAFETY: out pointers to locals; called once.
        let err = unsafe { bf_mpi_init(&mut rank, &mut size, &mut lr, &mut ls, &mut ub, &mut provided) };
        if err != 0 {
            return Err(format!("MPI_Init_thread failed with MPI error {err}"));
        }
        if provided < FUNNELED {
            return Err(format!(
                "the MPI library gives thread level {provided}; blockflow needs MPI_THREAD_FUNNELED (1)"
            ));
        }
        Ok(Mpi {
            rank: rank as Rank,
            ranks: size as usize,
            node: (lr as usize, ls as usize),
            tag_ub: ub.max(32767) as u32,
            thread: std::thread::current().id(),
            sends: Mutex::new(Vec::new()),
            aborted: Mutex::new(None),
        })
    }

    /// The largest tag value MPI accepts here (`MPI_TAG_UB`).
    pub fn tag_ub(&self) -> u32 {
        self.tag_ub
    }

    /// Completes the sends under way (waiting at most `timeout`) and finalises MPI. Call once, at the
    /// end of a successful run, on every rank.
    pub fn finish(&self, timeout: Duration) {
        let start = Instant::now();
        while !self.sends.lock().expect("sends").is_empty() && start.elapsed() < timeout {
            let _ = self.complete_sends();
            std::thread::yield_now();
        }
        // SAFETY: called once, from the MPI thread.
        unsafe { bf_mpi_finalize() };
    }

    /// Ends the whole job at once (`MPI_Abort`), for failures that cannot be reported otherwise.
    pub fn kill(&self, code: i32) -> ! {
        // SAFETY: MPI_Abort does not return.
        unsafe { bf_mpi_abort(code) };
        std::process::exit(code)
    }

    fn mpi_error(&self, what: &str, err: i32) -> TransportError {
        TransportError::Mismatch(format!("{what} failed on rank {} with MPI error {err}", self.rank))
    }

    /// Fails when another rank ended the group (or this one did), or when called from a thread other
    /// than the one that initialised MPI.
    fn check(&self) -> Result<(), TransportError> {
        if std::thread::current().id() != self.thread {
            return Err(TransportError::Mismatch(
                "MPI was called from a thread other than the rank's driver".into(),
            ));
        }
        if let Some(e) = self.aborted.lock().expect("abort state").clone() {
            return Err(e);
        }
        let (mut flag, mut src, mut tag, mut len) = (0, 0, 0, 0i64);
        // SAFETY: out pointers to locals.
        let err = unsafe { bf_mpi_iprobe(ABORT, -1, -1, &mut flag, &mut src, &mut tag, &mut len) };
        if err != 0 || flag == 0 {
            return Ok(());
        }
        let mut buf = vec![0u8; len as usize];
        // SAFETY: a buffer of the probed size for the probed message.
        unsafe { bf_mpi_recv(ABORT, src, tag, buf.as_mut_ptr() as *mut c_void, len) };
        let code = i32::from_le_bytes(buf.get(..4).and_then(|b| b.try_into().ok()).unwrap_or([1, 0, 0, 0]));
        let e = TransportError::Aborted {
            rank: src as Rank,
            code,
            message: String::from_utf8_lossy(buf.get(4..).unwrap_or(&[])).into_owned(),
        };
        *self.aborted.lock().expect("abort state") = Some(e.clone());
        Err(e)
    }

    fn class(&self, c: u8) -> Result<i32, TransportError> {
        if c < CLASSES {
            Ok(c as i32)
        } else {
            Err(TransportError::Mismatch(format!(
                "message class {c}: the MPI transport has {CLASSES}"
            )))
        }
    }

    /// Tests the sends under way and drops the completed ones.
    fn complete_sends(&self) -> Result<(), TransportError> {
        let mut sends = self.sends.lock().expect("sends");
        let mut i = 0;
        while i < sends.len() {
            let mut done = 0;
            // SAFETY: a live request of this process.
            let err = unsafe { bf_mpi_test(sends[i].0 .0, &mut done) };
            if err != 0 {
                return Err(self.mpi_error("MPI_Test", err));
            }
            if done != 0 {
                sends.swap_remove(i);
            } else {
                i += 1;
            }
        }
        Ok(())
    }

    /// Waits for a collective's request, watching the abort channel.
    fn wait(&self, req: *mut c_void) -> Result<(), TransportError> {
        loop {
            let mut done = 0;
            // SAFETY: a live request of this process.
            let err = unsafe { bf_mpi_test(req, &mut done) };
            if err != 0 {
                return Err(self.mpi_error("MPI_Test", err));
            }
            if done != 0 {
                return Ok(());
            }
            self.check()?;
            let _ = self.complete_sends();
            std::thread::yield_now();
        }
    }

    fn receive(&self, cls: i32, src: i32, tag: i32, len: i64) -> Result<Vec<u8>, TransportError> {
        let mut buf = vec![0u8; len as usize];
        // SAFETY: a buffer of the probed size for the probed message.
        let err = unsafe { bf_mpi_recv(cls, src, tag, buf.as_mut_ptr() as *mut c_void, len) };
        if err != 0 {
            return Err(self.mpi_error("MPI_Recv", err));
        }
        Ok(buf)
    }
}

impl Transport for Mpi {
    fn rank(&self) -> Rank {
        self.rank
    }

    fn ranks(&self) -> usize {
        self.ranks
    }

    fn node_rank(&self) -> (usize, usize) {
        self.node
    }

    fn send(&self, to: Rank, tag: Tag, bytes: Vec<u8>) -> Result<(), TransportError> {
        self.check()?;
        if to >= self.ranks {
            return Err(TransportError::NoSuchRank {
                rank: to,
                ranks: self.ranks,
            });
        }
        if tag.value > self.tag_ub {
            return Err(TransportError::Mismatch(format!(
                "tag {} above this MPI's MPI_TAG_UB {}",
                tag.value, self.tag_ub
            )));
        }
        let cls = self.class(tag.class)?;
        if bytes.len() > i32::MAX as usize {
            return Err(TransportError::Mismatch(format!(
                "a message of {} bytes (MPI counts are 31-bit)",
                bytes.len()
            )));
        }
        let mut req = std::ptr::null_mut();
        // SAFETY: the buffer lives in `sends` until the request completes (a Vec's heap buffer does not
        // move when the Vec does).
        let err = unsafe {
            bf_mpi_isend(
                cls,
                to as i32,
                tag.value as i32,
                bytes.as_ptr() as *const c_void,
                bytes.len() as i64,
                &mut req,
            )
        };
        if err != 0 {
            return Err(self.mpi_error("MPI_Isend", err));
        }
        self.sends.lock().expect("sends").push((Request(req), bytes));
        Ok(())
    }

    fn try_recv(&self, from: Rank, tag: Tag) -> Result<Option<Vec<u8>>, TransportError> {
        self.check()?;
        let cls = self.class(tag.class)?;
        let (mut flag, mut src, mut t, mut len) = (0, 0, 0, 0i64);
        // SAFETY: out pointers to locals.
        let err = unsafe {
            bf_mpi_iprobe(
                cls,
                from as i32,
                tag.value as i32,
                &mut flag,
                &mut src,
                &mut t,
                &mut len,
            )
        };
        if err != 0 {
            return Err(self.mpi_error("MPI_Iprobe", err));
        }
        if flag == 0 {
            return Ok(None);
        }
        self.receive(cls, src, t, len).map(Some)
    }

    fn try_recv_any(&self, class: u8) -> Result<Option<(Rank, Tag, Vec<u8>)>, TransportError> {
        self.check()?;
        let cls = self.class(class)?;
        let (mut flag, mut src, mut t, mut len) = (0, 0, 0, 0i64);
        // SAFETY: out pointers to locals.
        let err = unsafe { bf_mpi_iprobe(cls, -1, -1, &mut flag, &mut src, &mut t, &mut len) };
        if err != 0 {
            return Err(self.mpi_error("MPI_Iprobe", err));
        }
        if flag == 0 {
            return Ok(None);
        }
        let bytes = self.receive(cls, src, t, len)?;
        Ok(Some((src as Rank, Tag::new(class, t as u32), bytes)))
    }

    fn poll(&self) -> Result<usize, TransportError> {
        self.check()?;
        self.complete_sends()?;
        Ok(0)
    }

    fn allreduce_u64(&self, values: &mut [u64], op: IntOp) -> Result<(), TransportError> {
        let mine: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        let all = self.allgather(&mine)?;
        if all.iter().any(|r| r.len() != mine.len()) {
            return Err(TransportError::Mismatch("allreduce_u64 lengths differ".into()));
        }
        let at = |r: &Vec<u8>, k: usize| u64::from_le_bytes(r[8 * k..8 * k + 8].try_into().expect("8 bytes"));
        for (k, v) in values.iter_mut().enumerate() {
            *v = all[1..]
                .iter()
                .fold(at(&all[0], k), |acc, r| combine_int(acc, at(r, k), op));
        }
        Ok(())
    }

    fn allreduce_f64(&self, values: &mut [f64], op: FloatOp) -> Result<(), TransportError> {
        let mine: Vec<u8> = values.iter().flat_map(|v| v.to_bits().to_le_bytes()).collect();
        let all = self.allgather(&mine)?;
        if all.iter().any(|r| r.len() != mine.len()) {
            return Err(TransportError::Mismatch("allreduce_f64 lengths differ".into()));
        }
        let at = |r: &Vec<u8>, k: usize| f64::from_bits(u64::from_le_bytes(r[8 * k..8 * k + 8].try_into().expect("8")));
        for (k, v) in values.iter_mut().enumerate() {
            *v = all[1..]
                .iter()
                .fold(at(&all[0], k), |acc, r| combine_float(acc, at(r, k), op));
        }
        Ok(())
    }

    fn allgather(&self, bytes: &[u8]) -> Result<Vec<Vec<u8>>, TransportError> {
        self.check()?;
        let n = self.ranks;
        let len = bytes.len() as i64;
        let mut lens = vec![0i64; n];
        let mut req = std::ptr::null_mut();
        // SAFETY: `len` and `lens` (n entries) outlive the request, which `wait` completes.
        let err = unsafe { bf_mpi_iallgather_len(&len, lens.as_mut_ptr(), &mut req) };
        if err != 0 {
            return Err(self.mpi_error("MPI_Iallgather", err));
        }
        self.wait(req)?;
        let total: i64 = lens.iter().sum();
        if total > i32::MAX as i64 {
            return Err(TransportError::Mismatch(format!(
                "an allgather of {total} bytes (MPI counts are 31-bit)"
            )));
        }
        let counts: Vec<i32> = lens.iter().map(|&l| l as i32).collect();
        let displs: Vec<i32> = counts
            .iter()
            .scan(0i32, |at, &c| {
                let d = *at;
                *at += c;
                Some(d)
            })
            .collect();
        let mut all = vec![0u8; total as usize];
        let mut req = std::ptr::null_mut();
        // SAFETY: the buffers outlive the request, which `wait` completes.
        let err = unsafe {
            bf_mpi_iallgatherv(
                bytes.as_ptr() as *const c_void,
                len,
                all.as_mut_ptr() as *mut c_void,
                counts.as_ptr(),
                displs.as_ptr(),
                &mut req,
            )
        };
        if err != 0 {
            return Err(self.mpi_error("MPI_Iallgatherv", err));
        }
        self.wait(req)?;
        Ok((0..n)
            .map(|r| all[displs[r] as usize..(displs[r] + counts[r]) as usize].to_vec())
            .collect())
    }

    fn broadcast(&self, root: Rank, bytes: &mut Vec<u8>) -> Result<(), TransportError> {
        if root >= self.ranks {
            return Err(TransportError::NoSuchRank {
                rank: root,
                ranks: self.ranks,
            });
        }
        let mine = if self.rank == root {
            std::mem::take(bytes)
        } else {
            Vec::new()
        };
        let mut all = self.allgather(&mine)?;
        *bytes = std::mem::take(&mut all[root]);
        Ok(())
    }

    fn abort(&self, code: i32, message: &str) {
        {
            let mut a = self.aborted.lock().expect("abort state");
            if a.is_some() {
                return;
            }
            *a = Some(TransportError::Aborted {
                rank: self.rank,
                code,
                message: message.to_string(),
            });
        }
        let mut notice = code.to_le_bytes().to_vec();
        notice.extend_from_slice(message.as_bytes());
        let mut reqs = Vec::new();
        for to in (0..self.ranks).filter(|&r| r != self.rank) {
            let mut req = std::ptr::null_mut();
            // SAFETY: `notice` outlives the requests, completed (or given up) below.
            let err = unsafe {
                bf_mpi_isend(
                    ABORT,
                    to as i32,
                    0,
                    notice.as_ptr() as *const c_void,
                    notice.len() as i64,
                    &mut req,
                )
            };
            if err == 0 {
                reqs.push(req);
            }
        }
        // Small messages complete at once; give the others a moment, then let the process end (the
        // launcher ends the job when a rank exits with an error).
        let start = Instant::now();
        while !reqs.is_empty() && start.elapsed() < Duration::from_secs(2) {
            reqs.retain(|&r| {
                let mut done = 0;
                // SAFETY: a live request.
                unsafe { bf_mpi_test(r, &mut done) };
                done == 0
            });
            std::thread::yield_now();
        }
        if !reqs.is_empty() {
            // Still in flight: the buffer must outlive the sends.
            std::mem::forget(notice);
        }
    }
}
