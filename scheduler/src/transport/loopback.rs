//! R ranks in one OS process: each rank is a thread with its own mailbox; a message is moved, never
//! shared. With [`Delays`], every message is held back by a seeded pseudo-random time before it can be
//! received (keeping the order per sender and tag), to shake out ordering assumptions.

use super::{combine_float, combine_int, FloatOp, IntOp, Rank, Tag, Transport, TransportError};
use std::collections::{HashMap, VecDeque};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

/// Seeded random delays on every message of a [`Loopback`] group.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Delays {
    /// Seed of the delays (the same seed gives the same delay to the n-th message of each sender).
    pub seed: u64,
    /// Longest delay.
    pub max: Duration,
}

/// A message on its way: receivable from `due` on.
#[derive(Debug)]
struct InFlight {
    due: Instant,
    from: Rank,
    tag: Tag,
    bytes: Vec<u8>,
}

/// One rank's incoming messages.
#[derive(Debug, Default)]
struct Mailbox {
    /// Received, per (sender, tag), oldest first.
    arrived: HashMap<(Rank, Tag), VecDeque<Vec<u8>>>,
    /// Messages in `arrived`.
    waiting: usize,
    /// Not yet due (with delays only).
    in_flight: Vec<InFlight>,
    /// The due time of the last message per (sender, tag), so a later one is never due earlier.
    last_due: HashMap<(Rank, Tag), Instant>,
}

/// The rendezvous of the collectives: contributions of the current round and the result of the last.
#[derive(Debug)]
struct Rendezvous {
    round: u64,
    count: usize,
    contributions: Vec<Option<(&'static str, Vec<u8>)>>,
    result: Arc<Vec<Vec<u8>>>,
}

/// What the ranks of one group share.
#[derive(Debug)]
struct Group {
    ranks: usize,
    delays: Option<Delays>,
    mailboxes: Vec<Mutex<Mailbox>>,
    rendezvous: Mutex<Rendezvous>,
    wake: Condvar,
    /// Per rank: the thread to unpark when a message arrives ([`Transport::set_waker`]).
    wakers: Vec<Mutex<Option<std::thread::Thread>>>,
    aborted: AtomicBool,
    abort: Mutex<Option<TransportError>>,
}

/// One rank of a loopback group (made by [`Loopback::group`] or [`run_loopback`]).
#[derive(Debug)]
pub struct Loopback {
    rank: Rank,
    group: Arc<Group>,
    /// Messages this rank has sent (the delay of the n-th is a function of the seed, rank and n).
    sent: AtomicU64,
}

impl Loopback {
    /// The `ranks` ranks of a new group, index = rank.
    pub fn group(ranks: usize, delays: Option<Delays>) -> Vec<Loopback> {
        assert!(ranks >= 1, "a group has at least one rank");
        let group = Arc::new(Group {
            ranks,
            delays,
            mailboxes: (0..ranks).map(|_| Mutex::new(Mailbox::default())).collect(),
            rendezvous: Mutex::new(Rendezvous {
                round: 0,
                count: 0,
                contributions: vec![None; ranks],
                result: Arc::new(Vec::new()),
            }),
            wake: Condvar::new(),
            wakers: (0..ranks).map(|_| Mutex::new(None)).collect(),
            aborted: AtomicBool::new(false),
            abort: Mutex::new(None),
        });
        (0..ranks)
            .map(|rank| Loopback {
                rank,
                group: group.clone(),
                sent: AtomicU64::new(0),
            })
            .collect()
    }

    fn check(&self) -> Result<(), TransportError> {
        if self.group.aborted.load(Ordering::Acquire) {
            Err(self
                .group
                .abort
                .lock()
                .expect("abort state")
                .clone()
                .expect("abort recorded"))
        } else {
            Ok(())
        }
    }

    fn check_rank(&self, rank: Rank) -> Result<(), TransportError> {
        if rank < self.group.ranks {
            Ok(())
        } else {
            Err(TransportError::NoSuchRank {
                rank,
                ranks: self.group.ranks,
            })
        }
    }

    /// The delay of this rank's `n`-th message (splitmix64 of seed, rank and n).
    pub(super) fn delay(&self, d: &Delays, n: u64) -> Duration {
        let mut z = d
            .seed
            .wrapping_add((self.rank as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15))
            .wrapping_add(n.wrapping_mul(0xD1B5_4A32_D192_ED03));
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        let max = d.max.as_nanos().max(1) as u64;
        Duration::from_nanos(z % (max + 1))
    }

    /// Every rank's `(kind, bytes)` of this round, indexed by rank: the one rendezvous behind every
    /// collective. `kind` names the collective and its size, so ranks that call different ones fail
    /// with [`TransportError::Mismatch`] instead of mixing data.
    fn exchange(&self, kind: &'static str, bytes: Vec<u8>) -> Result<Arc<Vec<Vec<u8>>>, TransportError> {
        self.check()?;
        let g = &*self.group;
        let mut r = g.rendezvous.lock().expect("rendezvous");
        let round = r.round;
        r.contributions[self.rank] = Some((kind, bytes));
        r.count += 1;
        if r.count == g.ranks {
            let all: Vec<(&'static str, Vec<u8>)> = r
                .contributions
                .iter_mut()
                .map(|c| c.take().expect("every rank contributed"))
                .collect();
            r.count = 0;
            r.round += 1;
            let kinds_agree = all.iter().all(|(k, _)| *k == all[0].0);
            r.result = Arc::new(all.into_iter().map(|(_, b)| b).collect());
            let result = r.result.clone();
            let mismatch = (!kinds_agree).then(|| format!("the ranks called different collectives in round {round}"));
            if let Some(m) = &mismatch {
                // Recorded before the others wake, so each of them sees the abort when it checks.
                self.record_abort(TransportError::Mismatch(m.clone()));
            }
            g.wake.notify_all();
            drop(r);
            return match mismatch {
                Some(m) => Err(TransportError::Mismatch(m)),
                None => Ok(result),
            };
        }
        while r.round == round {
            if g.aborted.load(Ordering::Acquire) {
                drop(r);
                return Err(self.check().expect_err("aborted"));
            }
            r = g.wake.wait_timeout(r, Duration::from_millis(50)).expect("rendezvous").0;
        }
        let result = r.result.clone();
        drop(r);
        self.check()?;
        if result.len() != g.ranks {
            return Err(TransportError::Mismatch(format!(
                "round {round} ended without every rank"
            )));
        }
        Ok(result)
    }

    fn abort_with(&self, e: TransportError) {
        self.record_abort(e);
        // Wake every rank waiting in a collective (they re-check the flag).
        let g = &*self.group;
        let _r = g.rendezvous.lock().expect("rendezvous");
        g.wake.notify_all();
    }

    /// Sets the group's abort state (the first error is kept) without waking anyone.
    fn record_abort(&self, e: TransportError) {
        let g = &*self.group;
        {
            let mut a = g.abort.lock().expect("abort state");
            if a.is_none() {
                *a = Some(e);
            }
        }
        g.aborted.store(true, Ordering::Release);
    }
}

impl Transport for Loopback {
    fn rank(&self) -> Rank {
        self.rank
    }

    fn ranks(&self) -> usize {
        self.group.ranks
    }

    fn send(&self, to: Rank, tag: Tag, bytes: Vec<u8>) -> Result<(), TransportError> {
        self.check()?;
        self.check_rank(to)?;
        let n = self.sent.fetch_add(1, Ordering::Relaxed);
        let mut m = self.group.mailboxes[to].lock().expect("mailbox");
        match &self.group.delays {
            None => {
                m.arrived.entry((self.rank, tag)).or_default().push_back(bytes);
                m.waiting += 1;
                let first = m.waiting == 1;
                drop(m);
                // The receiver's driver looks at every message it finds once woken: wake it for the
                // first one only.
                if first {
                    if let Some(t) = self.group.wakers[to].lock().expect("waker").as_ref() {
                        t.unpark();
                    }
                }
            }
            Some(d) => {
                let key = (self.rank, tag);
                let mut due = Instant::now() + self.delay(d, n);
                if let Some(&last) = m.last_due.get(&key) {
                    due = due.max(last);
                }
                m.last_due.insert(key, due);
                m.in_flight.push(InFlight {
                    due,
                    from: self.rank,
                    tag,
                    bytes,
                });
            }
        }
        Ok(())
    }

    fn try_recv(&self, from: Rank, tag: Tag) -> Result<Option<Vec<u8>>, TransportError> {
        self.check()?;
        self.check_rank(from)?;
        let mut m = self.group.mailboxes[self.rank].lock().expect("mailbox");
        let got = m.arrived.get_mut(&(from, tag)).and_then(|q| q.pop_front());
        m.waiting -= usize::from(got.is_some());
        Ok(got)
    }

    fn try_recv_any(&self, class: u8) -> Result<Option<(Rank, Tag, Vec<u8>)>, TransportError> {
        self.check()?;
        let mut m = self.group.mailboxes[self.rank].lock().expect("mailbox");
        let key = m
            .arrived
            .iter()
            .filter(|(k, q)| k.1.class == class && !q.is_empty())
            .map(|(k, _)| *k)
            .min();
        let got = key.and_then(|k| {
            let q = m.arrived.get_mut(&k).expect("key found above");
            let bytes = q.pop_front()?;
            if q.is_empty() {
                m.arrived.remove(&k);
            }
            Some((k.0, k.1, bytes))
        });
        m.waiting -= usize::from(got.is_some());
        Ok(got)
    }

    fn sends_from_any_thread(&self) -> bool {
        true
    }

    fn set_waker(&self, driver: std::thread::Thread) {
        *self.group.wakers[self.rank].lock().expect("waker") = Some(driver);
    }

    fn poll(&self) -> Result<usize, TransportError> {
        self.check()?;
        let mut m = self.group.mailboxes[self.rank].lock().expect("mailbox");
        if m.in_flight.is_empty() {
            return Ok(0);
        }
        let now = Instant::now();
        // Deliver the due messages in due order (ties in send order: the sort is stable), which keeps
        // the order per (sender, tag) because their due times never decrease.
        let mut due: Vec<InFlight> = Vec::new();
        let mut i = 0;
        while i < m.in_flight.len() {
            if m.in_flight[i].due <= now {
                due.push(m.in_flight.remove(i));
            } else {
                i += 1;
            }
        }
        due.sort_by_key(|x| x.due);
        let n = due.len();
        for x in due {
            m.arrived.entry((x.from, x.tag)).or_default().push_back(x.bytes);
            m.waiting += 1;
        }
        Ok(n)
    }

    fn allreduce_u64(&self, values: &mut [u64], op: IntOp) -> Result<(), TransportError> {
        let mine: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        let all = self.exchange("allreduce_u64", mine)?;
        if all.iter().any(|r| r.len() != 8 * values.len()) {
            return Err(TransportError::Mismatch("allreduce_u64 lengths differ".into()));
        }
        let at = |r: &Vec<u8>, k: usize| u64::from_le_bytes(r[8 * k..8 * k + 8].try_into().expect("8 bytes"));
        for (k, v) in values.iter_mut().enumerate() {
            let mut acc = at(&all[0], k);
            for r in &all[1..] {
                acc = combine_int(acc, at(r, k), op);
            }
            *v = acc;
        }
        Ok(())
    }

    fn allreduce_f64(&self, values: &mut [f64], op: FloatOp) -> Result<(), TransportError> {
        let mine: Vec<u8> = values.iter().flat_map(|v| v.to_bits().to_le_bytes()).collect();
        let all = self.exchange("allreduce_f64", mine)?;
        if all.iter().any(|r| r.len() != 8 * values.len()) {
            return Err(TransportError::Mismatch("allreduce_f64 lengths differ".into()));
        }
        let at = |r: &Vec<u8>, k: usize| {
            f64::from_bits(u64::from_le_bytes(r[8 * k..8 * k + 8].try_into().expect("8 bytes")))
        };
        for (k, v) in values.iter_mut().enumerate() {
            let mut acc = at(&all[0], k);
            for r in &all[1..] {
                acc = combine_float(acc, at(r, k), op);
            }
            *v = acc;
        }
        Ok(())
    }

    fn allgather(&self, bytes: &[u8]) -> Result<Vec<Vec<u8>>, TransportError> {
        Ok(self.exchange("allgather", bytes.to_vec())?.as_ref().clone())
    }

    fn broadcast(&self, root: Rank, bytes: &mut Vec<u8>) -> Result<(), TransportError> {
        self.check_rank(root)?;
        let mine = if self.rank == root {
            std::mem::take(bytes)
        } else {
            Vec::new()
        };
        let all = self.exchange("broadcast", mine)?;
        *bytes = all[root].clone();
        Ok(())
    }

    fn abort(&self, code: i32, message: &str) {
        self.abort_with(TransportError::Aborted {
            rank: self.rank,
            code,
            message: message.to_string(),
        });
    }
}

/// Runs `f` on each rank of a new loopback group of `ranks` ranks, each on its own thread, and returns
/// the results by rank. A rank whose `f` panics aborts the group (so the others do not wait for it) and
/// the panic is re-raised here after every thread has ended.
pub fn run_loopback<R: Send>(ranks: usize, delays: Option<Delays>, f: impl Fn(&Loopback) -> R + Sync) -> Vec<R> {
    run_loopback_shared(ranks, delays, |t| f(&t))
}

/// [`run_loopback`] handing each rank its transport as an `Arc` (to keep in longer-lived state).
pub fn run_loopback_shared<R: Send>(
    ranks: usize,
    delays: Option<Delays>,
    f: impl Fn(Arc<Loopback>) -> R + Sync,
) -> Vec<R> {
    let group = Loopback::group(ranks, delays);
    std::thread::scope(|s| {
        let handles: Vec<_> = group
            .into_iter()
            .map(|t| {
                let f = &f;
                let t = Arc::new(t);
                std::thread::Builder::new()
                    .name(format!("blockflow-rank{}", t.rank))
                    .spawn_scoped(s, move || {
                        let out = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| f(t.clone())));
                        if out.is_err() {
                            t.abort(101, "the rank's driver panicked");
                        }
                        out
                    })
                    .expect("spawn a rank thread")
            })
            .collect();
        let results: Vec<_> = handles.into_iter().map(|h| h.join().expect("rank thread")).collect();
        results
            .into_iter()
            .map(|r| r.unwrap_or_else(|p| std::panic::resume_unwind(p)))
            .collect()
    })
}
