//! Moving blocks between processes or ranks: a new assignment for the pipeline, the moved blocks carried
//! as the one block format of [`crate::serialise`].

use super::messages::MessagePlan;
use super::ranked::RankGhosts;
use super::Pipeline;
use crate::error::{Error, Result};
use crate::physics::simulation::Simulation;
use crate::ranks::class;
use crate::serialise::{decode_block, encode_block, peek_header};
use blockflow_kernels::Real;
use blockflow_scheduler::transport::Tag;
use std::sync::Mutex;

impl<T: Real> Pipeline<T> {
    /// Moves blocks to new owners: every block whose owner changes is serialised ([`crate::serialise`])
    /// by a thread of its old owner and rebuilt from the bytes by a thread of its new owner, which
    /// first-touches its new fields; then the ghost-region message plan is recomputed and the step graph
    /// of a full graph run is compiled for the new owners. Ghost layers are refilled by the
    /// next step's exchange. The numerics never see an owner. Under ranks the bytes travel as messages
    /// (every rank calls this at once), the old owner gives the block up and the new one holds it from
    /// then on. Returns the blocks moved and their bytes (over all ranks).
    pub fn set_owners(&mut self, sim: &mut Simulation<T>, owners: Vec<u32>) -> Result<(usize, u64)> {
        assert_eq!(owners.len(), sim.blocks.len());
        let moved: Vec<usize> = (0..owners.len()).filter(|&b| owners[b] != self.owners[b]).collect();
        if moved.is_empty() {
            return Ok((0, 0));
        }
        let bytes = if self.ranks.is_some() {
            self.migrate_ranks(sim, &owners, &moved)?
        } else {
            self.migrate_processes(sim, &owners, &moved)
        };
        self.plan = MessagePlan::new(sim, &owners);
        if let Some(state) = self.ranks.as_mut() {
            state.ghosts = RankGhosts::new(sim, &owners, self.world.rank() as u32, self.settings.steps_per_graph);
        }
        self.owners = owners;
        self.graphs.clear();
        self.counts.clear();
        // The graph of a full run for the new owners, compiled here so that the balancing
        // step's clock covers it.
        if self.ranks.as_ref().is_none_or(|r| r.flags.is_some()) {
            self.graph(sim, self.settings.steps_per_graph);
        }
        Ok((moved.len(), bytes))
    }

    /// Moves blocks between the virtual processes of the executor (shared memory).
    fn migrate_processes(&self, sim: &Simulation<T>, owners: &[u32], moved: &[usize]) -> u64 {
        let bufs: Vec<Mutex<Vec<u8>>> = moved.iter().map(|_| Mutex::new(Vec::new())).collect();
        let old = &self.owners;
        self.exec.on_each_process(|p| {
            for (i, &b) in moved.iter().enumerate() {
                if old[b] == p {
                    encode_block(sim, b, &mut bufs[i].lock().expect("migration buffer"));
                }
            }
        });
        self.exec.on_each_process(|p| {
            for (i, &b) in moved.iter().enumerate() {
                if owners[b] == p {
                    let bytes = bufs[i].lock().expect("migration buffer");
                    // SAFETY: no task runs; each moved block is rebuilt by exactly one thread.
                    if let Err(e) = unsafe { decode_block(sim, b, &bytes) } {
                        panic!("block {b} does not rebuild from its own bytes: {e}");
                    }
                }
            }
        });
        bufs.iter()
            .map(|b| b.lock().expect("migration buffer").len() as u64)
            .sum()
    }

    /// Moves blocks between ranks: the old owner encodes and sends each block it gives up, then releases
    /// it; the new owner receives, holds and decodes it (on its worker, which first-touches the fields).
    fn migrate_ranks(&mut self, sim: &mut Simulation<T>, owners: &[u32], moved: &[usize]) -> Result<u64> {
        let world = self.world.clone();
        let me = world.rank() as u32;
        let t = world.transport();
        let tag = Tag::new(class::MIGRATE, 0);
        let mut sent = 0u64;
        let mut bytes = Vec::new();
        for &b in moved.iter().filter(|&&b| self.owners[b] == me) {
            bytes.clear();
            encode_block(sim, b, &mut bytes);
            sent += bytes.len() as u64;
            t.send(owners[b] as usize, tag, bytes.clone())
                .map_err(|e| world.error(e))?;
        }
        let want: Vec<usize> = moved.iter().copied().filter(|&b| owners[b] == me).collect();
        let mut arrived: Vec<Option<Vec<u8>>> = vec![None; want.len()];
        let mut left = want.len();
        while left > 0 {
            t.poll().map_err(|e| world.error(e))?;
            let Some((from, _, msg)) = t.try_recv_any(class::MIGRATE).map_err(|e| world.error(e))? else {
                std::thread::yield_now();
                continue;
            };
            let bad = |m: String| Error::Aborted {
                rank: me as usize,
                code: 70,
                message: format!("a migrated block from rank {from} {m}; this is a bug, please report it"),
            };
            let id = peek_header(&msg).map_err(|e| bad(e.to_string()))?.id;
            let i = want
                .binary_search(&id)
                .map_err(|_| bad(format!("is block {id}, not one moving here")))?;
            arrived[i] = Some(msg);
            left -= 1;
        }
        for &b in moved.iter().filter(|&&b| self.owners[b] == me) {
            // SAFETY: no task runs; the block's bytes went out above.
            unsafe { sim.blocks[b].release() };
        }
        for b in sim.blocks.iter().filter(|b| owners[b.id] != me) {
            // SAFETY: no task runs. Copies of other ranks' blocks are refilled before the next graph run.
            unsafe { b.set_remote_forces(Vec::new()) };
        }
        if let Some(parts) = sim.particles.as_mut() {
            let held = (0..owners.len()).map(|b| owners[b] == me).collect();
            // SAFETY: no task runs.
            unsafe { parts.hold_only(held) };
        }
        let errors: Mutex<Vec<String>> = Mutex::new(Vec::new());
        let sim_ref: &Simulation<T> = sim;
        self.exec.on_each_process(|_| {
            for (&b, msg) in want.iter().zip(&arrived) {
                // SAFETY: no task runs; each moved block is rebuilt by this one thread.
                let r = unsafe {
                    sim_ref.blocks[b].hold();
                    decode_block(sim_ref, b, msg.as_ref().expect("every block arrived"))
                };
                if let Err(e) = r {
                    errors.lock().expect("decode errors").push(format!("block {b}: {e}"));
                }
            }
        });
        if let Some(e) = errors.into_inner().expect("decode errors").into_iter().next() {
            return Err(Error::Aborted {
                rank: me as usize,
                code: 70,
                message: format!("{e} (a migrated block); this is a bug, please report it"),
            });
        }
        let mut total = [sent];
        world.sum(&mut total)?;
        Ok(total[0])
    }
}
