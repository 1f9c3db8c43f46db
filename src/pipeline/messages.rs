//! Which ghost regions cross processes under an assignment ([`MessagePlan`]: the outgoing messages of
//! every sender, the slot of every remote (receiver, region)), and the bytes of every region
//! ([`MessageSizes`], which tells the cost model what an edge of the step graph carries).

use super::kinds::{Payload, TaskKind};
use crate::metrics::cost_model::TaskSemantics;
use crate::physics::block::Block;
use crate::physics::simulation::Simulation;
use blockflow_kernels::Real;
use blockflow_scheduler::TaskSpec;
use std::collections::HashMap;
use std::sync::Mutex;

/// A remote message: which receiver and ghost region a slot feeds.
#[derive(Clone, Copy, Debug)]
pub(super) struct Outgoing {
    /// Receiving block.
    pub(super) receiver: usize,
    /// Index of the region in the receiver's `recv` list.
    pub(super) recv: usize,
    /// Message slot.
    pub(super) slot: usize,
}

/// The cross-process ghost regions of an assignment and their message buffers.
pub(super) struct MessagePlan<T> {
    /// Outgoing messages per sending block.
    pub(super) outgoing: Vec<Vec<Outgoing>>,
    /// Slot per (receiving block, region index) when the sender is remote.
    pub(super) slot_of: Vec<Vec<Option<usize>>>,
    /// The message buffers.
    pub(super) slots: Vec<Mutex<Vec<T>>>,
}

impl<T: Real> MessagePlan<T> {
    /// The plan of `owners` (block id → process).
    pub(super) fn new(sim: &Simulation<T>, owners: &[u32]) -> Self {
        let mut outgoing = vec![Vec::new(); sim.blocks.len()];
        let mut slot_of = Vec::with_capacity(sim.blocks.len());
        let mut nslots = 0;
        for b in &sim.blocks {
            let mut v = Vec::with_capacity(b.recv.len());
            for (r, g) in b.recv.iter().enumerate() {
                if owners[g.from] != owners[b.id] {
                    outgoing[g.from].push(Outgoing {
                        receiver: b.id,
                        recv: r,
                        slot: nslots,
                    });
                    v.push(Some(nslots));
                    nslots += 1;
                } else {
                    v.push(None);
                }
            }
            slot_of.push(v);
        }
        MessagePlan {
            outgoing,
            slot_of,
            slots: (0..nslots).map(|_| Mutex::new(Vec::new())).collect(),
        }
    }

    /// Bytes and count of the cross-process messages of one step that the blocks for which `mine` holds
    /// send.
    pub(super) fn remote_per_step(&self, sim: &Simulation<T>, mine: impl Fn(usize) -> bool) -> (u64, u64) {
        let mut bytes = 0u64;
        let mut remote = 0u64;
        for o in (0..self.outgoing.len())
            .filter(|&b| mine(b))
            .flat_map(|b| &self.outgoing[b])
        {
            let g = &sim.blocks[o.receiver].recv[o.recv];
            bytes += (region_cells(&sim.blocks[o.receiver], g.offset) * g.directions.len() * T::BYTES) as u64;
            remote += 1;
        }
        (bytes, remote)
    }
}

/// Cells of the ghost region at offset `off` of block `b`.
fn region_cells<T: Real>(b: &Block<T>, off: [i32; 3]) -> usize {
    (0..3).map(|a| if off[a] == 0 { b.layout.size[a] } else { 1 }).product()
}

/// The bytes of every (sender block, receiver block) ghost region, summed over the regions a pair shares
/// across periodic wraps: what the edge into a `comm` task carries.
pub struct MessageSizes {
    region_bytes: HashMap<(u32, u32), u64>,
}

impl MessageSizes {
    /// The region sizes of `sim`'s blocks.
    pub fn of<T: Real>(sim: &Simulation<T>) -> Self {
        let mut region_bytes = HashMap::new();
        for b in &sim.blocks {
            for g in &b.recv {
                let bytes = (region_cells(b, g.offset) * g.directions.len() * T::BYTES) as u64;
                *region_bytes.entry((g.from as u32, b.id as u32)).or_insert(0) += bytes;
            }
        }
        MessageSizes { region_bytes }
    }
}

impl TaskSemantics for MessageSizes {
    fn step(&self, spec: &TaskSpec) -> usize {
        Payload::of(spec).step
    }

    fn edge_bytes(&self, a: &TaskSpec, b: &TaskSpec) -> u64 {
        if Payload::of(b).kind == TaskKind::Comm {
            self.region_bytes.get(&(a.block, b.block)).copied().unwrap_or(0)
        } else {
            0
        }
    }
}
