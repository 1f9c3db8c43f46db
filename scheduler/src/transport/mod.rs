//! Moving bytes between ranks: the interface every rank driver talks through ([`Transport`]) and two
//! implementations, [`SingleRank`] (one rank, no copies across anything) and [`Loopback`] (R ranks in one
//! OS process, each on its own thread with its own mailbox, optionally with seeded random delays on every
//! message); with the `mpi` feature, `Mpi` (ranks in separate processes of an MPI job).
//!
//! The model is MPI's, reduced to what a block-structured solver needs:
//! - point-to-point messages are owned byte vectors addressed by (receiver, [`Tag`]); a send never
//!   blocks, and messages from one sender with one tag arrive in the order they were sent (MPI's
//!   non-overtaking rule); a receive is probed ([`Transport::try_recv`]) or waited for
//!   ([`Transport::recv`]), and [`Transport::poll`] completes whatever can complete now;
//! - collectives are called by every rank in the same order: allreduce of integers (sum, max, min, or)
//!   and of floats by max or min only (a float sum depends on the order of its terms, so sums that must
//!   stay bitwise identical for any rank count are gathered and added in a fixed order by the caller),
//!   allgather of byte vectors and broadcast; reductions combine the ranks' values in rank order;
//! - [`Transport::abort`] ends the group: every call on every rank, including one waiting in a
//!   collective or a receive, returns [`TransportError::Aborted`] from then on, so one failing rank
//!   never leaves the others hanging.

mod loopback;
#[cfg(feature = "mpi")]
mod mpi;
mod single;
#[cfg(test)]
mod tests;

pub use loopback::{run_loopback, run_loopback_shared, Delays, Loopback};
#[cfg(feature = "mpi")]
pub use mpi::Mpi;
pub use single::SingleRank;

use std::fmt;

/// The `mpirun` options (Open MPI) that start more ranks than there are cores, as root, without binding
/// ranks to cores, quietly; followed by `-np N`. For tests and benchmarks on a small machine, not for a
/// cluster, where the launcher's own binding is wanted.
pub const MPIRUN_SMALL_MACHINE: [&str; 5] = ["--allow-run-as-root", "--oversubscribe", "--bind-to", "none", "-q"];

/// A rank's index in its group (0-based).
pub type Rank = usize;

/// What distinguishes messages between the same two ranks: the message class (ghost regions, bodies,
/// forces, …; an MPI transport gives each class its own communicator) and a value both sides derive from
/// the plan of the step (e.g. the receiving block and region).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Tag {
    /// Message class.
    pub class: u8,
    /// Tag within the class (MPI guarantees tags up to 32767; larger ones are checked against its
    /// `MPI_TAG_UB`).
    pub value: u32,
}

impl Tag {
    /// The tag `value` of class `class`.
    pub const fn new(class: u8, value: u32) -> Self {
        Tag { class, value }
    }
}

/// How an integer allreduce combines the ranks' values.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum IntOp {
    /// Wrapping sum.
    Sum,
    /// Largest value.
    Max,
    /// Smallest value.
    Min,
    /// Bitwise or (flags).
    Or,
}

/// How a float allreduce combines the ranks' values: extremes only, which do not depend on the order of
/// the terms. A NaN on any rank gives NaN (an instability must not be hidden by a reduction).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FloatOp {
    /// Largest value (NaN if any value is NaN).
    Max,
    /// Smallest value (NaN if any value is NaN).
    Min,
}

/// Why a transport call failed.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum TransportError {
    /// Rank `rank` called [`Transport::abort`] with `code` and `message`.
    Aborted {
        /// The rank that aborted.
        rank: Rank,
        /// Its exit code.
        code: i32,
        /// Its one-line reason.
        message: String,
    },
    /// A call named a rank outside the group.
    NoSuchRank {
        /// The rank named.
        rank: Rank,
        /// Ranks in the group.
        ranks: usize,
    },
    /// The ranks called different collectives, or the same one with different sizes, at the same point.
    Mismatch(String),
}

impl fmt::Display for TransportError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            TransportError::Aborted { rank, code, message } => {
                write!(f, "rank {rank} aborted (exit code {code}): {message}")
            }
            TransportError::NoSuchRank { rank, ranks } => {
                write!(f, "rank {rank} does not exist (the group has {ranks} ranks)")
            }
            TransportError::Mismatch(m) => write!(f, "collective mismatch: {m}"),
        }
    }
}

impl std::error::Error for TransportError {}

/// The operations a rank driver uses to talk to the other ranks of its group (see the module docs for
/// the ordering and failure rules).
pub trait Transport: Send + Sync {
    /// This rank's index.
    fn rank(&self) -> Rank;

    /// Ranks in the group.
    fn ranks(&self) -> usize;

    /// This rank's index among the ranks on its machine, and their number (for placing its threads on
    /// the machine's cores). In-process groups share one machine: (rank, ranks).
    fn node_rank(&self) -> (Rank, usize) {
        (self.rank(), self.ranks())
    }

    /// Queues `bytes` for rank `to` under `tag` and returns at once (never waits for the receiver).
    fn send(&self, to: Rank, tag: Tag, bytes: Vec<u8>) -> Result<(), TransportError>;

    /// The oldest message that has arrived from `from` under `tag`, if any; never waits.
    fn try_recv(&self, from: Rank, tag: Tag) -> Result<Option<Vec<u8>>, TransportError>;

    /// The oldest message of class `class` that has arrived from any rank under any tag of that class,
    /// with its sender and tag, if any; never waits. (Messages of one sender and tag still come in the
    /// order they were sent; between senders or tags the order is the transport's.)
    fn try_recv_any(&self, class: u8) -> Result<Option<(Rank, Tag, Vec<u8>)>, TransportError>;

    /// Completes what can complete now (delivers messages that are due) and returns how many messages
    /// arrived at this rank in this call.
    fn poll(&self) -> Result<usize, TransportError>;

    /// The thread to unpark when a message arrives for this rank (the rank's driver, which parks while
    /// it waits). Transports that cannot wake a thread ignore it; the driver then finds the message at
    /// its next poll.
    fn set_waker(&self, _driver: std::thread::Thread) {}

    /// Whether any thread of the rank may call [`Transport::send`] (else only the rank's driver: MPI
    /// initialised for funnelled threads). A rank whose worker threads may send skips the hop through
    /// its driver.
    fn sends_from_any_thread(&self) -> bool {
        false
    }

    /// Waits for the oldest message from `from` under `tag` (polling) and takes it.
    fn recv(&self, from: Rank, tag: Tag) -> Result<Vec<u8>, TransportError> {
        loop {
            self.poll()?;
            if let Some(m) = self.try_recv(from, tag)? {
                return Ok(m);
            }
            std::thread::yield_now();
        }
    }

    /// Combines `values` element-wise over all ranks by `op`, in rank order; every rank gets the result in
    /// place. Every rank must pass the same length.
    fn allreduce_u64(&self, values: &mut [u64], op: IntOp) -> Result<(), TransportError>;

    /// Combines `values` element-wise over all ranks by `op`; every rank gets the result in place.
    fn allreduce_f64(&self, values: &mut [f64], op: FloatOp) -> Result<(), TransportError>;

    /// Every rank's `bytes`, indexed by rank, on every rank.
    fn allgather(&self, bytes: &[u8]) -> Result<Vec<Vec<u8>>, TransportError>;

    /// Replaces `bytes` on every rank by root's `bytes`.
    fn broadcast(&self, root: Rank, bytes: &mut Vec<u8>) -> Result<(), TransportError>;

    /// Ends the group with `code` and a one-line `message`: from now on every call on every rank returns
    /// [`TransportError::Aborted`] (the first abort wins).
    fn abort(&self, code: i32, message: &str);
}

/// `a` combined with `b` by `op`.
fn combine_int(a: u64, b: u64, op: IntOp) -> u64 {
    match op {
        IntOp::Sum => a.wrapping_add(b),
        IntOp::Max => a.max(b),
        IntOp::Min => a.min(b),
        IntOp::Or => a | b,
    }
}

/// `a` combined with `b` by `op`, NaN if either is NaN; between +0 and −0 the first operand wins, so the
/// result depends only on the rank order.
fn combine_float(a: f64, b: f64, op: FloatOp) -> f64 {
    if a.is_nan() || b.is_nan() {
        return f64::NAN;
    }
    match op {
        FloatOp::Max => {
            if b > a {
                b
            } else {
                a
            }
        }
        FloatOp::Min => {
            if b < a {
                b
            } else {
                a
            }
        }
    }
}
