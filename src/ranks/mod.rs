//! The ranks a run is spread over ([`World`]): this rank's index, the group's transport, and the
//! collectives the run needs, each keeping the block-id order of the numbers it combines.
//!
//! Under virtual processes the world is one rank ([`World::single`]): every block lives in this OS
//! process, and every global view (diagnostics, bodies, checksums, outputs) is computed from memory.
//! Under ranks ([`World::new`] over a [`Transport`]: the in-process loopback of `blockflow run --ranks R`,
//! or MPI) each rank holds only the blocks it owns; a global view is then its per-block parts gathered
//! and combined in ascending block-id order, so it has the same bits as the single-rank one:
//! - integer sums (checksums, counts) and extremes are reduced directly ([`World::sum`], [`World::or`],
//!   [`World::min`], [`World::max_f64`]): their result does not depend on the order of the terms;
//! - per-block values are gathered with their block ids ([`World::all_blocks`] to every rank,
//!   [`World::gather_blocks`] to rank 0) and the caller combines them in block-id order, exactly as the
//!   single-rank code does over its blocks.
//!
//! Messages of different purposes never mix: each has its own transport class ([`class`]).

pub mod views;

use crate::error::{Error, Result};
use blockflow_scheduler::transport::{FloatOp, IntOp, SingleRank, Tag, Transport, TransportError};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::Arc;

/// The transport classes of a run's messages.
pub mod class {
    /// The messages of a graph run: ghost regions, published bodies, velocity changes, body forces.
    pub const GRAPH: u8 = 1;
    /// The copies of the neighbours' particle state sent before a graph run.
    pub const HALO: u8 = 2;
    /// Blocks moving to a new owner.
    pub const MIGRATE: u8 = 3;
    /// Per-block records gathered to rank 0 (outputs, checkpoints).
    pub const GATHER: u8 = 4;
}

/// The group of ranks a run is spread over, seen from one of them (see the module docs).
pub struct World {
    transport: Arc<dyn Transport>,
    /// Gathers so far (every rank makes the same ones in the same order): the tag of the next one.
    gathers: AtomicU32,
}

impl std::fmt::Debug for World {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "World(rank {} of {})", self.rank(), self.ranks())
    }
}

impl World {
    /// A world of one rank: every block in this process.
    pub fn single() -> Self {
        World::new(Arc::new(SingleRank::new()))
    }

    /// This rank of the group behind `transport`.
    pub fn new(transport: Arc<dyn Transport>) -> Self {
        World {
            transport,
            gathers: AtomicU32::new(0),
        }
    }

    /// This rank's index.
    pub fn rank(&self) -> usize {
        self.transport.rank()
    }

    /// Ranks in the group.
    pub fn ranks(&self) -> usize {
        self.transport.ranks()
    }

    /// Whether this is rank 0, the one that writes the run's outputs.
    pub fn is_root(&self) -> bool {
        self.rank() == 0
    }

    /// Whether the group has one rank (every block in this process).
    pub fn is_single(&self) -> bool {
        self.ranks() == 1
    }

    /// The transport.
    pub fn transport(&self) -> &dyn Transport {
        &*self.transport
    }

    /// Ends the group because this rank failed with `e`: every rank waiting in a collective or for a
    /// message gets [`Error::Aborted`] with this rank's exit code and message.
    pub fn abort(&self, e: &Error) {
        self.transport.abort(e.exit_code(), &e.to_string());
    }

    /// A transport failure as a run error: another rank's abort keeps its rank, code and message.
    pub fn error(&self, e: TransportError) -> Error {
        match e {
            TransportError::Aborted { rank, code, message } => Error::Aborted { rank, code, message },
            other => Error::Aborted {
                rank: self.rank(),
                code: 70,
                message: format!("the ranks fell out of step ({other}); this is a bug, please report it"),
            },
        }
    }

    /// Bitwise or of `v` over the ranks (flags, sets of blocks).
    pub fn or(&self, v: &mut [u64]) -> Result<()> {
        self.transport.allreduce_u64(v, IntOp::Or).map_err(|e| self.error(e))
    }

    /// Wrapping sum of `v` over the ranks (checksums, counts).
    pub fn sum(&self, v: &mut [u64]) -> Result<()> {
        self.transport.allreduce_u64(v, IntOp::Sum).map_err(|e| self.error(e))
    }

    /// Smallest `v` over the ranks (the first of several events, by a key).
    pub fn min(&self, v: &mut [u64]) -> Result<()> {
        self.transport.allreduce_u64(v, IntOp::Min).map_err(|e| self.error(e))
    }

    /// Largest `v` over the ranks (NaN if any rank has NaN).
    pub fn max_f64(&self, v: &mut [f64]) -> Result<()> {
        self.transport.allreduce_f64(v, FloatOp::Max).map_err(|e| self.error(e))
    }

    /// Every rank's bytes, by rank.
    pub fn allgather(&self, bytes: &[u8]) -> Result<Vec<Vec<u8>>> {
        self.transport.allgather(bytes).map_err(|e| self.error(e))
    }

    /// Root's bytes on every rank.
    pub fn broadcast(&self, root: usize, bytes: &mut Vec<u8>) -> Result<()> {
        self.transport.broadcast(root, bytes).map_err(|e| self.error(e))
    }

    /// The records of `blocks` blocks on every rank: each rank gives those of the blocks it holds as
    /// (block id, bytes); every block must be given by exactly one rank. Indexed by block id.
    pub fn all_blocks(&self, blocks: usize, mine: Vec<(usize, Vec<u8>)>) -> Result<Vec<Vec<u8>>> {
        if self.is_single() {
            return assemble(blocks, [mine]);
        }
        let all = self.allgather(&encode_records(&mine))?;
        let parts: Vec<Vec<(usize, Vec<u8>)>> = all.iter().map(|b| decode_records(b)).collect();
        assemble(blocks, parts)
    }

    /// [`World::all_blocks`] on rank 0 only (the others send theirs and get `None`): what rank 0 needs to
    /// write an output of the whole domain.
    pub fn gather_blocks(&self, blocks: usize, mine: Vec<(usize, Vec<u8>)>) -> Result<Option<Vec<Vec<u8>>>> {
        if self.is_single() {
            return assemble(blocks, [mine]).map(Some);
        }
        let tag = self.stream_tag();
        if !self.is_root() {
            self.transport
                .send(0, tag, encode_records(&mine))
                .map_err(|e| self.error(e))?;
            return Ok(None);
        }
        let mut parts = vec![mine];
        for r in 1..self.ranks() {
            let bytes = self.transport.recv(r, tag).map_err(|e| self.error(e))?;
            parts.push(decode_records(&bytes));
        }
        assemble(blocks, parts).map(Some)
    }

    /// The tag of a new stream of messages to rank 0 (every rank calls this at the same point, so they all
    /// name the stream alike): for outputs that rank 0 writes as the pieces arrive.
    pub fn stream_tag(&self) -> Tag {
        Tag::new(class::GATHER, self.gathers.fetch_add(1, Ordering::Relaxed) & 0x7fff)
    }

    /// One f64 per block on every rank: each rank gives the values of the blocks it holds (see
    /// [`World::all_blocks`]).
    pub fn all_block_values(&self, blocks: usize, mine: Vec<(usize, f64)>) -> Result<Vec<f64>> {
        let records = mine.into_iter().map(|(b, v)| (b, v.to_le_bytes().to_vec())).collect();
        Ok(self
            .all_blocks(blocks, records)?
            .iter()
            .map(|v| f64::from_le_bytes(v[..8].try_into().expect("8 bytes per value")))
            .collect())
    }
}

/// Per-block records as bytes: u32 count, then per record u32 block id, u64 length, the bytes.
fn encode_records(records: &[(usize, Vec<u8>)]) -> Vec<u8> {
    let len: usize = records.iter().map(|(_, b)| 12 + b.len()).sum();
    let mut out = Vec::with_capacity(4 + len);
    out.extend_from_slice(&(records.len() as u32).to_le_bytes());
    for (b, bytes) in records {
        out.extend_from_slice(&(*b as u32).to_le_bytes());
        out.extend_from_slice(&(bytes.len() as u64).to_le_bytes());
        out.extend_from_slice(bytes);
    }
    out
}

/// The records of [`encode_records`] (bytes a rank of the same group wrote).
fn decode_records(bytes: &[u8]) -> Vec<(usize, Vec<u8>)> {
    let u32_at = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes")) as usize;
    let n = u32_at(0);
    let mut at = 4;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let b = u32_at(at);
        let len = u64::from_le_bytes(bytes[at + 4..at + 12].try_into().expect("8 bytes")) as usize;
        out.push((b, bytes[at + 12..at + 12 + len].to_vec()));
        at += 12 + len;
    }
    out
}

/// The records of every block from the ranks' parts (each block exactly once).
fn assemble(blocks: usize, parts: impl IntoIterator<Item = Vec<(usize, Vec<u8>)>>) -> Result<Vec<Vec<u8>>> {
    let mut out: Vec<Option<Vec<u8>>> = vec![None; blocks];
    for (b, bytes) in parts.into_iter().flatten() {
        if b >= blocks || out[b].is_some() {
            return Err(Error::Aborted {
                rank: 0,
                code: 70,
                message: format!("block {b} was gathered twice or does not exist; this is a bug, please report it"),
            });
        }
        out[b] = Some(bytes);
    }
    out.into_iter()
        .enumerate()
        .map(|(b, r)| {
            r.ok_or_else(|| Error::Aborted {
                rank: 0,
                code: 70,
                message: format!("no rank holds block {b}; this is a bug, please report it"),
            })
        })
        .collect()
}

/// Runs `f` on every rank of a new in-process (loopback) group of `ranks` ranks, each on its own thread
/// with its own [`World`], optionally with seeded random delays on every message; returns the results by
/// rank. A rank whose `f` panics ends the group (the others' collectives and receives fail instead of
/// waiting for it) and the panic is resumed here once every rank has returned.
pub fn run_loopback<R: Send>(
    ranks: usize,
    delays: Option<blockflow_scheduler::transport::Delays>,
    f: impl Fn(World) -> R + Sync,
) -> Vec<R> {
    blockflow_scheduler::transport::run_loopback_shared(ranks, delays, |t| f(World::new(t)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn block_records_come_back_in_block_order_on_every_rank_and_on_the_root() {
        for ranks in [1, 2, 3] {
            let out = run_loopback(ranks, None, |w| {
                // Block b belongs to rank b % ranks, its record is b repeated b times.
                let mine: Vec<(usize, Vec<u8>)> = (0..7)
                    .filter(|b| b % w.ranks() == w.rank())
                    .map(|b| (b, vec![b as u8; b]))
                    .collect();
                let all = w.all_blocks(7, mine.clone()).unwrap();
                let root = w.gather_blocks(7, mine.clone()).unwrap();
                let again = w.gather_blocks(7, mine).unwrap();
                let own = (0..7).filter(|b| b % w.ranks() == w.rank());
                let values = w
                    .all_block_values(7, own.map(|b| (b, b as f64 * 0.5)).collect())
                    .unwrap();
                (w.rank(), all, root, again, values)
            });
            for (rank, all, root, again, values) in out {
                let want: Vec<Vec<u8>> = (0..7).map(|b| vec![b as u8; b]).collect();
                assert_eq!(all, want);
                assert_eq!(root.is_some(), rank == 0);
                assert_eq!(again.is_some(), rank == 0);
                if let (Some(r), Some(a)) = (root, again) {
                    assert_eq!((r, a), (want.clone(), want));
                }
                assert_eq!(values, (0..7).map(|b| b as f64 * 0.5).collect::<Vec<_>>());
            }
        }
    }

    #[test]
    fn a_failing_rank_ends_the_others_with_its_code_and_message() {
        let out = run_loopback(3, None, |w| {
            if w.rank() == 1 {
                w.abort(&Error::Config("bad key x.y".into()));
                return None;
            }
            let e = w.sum(&mut [1]).expect_err("the group was ended");
            Some((e.exit_code(), e.to_string()))
        });
        for o in out.into_iter().flatten() {
            assert_eq!(o, (1, "rank 1: bad key x.y".to_string()));
        }
    }
}
