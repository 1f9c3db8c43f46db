//! The transport of a group of one rank: messages to itself go straight into its mailbox, collectives
//! return the rank's own values.

use super::{FloatOp, IntOp, Rank, Tag, Transport, TransportError};
use std::collections::{HashMap, VecDeque};
use std::sync::Mutex;

/// A group of one rank (the virtual-process mode: every block in one OS process, shared memory).
#[derive(Debug, Default)]
pub struct SingleRank {
    mailbox: Mutex<HashMap<Tag, VecDeque<Vec<u8>>>>,
    aborted: Mutex<Option<TransportError>>,
}

impl SingleRank {
    /// A new group of one rank.
    pub fn new() -> Self {
        SingleRank::default()
    }

    fn check(&self) -> Result<(), TransportError> {
        match &*self.aborted.lock().expect("abort state") {
            Some(e) => Err(e.clone()),
            None => Ok(()),
        }
    }

    fn check_rank(&self, rank: Rank) -> Result<(), TransportError> {
        if rank == 0 {
            Ok(())
        } else {
            Err(TransportError::NoSuchRank { rank, ranks: 1 })
        }
    }
}

impl Transport for SingleRank {
    fn rank(&self) -> Rank {
        0
    }

    fn ranks(&self) -> usize {
        1
    }

    fn send(&self, to: Rank, tag: Tag, bytes: Vec<u8>) -> Result<(), TransportError> {
        self.check()?;
        self.check_rank(to)?;
        self.mailbox
            .lock()
            .expect("mailbox")
            .entry(tag)
            .or_default()
            .push_back(bytes);
        Ok(())
    }

    fn try_recv(&self, from: Rank, tag: Tag) -> Result<Option<Vec<u8>>, TransportError> {
        self.check()?;
        self.check_rank(from)?;
        Ok(self
            .mailbox
            .lock()
            .expect("mailbox")
            .get_mut(&tag)
            .and_then(|q| q.pop_front()))
    }

    fn try_recv_any(&self, class: u8) -> Result<Option<(Rank, Tag, Vec<u8>)>, TransportError> {
        self.check()?;
        let mut m = self.mailbox.lock().expect("mailbox");
        let mut tags: Vec<Tag> = m.keys().filter(|t| t.class == class).copied().collect();
        tags.sort();
        for tag in tags {
            if let Some(bytes) = m.get_mut(&tag).and_then(|q| q.pop_front()) {
                return Ok(Some((0, tag, bytes)));
            }
        }
        Ok(None)
    }

    fn recv(&self, from: Rank, tag: Tag) -> Result<Vec<u8>, TransportError> {
        // Nothing else can send to a group of one: a missing message would never come.
        self.try_recv(from, tag)?.ok_or_else(|| {
            TransportError::Mismatch(format!(
                "rank 0 waits for a message (class {}, tag {}) that it never sent itself",
                tag.class, tag.value
            ))
        })
    }

    fn poll(&self) -> Result<usize, TransportError> {
        self.check().map(|_| 0)
    }

    fn allreduce_u64(&self, _values: &mut [u64], _op: IntOp) -> Result<(), TransportError> {
        self.check()
    }

    fn allreduce_f64(&self, _values: &mut [f64], _op: FloatOp) -> Result<(), TransportError> {
        // The extreme of one value is the value (NaN included).
        self.check()
    }

    fn allgather(&self, bytes: &[u8]) -> Result<Vec<Vec<u8>>, TransportError> {
        self.check()?;
        Ok(vec![bytes.to_vec()])
    }

    fn broadcast(&self, root: Rank, _bytes: &mut Vec<u8>) -> Result<(), TransportError> {
        self.check()?;
        self.check_rank(root)
    }

    fn abort(&self, code: i32, message: &str) {
        let mut a = self.aborted.lock().expect("abort state");
        if a.is_none() {
            *a = Some(TransportError::Aborted {
                rank: 0,
                code,
                message: message.to_string(),
            });
        }
    }
}
