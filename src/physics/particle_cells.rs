//! The particle overlay of a block ([`ParticleCells`]): which cells the spheres cover this step, the fluid
//! runs and cell counts that leaves, the links from fluid cells into particle cells with their δ_q, the
//! cells that changed state, and the per-body force partial sums of the block's links. Written by the
//! mapping, reconstruction and surface-boundary stages of [`super::coupling`]; held by [`super::block::Block`].

use super::coupling::rows::CellBits;
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

/// A fluid cell with links into particle cells: bit q of `dirs` (q = 1..18) is set when the cell at
/// x_f + c_q is covered by a body. The surface boundary pass derives each link's body, δ_q and second
/// cell from the cell, the direction and the mapped bodies.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LinkCell {
    /// Element index of the fluid cell x_f.
    pub cell: u32,
    /// Directions with a link, one bit per q.
    pub dirs: u32,
    /// Directions q of `dirs` whose second cell x_f − c_q is fluid now (static fluid, not covered): the
    /// links where the CLI of eq. (6) has its interpolation partner; one bit per q.
    pub second_fluid: u32,
    /// Ghost-inclusive coordinates of the cell (`Layout::coords` of `cell`).
    pub xyz: [u32; 3],
}

/// What the mapping derives once from a block's static geometry: fluid and near-wall cells as bit rows,
/// and where each interior row's static fluid runs start in the block's segment list.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct StaticRows {
    /// Static fluid cells.
    pub fluid: CellBits,
    /// Static fluid cells next to a wall (NEAR_BOUNDARY).
    pub near_wall: CellBits,
    /// Index of the first static segment of interior row (y, z) in `Block::segments`, row
    /// `(y − 1) + (fy − 2)(z − 1)`, plus one entry past the last row.
    pub row_segments: Vec<u32>,
}

/// Where each interior row's part of the mapping's lists starts, so that a row whose neighbourhood did
/// not change can be copied from the previous mapping instead of derived again. Rows are numbered
/// `(y − 1) + (fy − 2)(z − 1)`; each start vector has one entry past the last row.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RowIndex {
    /// Whether the index describes the overlay's current lists.
    pub valid: bool,
    /// First entry of each row in [`ParticleCells::segments`].
    pub segments: Vec<u32>,
    /// First entry of each row in [`ParticleCells::link_cells`].
    pub link_cells: Vec<u32>,
    /// Per row: fluid cells, near-boundary cells, cells with a particle link.
    pub counts: Vec<[u32; 3]>,
}

/// Buffers of the mapping's lists, kept between mappings so that a step allocates nothing.
#[derive(Clone, Debug, Default)]
pub(crate) struct SpareLists {
    pub segments: Vec<Segment>,
    pub link_cells: Vec<LinkCell>,
    pub index: RowIndex,
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

/// What the last mapping of a block did (regressors of the workload estimator's mapping part; no
/// effect on the overlay).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MapWork {
    /// Whether the mapping ran beyond its fast path (a body was near before or is near now).
    pub active: bool,
    /// Cells of the bodies' bounding boxes visited while writing owners (every periodic image).
    pub box_cells: u64,
    /// Interior rows derived again (the others were copied from the previous mapping).
    pub rows_derived: u64,
}

/// Exponential averages, over the mappings of a block, of the mapping's work counters that jump from
/// step to step (a sphere crossing a cell plane turns and covers a whole cap of cells at once): what
/// the workload estimator weighs a block by when it balances, so that one step's jump does not decide
/// where a block goes for the next interval. Each mapping moves every average by
/// [`MapAverage::WEIGHT`] of the way to its own counts; the first sets them. Working memory of the
/// balancer only: the block's bytes (migration between ranks, checkpoints) do not carry it, so after a
/// restart or a move between ranks the averages start again from the next mapping.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MapAverage {
    /// Whether a mapping has set the averages.
    pub started: bool,
    /// Bodies mapped.
    pub bodies: f64,
    /// Bounding-box cells visited.
    pub box_cells: f64,
    /// Rows derived again.
    pub rows_derived: f64,
    /// Cells turned fluid.
    pub turned: f64,
    /// Cells covered.
    pub covered: f64,
}

impl MapAverage {
    /// The weight of the newest mapping (an average over about 2 / WEIGHT − 1 = 15 steps).
    pub const WEIGHT: f64 = 0.125;

    /// The counts in the order of the fields.
    pub fn as_array(&self) -> [f64; 5] {
        [
            self.bodies,
            self.box_cells,
            self.rows_derived,
            self.turned,
            self.covered,
        ]
    }

    /// Folds one mapping's counts (in the order of [`MapAverage::as_array`]) into the averages.
    pub fn update(&mut self, counts: [f64; 5]) {
        let [bodies, box_cells, rows_derived, turned, covered] = if self.started {
            let old = self.as_array();
            std::array::from_fn(|i| old[i] + Self::WEIGHT * (counts[i] - old[i]))
        } else {
            counts
        };
        *self = MapAverage {
            started: true,
            bodies,
            box_cells,
            rows_derived,
            turned,
            covered,
        };
    }
}

/// The particle overlay of one block.
#[derive(Clone, Debug, Default)]
pub struct ParticleCells {
    /// Id + 1 of the body covering each cell (ghost layer included); 0: none.
    pub owner: Vec<u64>,
    /// The previous mapping's buffer, reused.
    pub(crate) owner_spare: Vec<u64>,
    /// Scratch: the cells of `owner` that are covered, as bit rows (empty: not derived yet).
    pub(crate) occupied: CellBits,
    /// The previous mapping's bit rows, reused.
    pub(crate) occupied_spare: CellBits,
    /// Scratch: the block's static rows (derived on first use).
    pub(crate) statics: StaticRows,
    /// Scratch: where each row's entries of the lists start (kept from one mapping to the next).
    pub(crate) row_index: RowIndex,
    /// Scratch of the surface boundary pass: a batch of links.
    pub(crate) link_batch: Box<blockflow_kernels::link_batch::LinkBatch>,
    /// The previous mapping's lists and row index, reused as buffers.
    pub(crate) spare: SpareLists,
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
    /// The fluid cells with links into particle cells, in cell order.
    pub link_cells: Vec<LinkCell>,
    /// Interior cells that turned from solid to fluid in this step, with the id of the body that left.
    pub turned: Vec<(usize, u64)>,
    /// Interior cells that a body covered in this step (fluid to solid), with its id.
    pub covered: Vec<(usize, u64)>,
    /// Momentum the covered and reconstructed cells exchanged with each body in this step (the fluid
    /// momentum a body swallows, minus what a rebuilt cell receives), sorted by id; added to the force.
    pub exchanged: Vec<BodyForce>,
    /// Forces of the last boundary pass, sorted by id.
    pub forces: Vec<BodyForce>,
    /// What the last mapping did.
    pub map_work: MapWork,
    /// What the mappings did, averaged over the recent ones.
    pub map_average: MapAverage,
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
