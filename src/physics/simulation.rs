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
