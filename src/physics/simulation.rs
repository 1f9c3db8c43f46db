//! The state of a whole run ([`Simulation`]: blocks, fluid parameters, rigid bodies, the static geometry)
//! with its global diagnostics and the checksum over the exact bits of the state, independent of the
//! block layout. The time step itself is the task graph of `pipeline` (and, as the serial reference,
//! [`super::serial`]).

use crate::config::{KernelChoice, Refill, SurfaceBoundary};
use crate::error::Instability;
use crate::physics::block::Block;
use crate::physics::domain::DomainSpec;
use crate::physics::fluid;
use crate::physics::geometry::Geometry;
use blockflow_kernels::d3q19::Q;
use blockflow_kernels::sweep::SweepStats;
use blockflow_kernels::trt::post_collision_equilibrium;
use blockflow_kernels::{Pattern, Real, TrtParams};

/// Global diagnostics of the fluid: per-block partial sums added in block-id order, so they do not
/// depend on who computed which block (virtual process or rank).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Diagnostics {
    /// Σ ρ over fluid cells.
    pub mass: f64,
    /// Σ δρ over fluid cells (the mass deviation, without the rounding of adding 1 per cell).
    pub mass_deviation: f64,
    /// Σ ½ ρ0 |u|² over fluid cells.
    pub kinetic_energy: f64,
    /// Largest |u|.
    pub max_velocity: f64,
    /// Fluid cells summed over.
    pub cells: usize,
}

impl Diagnostics {
    /// The diagnostics of the whole fluid from its blocks' ([`Simulation::block_diagnostics`]), given in
    /// ascending block-id order: Σ δρ, Σ ½|u|² and the cells added block by block, the largest |u|, and
    /// ρ summed as cells + Σ δρ.
    pub fn combine(blocks: impl IntoIterator<Item = Diagnostics>) -> Diagnostics {
        let mut d = Diagnostics::default();
        for b in blocks {
            d.mass_deviation += b.mass_deviation;
            d.kinetic_energy += b.kinetic_energy;
            d.max_velocity = d.max_velocity.max(b.max_velocity);
            d.cells += b.cells;
        }
        d.mass = d.cells as f64 + d.mass_deviation;
        d
    }
}

/// The fluid–particle coupling switches of a run (`[particles]` keys).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CouplingParams {
    /// Boundary condition at particle surfaces (`particles.boundary`).
    pub surface: SurfaceBoundary,
    /// Average the hydrodynamic force over the current and the previous step (`particles.force_averaging`).
    pub force_averaging: bool,
    /// Pass the momentum of covered and uncovered cells to the bodies (`particles.conserve_momentum`).
    pub conserve_momentum: bool,
    /// How uncovered cells are rebuilt (`particles.refill`).
    pub refill: Refill,
}

impl Default for CouplingParams {
    fn default() -> Self {
        CouplingParams {
            surface: SurfaceBoundary::Cli,
            force_averaging: true,
            conserve_momentum: false,
            refill: Refill::Equilibrium,
        }
    }
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
    /// Fluid–particle coupling switches (surface boundary condition, force averaging).
    pub coupling: CouplingParams,
    /// Rigid bodies, if the scene has any.
    pub particles: Option<crate::physics::particles::Particles>,
    /// The static geometry the blocks were built from (kept for `run.no_skip`, which re-derives every
    /// block's flags and links from it each step).
    pub geometry: Geometry,
}

impl<T: Real> Simulation<T> {
    /// Builds all blocks from the geometry (fields streamed by `pattern`), at rest.
    pub fn new(
        domain: DomainSpec,
        geo: &Geometry,
        params: TrtParams,
        velocity_limit: f64,
        kernel: KernelChoice,
        pattern: Pattern,
        coupling: CouplingParams,
    ) -> Self {
        let blocks = (0..domain.num_blocks())
            .map(|id| Block::new(&domain, geo, id, pattern))
            .collect();
        Simulation {
            domain,
            blocks,
            params,
            step: 0,
            velocity_limit,
            kernel,
            coupling,
            particles: None,
            geometry: geo.clone(),
        }
    }

    /// Initialises every fluid cell of the blocks this process holds at (forced) equilibrium with
    /// `state(global cell) = (δρ, u)`.
    pub fn init(&mut self, state: impl Fn([usize; 3]) -> (f64, [f64; 3])) {
        let p = self.params;
        for b in self.blocks.iter_mut().filter(|b| b.is_held()) {
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

    /// Advances the step counter and checks one step's sweep statistics (one per block, in block order).
    pub fn finish_step(&mut self, stats: &[SweepStats]) -> Result<(), Instability> {
        self.step += 1;
        match stats.iter().position(|st| self.is_unstable(st)) {
            Some(id) => Err(self.instability(id, self.step)),
            None => Ok(()),
        }
    }

    /// Whether a sweep's statistics show an unstable block (a non-finite value or |u| above the limit).
    pub fn is_unstable(&self, st: &SweepStats) -> bool {
        let limit2 = self.velocity_limit * self.velocity_limit;
        st.nonfinite || st.max_u2.is_nan() || st.max_u2 > limit2
    }

    /// The report of an instability the detector found in block `id` (held by this process) at `step`:
    /// the first bad cell of the current state with its density and velocity.
    pub fn instability(&self, id: usize, step: u64) -> Instability {
        let b = &self.blocks[id];
        let (cell, r, u) = fluid::find_bad_cell(b, self.parity(), self.velocity_limit, self.params.force).unwrap_or((
            b.origin,
            f64::NAN,
            [f64::NAN; 3],
        ));
        Instability {
            step,
            block: id,
            block_coords: b.coords,
            cell,
            density: 1.0 + r,
            velocity: u,
            limit: self.velocity_limit,
        }
    }

    /// Calls `visit(global cell, δρ, u)` for every fluid cell of the blocks this process holds, blocks in
    /// id order.
    pub fn for_each_fluid(&self, mut visit: impl FnMut([usize; 3], f64, [f64; 3])) {
        for b in self.blocks.iter().filter(|b| b.is_held()) {
            self.for_each_fluid_of(b.id, &mut visit);
        }
    }

    /// Calls `visit(global cell, δρ, u)` for every fluid cell of block `b` (held by this process), in
    /// x-fastest order.
    pub fn for_each_fluid_of(&self, b: usize, visit: impl FnMut([usize; 3], f64, [f64; 3])) {
        let force = self.params.force;
        let p = self.parity();
        fluid::for_each_fluid_moments(&self.blocks[b], p, force, visit);
    }

    /// The partial sums of block `b` (held by this process) for [`Diagnostics::combine`]: Σ δρ, Σ ½|u|²,
    /// the largest |u| and the cells, over its fluid cells in x-fastest order.
    pub fn block_diagnostics(&self, b: usize) -> Diagnostics {
        let mut d = Diagnostics::default();
        self.for_each_fluid_of(b, |_, r, u| {
            let u2 = u[0] * u[0] + u[1] * u[1] + u[2] * u[2];
            d.mass_deviation += r;
            d.kinetic_energy += 0.5 * u2;
            d.max_velocity = d.max_velocity.max(u2.sqrt());
            d.cells += 1;
        });
        d.mass = d.cells as f64 + d.mass_deviation;
        d
    }

    /// Mass, kinetic energy and the largest velocity of the fluid of the blocks this process holds (all
    /// of them but under ranks): per-block partial sums combined in block-id order.
    pub fn diagnostics(&self) -> Diagnostics {
        self.diagnostics_on(1)
    }

    /// [`Simulation::diagnostics`] computed by `threads` threads, each summing a contiguous range of the
    /// held blocks: the per-block sums are combined in block-id order as before, so the result has the
    /// same bits for any thread count.
    pub fn diagnostics_on(&self, threads: usize) -> Diagnostics {
        let held: Vec<usize> = self.blocks.iter().filter(|b| b.is_held()).map(|b| b.id).collect();
        let threads = threads.clamp(1, held.len().max(1));
        if threads == 1 {
            return Diagnostics::combine(held.iter().map(|&b| self.block_diagnostics(b)));
        }
        let per: Vec<Diagnostics> = std::thread::scope(|s| {
            let chunk = held.len().div_ceil(threads);
            let parts: Vec<_> = held
                .chunks(chunk)
                .map(|ids| s.spawn(move || ids.iter().map(|&b| self.block_diagnostics(b)).collect::<Vec<_>>()))
                .collect();
            parts
                .into_iter()
                .flat_map(|h| h.join().expect("a diagnostics thread panicked"))
                .collect()
        });
        Diagnostics::combine(per)
    }

    /// A hash of the exact bits of every fluid cell's 19 PDFs of the blocks this process holds (all but
    /// under ranks), keyed by global cell index and combined by wrapping addition: identical for any block
    /// decomposition, process count or traversal order, and the sum of the ranks' hashes under ranks.
    pub fn checksum(&self) -> u64 {
        let n = self.domain.cells();
        let p = self.parity();
        let mut sum = 0u64;
        for b in self.blocks.iter().filter(|b| b.is_held()) {
            let (f, sl) = (b.field(p), b.slots(p));
            b.for_each_fluid(|g, i| {
                let mut h = crate::util::hash::mix(0x5bd1_e995 ^ (g[0] + n[0] * (g[1] + n[1] * g[2])) as u64);
                for q in 0..Q {
                    h = crate::util::hash::mix(h ^ f.data()[sl.at(q, i)].bits());
                }
                sum = sum.wrapping_add(h);
            });
        }
        sum
    }
}
