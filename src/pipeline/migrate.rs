//! Moving blocks between processes: a new assignment for the pipeline, the moved blocks carried as the
//! one block format of [`crate::serialise`].

use super::messages::MessagePlan;
use super::Pipeline;
use crate::physics::simulation::Simulation;
use blockflow_kernels::Real;
use std::sync::Mutex;

impl<T: Real> Pipeline<T> {
    /// Moves blocks to new owners: every block whose owner changes is serialised ([`crate::serialise`])
    /// by a thread of its old owner and rebuilt from the bytes by a thread of its new owner, which
    /// first-touches its new fields; then the ghost-region message plan is recomputed and the compiled
    /// graphs are dropped (the next run compiles for the new owners). Ghost layers are refilled by the
    /// next step's exchange. The numerics never see an owner. Returns the blocks moved and their bytes.
    pub fn set_owners(&mut self, sim: &Simulation<T>, owners: Vec<u32>) -> (usize, u64) {
        assert_eq!(owners.len(), sim.blocks.len());
        let moved: Vec<usize> = (0..owners.len()).filter(|&b| owners[b] != self.owners[b]).collect();
        if moved.is_empty() {
            return (0, 0);
        }
        let bufs: Vec<Mutex<Vec<u8>>> = moved.iter().map(|_| Mutex::new(Vec::new())).collect();
        let old = &self.owners;
        self.exec.on_each_process(|p| {
            for (i, &b) in moved.iter().enumerate() {
                if old[b] == p {
                    crate::serialise::encode_block(sim, b, &mut bufs[i].lock().expect("migration buffer"));
                }
            }
        });
        let new = &owners;
        self.exec.on_each_process(|p| {
            for (i, &b) in moved.iter().enumerate() {
                if new[b] == p {
                    let bytes = bufs[i].lock().expect("migration buffer");
                    // SAFETY: no task runs; each moved block is rebuilt by exactly one thread.
                    if let Err(e) = unsafe { crate::serialise::decode_block(sim, b, &bytes) } {
                        panic!("block {b} does not rebuild from its own bytes: {e}");
                    }
                }
            }
        });
        let bytes: u64 = bufs
            .iter()
            .map(|b| b.lock().expect("migration buffer").len() as u64)
            .sum();
        self.plan = MessagePlan::new(sim, &owners);
        self.owners = owners;
        self.graphs.clear();
        self.counts.clear();
        (moved.len(), bytes)
    }
}
