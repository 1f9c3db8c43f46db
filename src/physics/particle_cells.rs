//! The particle overlay of a block ([`ParticleCells`]): which cells the spheres cover this step, the fluid
//! runs and cell counts that leaves, the links from fluid cells into particle cells with their δ_q, the
//! cells that changed state, and the per-body force partial sums of the block's links. Written by the
//! mapping, reconstruction and surface-boundary stages of [`super::coupling`]; held by [`super::block::Block`].

use blockflow_kernels::sweep::Segment;
use glam::DVec3;

/// What the mapping needs of a body.
#[derive(Clone, Copy, Debug)]
pub struct MapBody {
    /// Body id.
    pub id: u64,
    /// Canonical centre X.
    pub position: DVec3,
    /// Translational velocity V.
    pub velocity: DVec3,
    /// Angular velocity W.
    pub angular_velocity: DVec3,
    /// Radius.
    pub radius: f64,
}

/// A fluid cell's link into a particle cell.
#[derive(Clone, Copy, Debug)]
pub struct ParticleLink {
    /// Element index of the fluid cell x_f.
    pub fluid: usize,
    /// Outgoing direction q (c_q points into the body).
    pub q: u8,
    /// Index of the body in [`ParticleCells::bodies`].
    pub body: u32,
    /// δ_q in (0, 1] (1/2 for simple bounce-back).
    pub delta: f64,
    /// Element index of the second fluid cell x_f − c_q for CLI; `None`: simple bounce-back.
    pub second: Option<usize>,
    /// Offset x_f − X of the fluid cell centre from the body centre (minimum image).
    pub rel: DVec3,
}

/// Hydrodynamic force and torque the block's links put on one body.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BodyForce {
    /// Body id.
    pub id: u64,
    /// Force, eq. (8) restricted to this block's links.
    pub force: DVec3,
    /// Torque, eq. (9) restricted to this block's links.
    pub torque: DVec3,
}

/// The particle overlay of one block.
#[derive(Clone, Debug, Default)]
pub struct ParticleCells {
    /// Id + 1 of the body covering each cell (ghost layer included); 0: none.
    pub owner: Vec<u64>,
    /// The previous mapping's buffer, reused.
    pub(crate) owner_spare: Vec<u64>,
    /// Scratch: cells next to a particle cell.
    pub(crate) mark: Vec<bool>,
    /// Whether any cell of `owner` is covered.
    pub(crate) owned: bool,
    /// Runs of interior cells that are fluid now (static fluid and not covered by a body).
    pub segments: Vec<Segment>,
    /// Interior fluid cells now.
    pub fluid_cells: usize,
    /// Interior fluid cells with at least one particle link.
    pub near_particle_cells: usize,
    /// Interior fluid cells next to a wall or a particle (NB of Table 1).
    pub near_boundary_cells: usize,
    /// The bodies mapped in this step (locals and shadows), sorted by id.
    pub bodies: Vec<MapBody>,
    /// Links from fluid cells into particle cells, in cell order.
    pub links: Vec<ParticleLink>,
    /// Interior cells that turned from solid to fluid in this step, with the id of the body that left.
    pub turned: Vec<(usize, u64)>,
    /// Interior cells that a body covered in this step (fluid to solid), with its id.
    pub covered: Vec<(usize, u64)>,
    /// Momentum the covered and reconstructed cells exchanged with each body in this step (the fluid
    /// momentum a body swallows, minus what a rebuilt cell receives), sorted by id; added to the force.
    pub exchanged: Vec<BodyForce>,
    /// Forces of the last boundary pass, sorted by id.
    pub forces: Vec<BodyForce>,
}

impl ParticleCells {
    /// Whether any cell of `owner` was covered by the last mapping (the mapping's fast path for blocks
    /// with no body near depends on it).
    pub fn owned(&self) -> bool {
        self.owned
    }

    /// Sets [`ParticleCells::owned`] (for rebuilding an overlay from its serialised form; it must agree
    /// with `owner`).
    pub fn set_owned(&mut self, owned: bool) {
        self.owned = owned;
    }
}
