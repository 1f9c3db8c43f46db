//! The physical state of a run and the per-block stages of a time step: the block grid ([`domain`]), the
//! static geometry voxelised into cell flags ([`geometry`]), one block's fluid state ([`block`]) and its
//! particle overlay ([`particle_cells`]), the fluid stages of a step ([`fluid`]: exchange, boundary,
//! stream + collide), the rigid bodies ([`particles`]) and the fluid–particle coupling ([`coupling`]),
//! all held by [`simulation::Simulation`]; [`parts`] names the parts of a step (Algorithm 1) every timer
//! uses; [`serial`] is the plain serial time step the task graph is tested against.
//!
//! The state of one block lives with the concern that owns it, structure-of-arrays style, indexed by
//! block id everywhere:
//!
//! | state of block `b` | where |
//! |---|---|
//! | PDF fields, flags, fluid runs, wall links, ghost regions to receive | `sim.blocks[b]` ([`block::Block`]) |
//! | particle overlay (owners, links, forces) | `sim.blocks[b].particle_cells()` |
//! | local bodies, shadows, velocity changes, planes, neighbours | `sim.particles.blocks[b]` ([`particles::BlockBodies`]) |
//! | whether `b` has rigid-body tasks in the current graph | `sim.particles.active[b]` |
//! | owner process | the pipeline's owners (never read by the numerics) |
//!
//! Nothing here knows about threads, processes or the task graph: every function works on one block (and,
//! for exchanges and forces, the blocks around it), so the results do not depend on who runs it.

pub mod block;
pub mod coupling;
pub mod domain;
pub mod fluid;
pub mod geometry;
pub mod particle_cells;
pub mod particles;
pub mod parts;
pub mod serial;
pub mod simulation;
