//! What each task of the step graph does: the per-block stage of [`crate::physics`] its kind names, on
//! the field of its step's parity.

use super::graph::RbGroups;
use super::kinds::{Payload, TaskKind};
use super::messages::MessagePlan;
use super::ranked::RankGhosts;
use crate::physics::simulation::Simulation;
use crate::physics::{coupling, fluid};
use blockflow_kernels::sweep::SweepStats;
use blockflow_kernels::Real;
use blockflow_scheduler::TaskSpec;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;
use std::time::Instant;

/// Everything the tasks of one graph run read, shared by the worker threads.
pub(super) struct Dispatch<'a, T: Real> {
    /// The state (blocks, particles, parameters).
    pub(super) sim: &'a Simulation<T>,
    /// Cross-process messages of the current assignment.
    pub(super) plan: &'a MessagePlan<T>,
    /// Sweep statistics per (step in the run, block), reduced in block order after the run.
    pub(super) stats: &'a [Mutex<SweepStats>],
    /// `run.no_skip`: the general paths instead of the skipping ones.
    pub(super) no_skip: bool,
    /// Under ranks: the ghost regions between ranks (packed into messages by `ranked::post`, unpacked
    /// from their buffers by `comm`).
    pub(super) ghosts: Option<&'a RankGhosts>,
    /// The blocks each grouped rigid-body task runs.
    pub(super) groups: &'a RbGroups,
    /// Monotonic nanoseconds of each member of a grouped round, per (step in the run, block).
    pub(super) member_ns: &'a [AtomicU64],
}

impl<T: Real> Dispatch<'_, T> {
    /// Runs task `spec` of the graph run that starts after `self.sim.step` steps.
    ///
    /// # Safety
    /// The graph must carry the edges of the module docs of [`super`], [`crate::physics::particles::tasks`]
    /// and [`crate::physics::coupling::tasks`]: every pair of tasks whose accesses to the same data conflict
    /// is ordered.
    pub(super) unsafe fn run(&self, spec: &TaskSpec) {
        let sim = self.sim;
        let blocks = &sim.blocks;
        let b = &blocks[spec.block as usize];
        let payload = Payload::of(spec);
        let step = sim.step + payload.step as u64;
        let p = (step % 2) as usize;
        let surface = sim.coupling.surface;
        match payload.kind {
            TaskKind::Rb | TaskKind::RbSync => {
                let parts = sim
                    .particles
                    .as_ref()
                    .expect("rigid-body tasks only exist with particles");
                let g = step * parts.phases() + payload.sub as u64 + 1;
                let one = |m: usize| match payload.kind {
                    TaskKind::Rb => parts.rb(m, g),
                    _ => parts.rb_sync(m, g),
                };
                match self.groups.members(b.id, payload.sub % parts.rounds) {
                    // A group's members in id order; each reads only the phase before. Each member's
                    // time on the monotonic clock (tens of nanoseconds a read, where the task's CPU
                    // clock costs a microsecond) shares the group's CPU time among the members.
                    Some(members) if members.len() > 1 => {
                        let nb = sim.blocks.len();
                        let mut t = Instant::now();
                        for &m in members {
                            one(m);
                            let now = Instant::now();
                            let ns = now.duration_since(t).as_nanos() as u64;
                            self.member_ns[payload.step * nb + m].fetch_add(ns, Ordering::Relaxed);
                            t = now;
                        }
                    }
                    _ => one(b.id),
                }
            }
            TaskKind::Map => {
                let parts = sim.particles.as_ref().expect("map tasks only exist with particles");
                if b.fluid_cells == 0 {
                    // `run.no_skip` only: a block without fluid never gets an overlay.
                    coupling::tasks::map_scratch(parts, b, step)
                } else {
                    coupling::tasks::map_task(parts, b, step, self.no_skip)
                }
            }
            TaskKind::Reconstruct => {
                // Reconstruct writes b's field p before anyone reads it this step.
                if b.particle_cells().is_some() {
                    coupling::reconstruct(
                        &sim.domain,
                        b,
                        b.particle_cells_mut(),
                        p,
                        &sim.params,
                        coupling::Rebuild {
                            conserve_momentum: sim.coupling.conserve_momentum,
                            refill: sim.coupling.refill,
                        },
                    )
                }
            }
            TaskKind::Forces => {
                let parts = sim.particles.as_ref().expect("forces tasks only exist with particles");
                coupling::tasks::forces_task(parts, blocks, b.id, step, sim.coupling.force_averaging)
            }
            // Under ranks the message is packed when the task posts it.
            TaskKind::Send if self.ghosts.is_some() => {}
            TaskKind::Send => {
                for o in &self.plan.outgoing[b.id] {
                    let g = &blocks[o.receiver].recv[o.recv];
                    let mut buf = self.plan.slots[o.slot].lock().expect("slot");
                    fluid::pack(b, p, g.offset, &g.directions, &mut buf);
                }
            }
            TaskKind::Comm => {
                for (r, g) in b.recv.iter().enumerate() {
                    match self.plan.slot_of[b.id][r] {
                        Some(_) if self.ghosts.is_some() => self.ghosts.expect("checked").unpack(b, r, payload.step, p),
                        Some(s) => {
                            let buf = self.plan.slots[s].lock().expect("slot");
                            fluid::unpack(b, p, g.offset, &g.directions, &buf)
                        }
                        None if self.no_skip => {
                            fluid::copy_ghost_region(&blocks[g.from], b, p, g.offset, &g.directions)
                        }
                        None => fluid::copy_ghost(&blocks[g.from], b, p, g),
                    }
                }
            }
            TaskKind::StaticMap => b.check_static_geometry(&sim.domain, &sim.geometry),
            TaskKind::Boundary => {
                if self.no_skip {
                    fluid::boundary_general(b, p);
                } else {
                    fluid::boundary(b, p);
                }
                if b.particle_cells().is_some() {
                    // The boundary task is the only user of b's overlay and particle cells now.
                    coupling::boundary(&sim.domain, b, b.particle_cells_mut(), p, surface)
                }
            }
            TaskKind::Sweep => {
                // The graph orders every task touching field 1 - p of this block or writing field p
                // around this sweep.
                let st = if self.no_skip {
                    fluid::stream_collide_general(b, p, &sim.params)
                } else {
                    fluid::stream_collide(b, p, &sim.params, sim.kernel)
                };
                *self.stats[payload.step * blocks.len() + b.id].lock().expect("stats") = st;
            }
        }
    }
}
