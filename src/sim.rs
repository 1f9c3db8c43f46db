//! The fluid simulation state and its time step over all blocks, plus global diagnostics and the
//! layout-independent checksum. (The scheduler issue replaces the serial block loop by the task graph;
//! the per-block stages in [`crate::fluid`] stay as they are.)

use crate::block::Block;
use crate::config::KernelChoice;
use crate::domain::DomainSpec;
use crate::error::Instability;
use crate::fluid;
use crate::geometry::Geometry;
use blockflow_kernels::d3q19::Q;
use blockflow_kernels::sweep::SweepStats;
use blockflow_kernels::trt::post_collision_equilibrium;
use blockflow_kernels::{Real, TrtParams};
use std::time::Instant;

/// Seconds spent per part of the step (wall time of the serial loop).
#[derive(Clone, Copy, Debug, Default)]
pub struct PartTimes {
    /// Stream + collide (the fused kernel or both split sweeps).
    pub lbm: f64,
    /// Boundary passes.
    pub boundary: f64,
    /// Ghost exchange.
    pub exchange: f64,
}

/// Work done per step, for the skip rule's bookkeeping.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StepWork {
    /// Blocks that ran the fluid sweep (blocks without fluid are skipped).
    pub sweeps: usize,
    /// Blocks that ran a boundary pass (blocks without near-boundary cells are skipped).
    pub boundary_passes: usize,
    /// Ghost regions exchanged.
    pub messages: usize,
}

/// Global diagnostics of the fluid (sums in block order, so they do not depend on who computed what).
#[derive(Clone, Copy, Debug, Default)]
pub struct Diagnostics {
    /// Σ ρ over fluid cells.
    pub mass: f64,
    /// Σ δρ over fluid cells (the mass deviation, without the rounding of adding 1 per cell).
    pub mass_deviation: f64,
    /// Σ ½ ρ0 |u|² over fluid cells.
    pub kinetic_energy: f64,
    /// Largest |u|.
    pub max_velocity: f64,
}

/// The fluid of a whole domain.
pub struct Simulation<T: Real> {
    /// Block decomposition.
    pub domain: DomainSpec,
    /// Blocks in id order.
    pub blocks: Vec<Block<T>>,
    /// Collision parameters (τ, Λ, body force).
    pub params: TrtParams,
    /// Steps taken.
    pub step: u64,
    /// |u| limit of the instability detector.
    pub velocity_limit: f64,
    /// Fused or split kernels.
    pub kernel: KernelChoice,
    /// Accumulated part timings.
    pub times: PartTimes,
    /// Work of the last step.
    pub work: StepWork,
    /// Rigid bodies, if the scene has any.
    pub particles: Option<crate::particles::Particles>,
    /// The static geometry the blocks were built from (kept for `run.no_skip`, which re-derives every
    /// block's flags and links from it each step).
    pub geometry: Geometry,
}

impl<T: Real> Simulation<T> {
    /// Builds all blocks from the geometry, at rest.
    pub fn new(
        domain: DomainSpec,
        geo: &Geometry,
        params: TrtParams,
        velocity_limit: f64,
        kernel: KernelChoice,
    ) -> Self {
        let blocks = (0..domain.num_blocks())
            .map(|id| Block::new(&domain, geo, id))
            .collect();
        Simulation {
            domain,
            blocks,
            params,
            step: 0,
            velocity_limit,
            kernel,
            times: PartTimes::default(),
            work: StepWork::default(),
            particles: None,
            geometry: geo.clone(),
        }
    }

    /// Initialises every fluid cell at (forced) equilibrium with `state(global cell) = (δρ, u)`.
    pub fn init(&mut self, state: impl Fn([usize; 3]) -> (f64, [f64; 3])) {
        let p = self.params;
        for b in &mut self.blocks {
            b.init(|g| {
                let (r, u) = state(g);
                post_collision_equilibrium(r, u, &p)
            });
        }
    }

    /// Interior fluid cells of the whole domain.
    pub fn fluid_cells(&self) -> usize {
        self.blocks.iter().map(|b| b.fluid_cells).sum()
    }

    /// Parity of the field holding the current state.
    pub fn parity(&self) -> usize {
        (self.step % 2) as usize
    }

    /// One time step over all blocks in a plain serial loop (the reference the task-graph pipeline is
    /// tested and benchmarked against): exchange, boundary, stream + collide. Stops with the location of
    /// the first unstable cell (lowest block id) if the detector fires.
    pub fn step(&mut self) -> Result<(), Instability> {
        let p = self.parity();
        let mut work = StepWork::default();
        let t0 = Instant::now();
        for b in &self.blocks {
            for r in &b.recv {
                fluid::copy_ghost(&self.blocks[r.from], b, p, r.offset, &r.directions);
                work.messages += 1;
            }
        }
        let t1 = Instant::now();
        let mut tb = 0.0;
        let mut tl = 0.0;
        let mut stats = Vec::with_capacity(self.blocks.len());
        for b in &self.blocks {
            if b.fluid_cells == 0 {
                stats.push(SweepStats::default());
                continue;
            }
            let s0 = Instant::now();
            if !b.links.is_empty() {
                fluid::boundary(b, p);
                work.boundary_passes += 1;
            }
            let s1 = Instant::now();
            // SAFETY: serial loop: nothing else touches the block.
            stats.push(unsafe { fluid::stream_collide(b, p, &self.params, self.kernel) });
            work.sweeps += 1;
            tb += (s1 - s0).as_secs_f64();
            tl += s1.elapsed().as_secs_f64();
        }
        self.times.exchange += (t1 - t0).as_secs_f64();
        self.times.boundary += tb;
        self.times.lbm += tl;
        self.work = work;
        self.finish_step(&stats)
    }

    /// Advances the step counter and checks one step's sweep statistics (one per block, in block order).
    pub fn finish_step(&mut self, stats: &[SweepStats]) -> Result<(), Instability> {
        self.step += 1;
        let limit2 = self.velocity_limit * self.velocity_limit;
        let bad = stats
            .iter()
            .position(|st| st.nonfinite || st.max_u2.is_nan() || st.max_u2 > limit2);
        if let Some(id) = bad {
            let b = &self.blocks[id];
            let (cell, r, u) = fluid::find_bad_cell(b, self.parity(), self.velocity_limit, self.params.force)
                .unwrap_or((b.origin, f64::NAN, [f64::NAN; 3]));
            return Err(Instability {
                step: self.step,
                block: id,
                block_coords: b.coords,
                cell,
                density: 1.0 + r,
                velocity: u,
                limit: self.velocity_limit,
            });
        }
        Ok(())
    }

    /// Calls `visit(global cell, δρ, u)` for every fluid cell, blocks in id order.
    pub fn for_each_fluid(&self, mut visit: impl FnMut([usize; 3], f64, [f64; 3])) {
        let force = self.params.force;
        let p = self.parity();
        for b in &self.blocks {
            b.for_each_fluid(|g, i| {
                let (r, u) = fluid::cell_moments(b, p, i, force);
                visit(g, r, u);
            });
        }
    }

    /// Mass, kinetic energy and the largest velocity.
    pub fn diagnostics(&self) -> Diagnostics {
        let mut d = Diagnostics::default();
        let mut cells = 0usize;
        self.for_each_fluid(|_, r, u| {
            let u2 = u[0] * u[0] + u[1] * u[1] + u[2] * u[2];
            d.mass_deviation += r;
            d.kinetic_energy += 0.5 * u2;
            d.max_velocity = d.max_velocity.max(u2.sqrt());
            cells += 1;
        });
        d.mass = cells as f64 + d.mass_deviation;
        d
    }

    /// A hash of the exact bits of every fluid cell's 19 PDFs, keyed by global cell index and combined by
    /// wrapping addition: identical for any block decomposition, process count or traversal order.
    pub fn checksum(&self) -> u64 {
        let n = self.domain.cells();
        let p = self.parity();
        let mut sum = 0u64;
        for b in &self.blocks {
            let f = b.field(p);
            b.for_each_fluid(|g, i| {
                let mut h = mix(0x5bd1_e995 ^ (g[0] + n[0] * (g[1] + n[1] * g[2])) as u64);
                for q in 0..Q {
                    h = mix(h ^ f.get(q, i).bits());
                }
                sum = sum.wrapping_add(h);
            });
        }
        sum
    }
}

/// SplitMix64 finaliser: a strong 64-bit mixing function.
pub fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}
