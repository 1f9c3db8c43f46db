//! Fluid–particle coupling on a block (section 2.3 of Rettinger & Rüde 2019): mapping of the spheres
//! into cells (Algorithm 5), the CLI / simple bounce-back boundary of eq. (6) at their surfaces with the
//! momentum exchange of eqs. (7)–(9), and the reconstruction of cells that turn from solid to fluid
//! (Algorithm 6). The per-link numerics are the kernels' ([`blockflow_kernels::coupling`]); this module
//! finds the cells and links of a block and sums the forces per body.
//!
//! Geometry is evaluated in a way every block agrees on bit for bit: a cell is addressed by its wrapped
//! global index, a body by its canonical (wrapped) centre, and their offset is taken as the minimum image
//! on periodic axes. So a cell in one block's ghost layer is solid exactly when the same cell is solid in
//! the block that owns it.
//!
//! Static geometry (walls, planes) stays in the block's flags, mapped once; particles live in an overlay
//! ([`ParticleCells`](super::particle_cells::ParticleCells)) that is rebuilt by the `map` task of every step. Fixed bodies alone are mapped
//! once at set-up.
//!
//! Files: [`mapping`] (Algorithm 5), [`mod@reconstruct`] (Algorithm 6), [`surface`] (eq. 6 at particle
//! surfaces and the momentum exchange of eqs. 7–9), [`tasks`] (the coupling tasks of a step and the global
//! force view).

pub mod mapping;
pub mod reconstruct;
pub mod rows;
pub mod surface;
pub mod tasks;

pub use mapping::{map, map_with};
pub use reconstruct::{reconstruct, Rebuild};
pub use surface::boundary;

use crate::physics::domain::DomainSpec;
use glam::DVec3;

/// Minimum-image offset along one axis.
#[inline]
pub(crate) fn min_image(d: f64, len: f64, periodic: bool) -> f64 {
    if periodic {
        if d > 0.5 * len {
            d - len
        } else if d < -0.5 * len {
            d + len
        } else {
            d
        }
    } else {
        d
    }
}

/// Offset of the centre of the cell at full-layout coordinates (x, y, z) of block `b` from `centre`,
/// computed from the wrapped global cell index (the same bits in every block that holds the cell).
#[inline]
pub fn cell_offset(d: &DomainSpec, origin: [usize; 3], xyz: [usize; 3], centre: DVec3) -> DVec3 {
    DVec3::new(
        cell_offset_along(d, origin, 0, xyz[0], centre[0]),
        cell_offset_along(d, origin, 1, xyz[1], centre[1]),
        cell_offset_along(d, origin, 2, xyz[2], centre[2]),
    )
}

/// Component `a` of [`cell_offset`] for the cell at full-layout coordinate `k` along axis `a` (the
/// components are independent: the same bits as the full offset's).
#[inline]
pub fn cell_offset_along(d: &DomainSpec, origin: [usize; 3], a: usize, k: usize, centre: f64) -> f64 {
    let n = d.cells();
    let g = origin[a] as i64 + k as i64 - 1;
    let len = n[a] as i64;
    // Ghost cells lie at most one cell outside the domain: one period wraps them.
    let gw = if !d.periodic[a] || (0..len).contains(&g) {
        g
    } else if g < 0 {
        g + len
    } else {
        g - len
    };
    min_image(gw as f64 + 0.5 - centre, n[a] as f64, d.periodic[a])
}
