//! Mapping (Algorithm 5): the spheres near a block into its overlay: cell owners, the fluid runs that
//! leave, the cells that changed state since the previous mapping, and the fluid cells with links into
//! particle cells (their directions; δ_q is the surface boundary pass's).
//!
//! The owners are written body by body over each sphere's bounding box; everything else is derived row
//! by row from bit rows ([`CellBits`]): fluid now = static fluid and not covered, a row without covered
//! cells keeps its static runs, and the cells with a covered neighbour in direction q are the covered
//! bits of the neighbouring row shifted by c_q. The result is the same overlay, cell for cell and in the
//! same order, as a cell-by-cell scan.

use super::cell_offset_along;
use super::rows::{bit_cells, interior_mask, CellBits};
use crate::physics::block::Block;
use crate::physics::domain::DomainSpec;
use crate::physics::geometry::flags;
use crate::physics::particle_cells::{LinkCell, MapBody, MapWork, ParticleCells, RowIndex, StaticRows};
use blockflow_kernels::d3q19::{C, Q};
use blockflow_kernels::sweep::Segment;
use blockflow_kernels::Real;

/// Maps `bodies` (sorted by id, canonical centres) into block `b`'s overlay (Algorithm 5): owners of
/// every static fluid cell a sphere covers (the higher id wins where two overlap), fluid segments, the
/// link cells and the cells that turned from solid to fluid or were covered since the previous mapping.
pub fn map<T: Real>(d: &DomainSpec, b: &Block<T>, pc: &mut ParticleCells, bodies: Vec<MapBody>) {
    map_with(d, b, pc, bodies, true)
}

/// [`map`] with its shortcuts switched on or off: the fast path for a block with no body near (before
/// or now), and taking the rows whose neighbourhood no body entered or left from the previous mapping
/// (all of its lists as they are when no covered cell changed). With `shortcuts = false`
/// (`run.no_skip`) every row of every block is derived again, which gives the same overlay.
pub fn map_with<T: Real>(d: &DomainSpec, b: &Block<T>, pc: &mut ParticleCells, bodies: Vec<MapBody>, shortcuts: bool) {
    map_overlay(d, b, pc, bodies, shortcuts);
    let w = pc.map_work;
    let counts = [
        pc.bodies.len() as f64,
        w.box_cells as f64,
        w.rows_derived as f64,
        pc.turned.len() as f64,
        pc.covered.len() as f64,
    ];
    pc.map_average.update(counts);
}

/// The overlay of [`map_with`], without the averages of its work.
fn map_overlay<T: Real>(d: &DomainSpec, b: &Block<T>, pc: &mut ParticleCells, bodies: Vec<MapBody>, shortcuts: bool) {
    let l = b.layout;
    let full = l.full();
    // Cells of the block with its ghost layer (element indices run below the field's stride).
    let n = l.slots();
    if shortcuts && bodies.is_empty() && !pc.owned && pc.owner.len() == n {
        // No body near before or now: the static cells are the state; nothing to rebuild or reconstruct.
        if pc.segments.len() != b.segments.len() || pc.fluid_cells != b.fluid_cells {
            pc.segments = b.segments.clone();
        }
        pc.fluid_cells = b.fluid_cells;
        pc.near_boundary_cells = b.near_boundary_cells;
        pc.near_particle_cells = 0;
        pc.link_cells.clear();
        pc.turned.clear();
        pc.covered.clear();
        pc.bodies.clear();
        pc.row_index.valid = false;
        pc.map_work = MapWork::default();
        return;
    }
    if !pc.statics.fluid.fits(full) {
        pc.statics = static_rows(b);
        pc.row_index.valid = false;
    }
    let old = std::mem::take(&mut pc.owner);
    let first = old.len() != n;
    // The previous mapping's covered cells as bit rows (derived from the owners after a decode).
    let mut old_occ = std::mem::take(&mut pc.occupied);
    if !first && !old_occ.fits(full) {
        old_occ = occupied_of(&old, &l, full);
    }
    let mut owner = std::mem::take(&mut pc.owner_spare);
    owner.clear();
    owner.resize(n, 0);
    let mut occ = std::mem::take(&mut pc.occupied_spare);
    if occ.fits(full) {
        occ.clear();
    } else {
        occ = CellBits::new(full);
    }
    let mut box_cells = 0;
    let mut scratch = FillScratch::default();
    for body in &bodies {
        box_cells += fill_sphere(d, b, &pc.statics, body, &mut owner, &mut occ, &mut scratch);
    }
    pc.owner = owner;
    pc.owned = occ.any();
    let rows_derived = rows(b, pc, &old, if first { None } else { Some(&old_occ) }, &occ, shortcuts);
    pc.map_work = MapWork {
        active: true,
        box_cells,
        rows_derived,
    };
    pc.occupied = occ;
    pc.bodies = bodies;
    let mut spare = old;
    spare.clear();
    pc.owner_spare = spare;
    pc.occupied_spare = old_occ;
}

/// Per-axis offsets of a sphere's bounding-box cells from its centre, kept between the bodies of one
/// mapping.
#[derive(Default)]
struct FillScratch {
    /// x offsets of the box's cells.
    ox: Vec<f64>,
    /// Their squares.
    ox2: Vec<f64>,
    /// y offsets.
    oy: Vec<f64>,
}

/// Writes `body` into the owners of every static fluid cell (`statics.fluid`) its sphere covers (any
/// periodic image whose bounding box meets the block with its ghost layer); returns the number of
/// bounding-box cells visited.
fn fill_sphere<T: Real>(
    d: &DomainSpec,
    b: &Block<T>,
    statics: &StaticRows,
    body: &MapBody,
    owner: &mut [u64],
    occ: &mut CellBits,
    scratch: &mut FillScratch,
) -> u64 {
    let l = b.layout;
    let cells = d.cells();
    let mut visited = 0u64;
    let mut ranges = [[(0i64, -1i64); 3]; 3];
    for a in 0..3 {
        let shifts: &[f64] = if d.periodic[a] { &[-1.0, 0.0, 1.0] } else { &[0.0] };
        for (k, s) in shifts.iter().enumerate() {
            let x = body.position[a] + s * cells[a] as f64;
            let lo = ((x - body.radius - 0.5).floor() as i64 - b.origin[a] as i64 + 1).max(0);
            let hi = ((x + body.radius - 0.5).ceil() as i64 - b.origin[a] as i64 + 1).min(l.full()[a] as i64 - 1);
            ranges[a][k] = (lo, hi);
        }
    }
    let r2 = body.radius * body.radius;
    // The offset is separable per axis: compute each axis once (same bits as cell_offset).
    let axis = |a: usize, k: i64| cell_offset_along(d, b.origin, a, k as usize, body.position[a]);
    let FillScratch { ox, ox2, oy } = scratch;
    let id1 = body.id + 1;
    for rz in ranges[2].iter().filter(|r| r.0 <= r.1) {
        for ry in ranges[1].iter().filter(|r| r.0 <= r.1) {
            for rx in ranges[0].iter().filter(|r| r.0 <= r.1) {
                visited += ((rx.1 - rx.0 + 1) * (ry.1 - ry.0 + 1) * (rz.1 - rz.0 + 1)) as u64;
                ox.clear();
                ox.extend((rx.0..=rx.1).map(|k| axis(0, k)));
                ox2.clear();
                ox2.extend(ox.iter().map(|o| o * o));
                // Along one image's range the offset grows with x, so the cells of a row inside the
                // sphere (ox² + oy² + oz² ≤ R²) are one run around the smallest |ox|: found from there
                // with the same test at its two ends. (A sphere wider than half the domain could wrap
                // within the range: then every cell is tested.)
                let monotone = ox.windows(2).all(|w| w[0] < w[1]);
                let centre = (0..ox2.len()).fold(0, |m, j| if ox2[j] < ox2[m] { j } else { m });
                oy.clear();
                oy.extend((ry.0..=ry.1).map(|k| axis(1, k)));
                for z in rz.0..=rz.1 {
                    let oz = axis(2, z);
                    for (jy, y) in (ry.0..=ry.1).enumerate() {
                        let yz = oy[jy] * oy[jy] + oz * oz;
                        if yz > r2 {
                            continue;
                        }
                        let (y, z) = (y as usize, z as usize);
                        let inside = |j: usize| ox2[j] + yz <= r2;
                        let run = if !monotone {
                            None
                        } else if !inside(centre) {
                            continue;
                        } else {
                            let (mut lo, mut hi) = (centre, centre);
                            while lo > 0 && inside(lo - 1) {
                                lo -= 1;
                            }
                            while hi + 1 < ox2.len() && inside(hi + 1) {
                                hi += 1;
                            }
                            Some((lo, hi))
                        };
                        let row = l.idx(0, y, z);
                        let fluid = statics.fluid.row(y, z);
                        let bits = occ.row_mut(y, z);
                        let x0 = rx.0 as usize;
                        // Branch-free inside the run: whether a cell is static fluid is as good as random
                        // to a predictor. The row's bits gather in `acc` and go to memory once per word.
                        let (lo, hi) = run.unwrap_or((0, ox2.len() - 1));
                        let (mut acc, mut w) = (0u64, (x0 + lo) / 64);
                        for j in lo..=hi {
                            let x = x0 + j;
                            let on = (fluid[x / 64] >> (x % 64)) & 1 != 0 && (run.is_some() || inside(j));
                            owner[row + x] = if on { id1 } else { owner[row + x] };
                            if x / 64 != w {
                                bits[w] |= acc;
                                (acc, w) = (0, x / 64);
                            }
                            acc |= (on as u64) << (x % 64);
                        }
                        bits[w] |= acc;
                    }
                }
            }
        }
    }
    visited
}

/// Sets [`LinkCell::second_fluid`] of every link cell of `pc` from its owners and the block's flags: what
/// the mapping derives from bit rows, for an overlay read back from bytes.
pub fn derive_second_fluid<T: Real>(b: &Block<T>, pc: &mut ParticleCells) {
    let l = b.layout;
    let owner = &pc.owner;
    let fluid_now = |i: usize| b.flags[i] & flags::FLUID != 0 && owner.get(i).is_none_or(|&o| o == 0);
    for lc in pc.link_cells.iter_mut() {
        let mut dirs = lc.dirs;
        let mut second = 0;
        while dirs != 0 {
            let q = dirs.trailing_zeros() as usize;
            dirs &= dirs - 1;
            if fluid_now((lc.cell as isize - l.offset(C[q])) as usize) {
                second |= 1 << q;
            }
        }
        lc.second_fluid = second;
    }
}

/// The covered cells of an owner array as bit rows.
fn occupied_of(owner: &[u64], l: &blockflow_kernels::Layout, full: [usize; 3]) -> CellBits {
    let mut occ = CellBits::new(full);
    for z in 0..full[2] {
        for y in 0..full[1] {
            for x in 0..full[0] {
                if owner[l.idx(x, y, z)] != 0 {
                    occ.set(x, y, z);
                }
            }
        }
    }
    occ
}

/// The static rows of a block: fluid and near-wall cells, and the start of every interior row's static
/// runs in `b.segments`.
fn static_rows<T: Real>(b: &Block<T>) -> StaticRows {
    let l = b.layout;
    let full = l.full();
    let mut fluid = CellBits::new(full);
    let mut near_wall = CellBits::new(full);
    for z in 0..full[2] {
        for y in 0..full[1] {
            for x in 0..full[0] {
                let f = b.flags[l.idx(x, y, z)];
                if f & flags::FLUID != 0 {
                    fluid.set(x, y, z);
                    if f & flags::NEAR_BOUNDARY != 0 {
                        near_wall.set(x, y, z);
                    }
                }
            }
        }
    }
    let rows = (full[1] - 2) * (full[2] - 2);
    let mut row_segments = Vec::with_capacity(rows + 1);
    let mut k = 0;
    for z in 1..full[2] - 1 {
        for y in 1..full[1] - 1 {
            let first = l.idx(1, y, z);
            while k < b.segments.len() && b.segments[k].start < first {
                k += 1;
            }
            row_segments.push(k as u32);
        }
    }
    row_segments.push(b.segments.len() as u32);
    StaticRows {
        fluid,
        near_wall,
        row_segments,
    }
}

/// Everything the mapping derives row by row from the new covered cells `occ` (and the previous ones,
/// `old_occ`, with their owners `old`; `None` on a block's first mapping): fluid runs and counts, the
/// covered and turned cells, the link cells and the near-boundary counts (NB of Table 1).
///
/// A row's results depend only on the covered cells of the row and of its eight neighbour rows (in y
/// and z; x shifts stay inside a row). With `reuse`, a row whose neighbourhood is covered as in the
/// previous mapping takes its entries from the previous lists, found through the row index. Returns
/// the number of rows derived (not copied).
fn rows<T: Real>(
    b: &Block<T>,
    pc: &mut ParticleCells,
    old: &[u64],
    old_occ: Option<&CellBits>,
    occ: &CellBits,
    reuse: bool,
) -> u64 {
    let l = b.layout;
    let [fx, fy, fz] = l.full();
    let n_rows = (fy - 2) * (fz - 2);
    let mut derived = 0u64;
    let reusable = reuse && pc.row_index.valid && pc.row_index.counts.len() == n_rows;
    let words = occ.words;
    // Interior rows whose neighbourhood (the row and its eight neighbour rows) has covered cells that
    // changed since the previous mapping.
    let changed: Vec<bool> = match old_occ {
        Some(prev) if reusable => around_rows(
            occ.bits
                .chunks_exact(words)
                .zip(prev.bits.chunks_exact(words))
                .map(|(a, b)| a.iter().zip(b).any(|(a, b)| a != b)),
            fy,
            fz,
        ),
        _ => Vec::new(),
    };
    let reusable = reusable && old_occ.is_some();
    if reusable && !changed.contains(&true) {
        // No covered cell changed anywhere: the previous lists, row index and counts stand as they are.
        pc.turned.clear();
        pc.covered.clear();
        return 0;
    }
    let prev_segments = std::mem::replace(&mut pc.segments, std::mem::take(&mut pc.spare.segments));
    let prev_links = std::mem::replace(&mut pc.link_cells, std::mem::take(&mut pc.spare.link_cells));
    let prev_index = std::mem::replace(&mut pc.row_index, std::mem::take(&mut pc.spare.index));
    let index = &mut pc.row_index;
    index.segments.clear();
    index.link_cells.clear();
    index.counts.clear();
    let st = &pc.statics;
    pc.segments.clear();
    pc.link_cells.clear();
    pc.turned.clear();
    pc.covered.clear();
    let mut masks = vec![[0u64; Q]; words];
    // Per word and direction: the link cells whose second cell x − c_q is fluid now.
    let mut seconds = vec![[0u64; Q]; words];
    // Interior rows next to a row with a covered cell: only they can have links.
    let near_cov = around_rows(occ.bits.chunks_exact(words).map(|r| r.iter().any(|&w| w != 0)), fy, fz);
    let mut row = 0;
    // The first of the current run of clean rows.
    let mut clean: Option<usize> = None;
    for z in 1..fz - 1 {
        for y in 1..fy - 1 {
            if reusable && !changed[y + fy * z] {
                // A clean row: its entries are copied with the run of clean rows it belongs to.
                clean.get_or_insert(row);
                row += 1;
                continue;
            }
            if let Some(first) = clean.take() {
                copy_rows(
                    (&mut pc.segments, &mut pc.link_cells),
                    index,
                    (&prev_segments, &prev_links),
                    &prev_index,
                    first..row,
                );
            }
            derived += 1;
            index.segments.push(pc.segments.len() as u32);
            index.link_cells.push(pc.link_cells.len() as u32);
            // Fluid cells, near-boundary cells and cells with a particle link of this row.
            let mut counts = [0u32; 3];
            let base = l.idx(0, y, z);
            let covered_row = (0..words).any(|w| occ.row(y, z)[w] & interior_mask(fx, w) != 0);
            let check_links = near_cov[y + fy * z];
            let mut linked = false;
            for (w, (mask, second)) in masks.iter_mut().zip(seconds.iter_mut()).enumerate() {
                let im = interior_mask(fx, w);
                let fl = st.fluid.row(y, z)[w] & im;
                let cov = occ.row(y, z)[w] & im;
                let now = fl & !cov;
                counts[0] += now.count_ones();
                counts[1] += (now & st.near_wall.row(y, z)[w]).count_ones();
                if let Some(prev) = old_occ {
                    let was = prev.row(y, z)[w] & im;
                    for x in bit_cells(cov & !was, w) {
                        pc.covered.push((base + x, pc.owner[base + x] - 1));
                    }
                    for x in bit_cells(was & now, w) {
                        pc.turned.push((base + x, old[base + x] - 1));
                    }
                }
                // Links: bit x of mask q is set when cell x + c_q is covered.
                if !check_links {
                    continue;
                }
                linked |= link_masks(&st.fluid, occ, [y, z, w], now, mask, second) != 0;
            }
            if covered_row {
                let now = |w: usize| st.fluid.row(y, z)[w] & interior_mask(fx, w) & !occ.row(y, z)[w];
                push_runs(&mut pc.segments, (0..words).map(now), base);
            } else {
                let (a, e) = (st.row_segments[row] as usize, st.row_segments[row + 1] as usize);
                pc.segments.extend_from_slice(&b.segments[a..e]);
            }
            if linked {
                let near_wall = st.near_wall.row(y, z);
                push_link_cells(
                    &mut pc.link_cells,
                    (&masks, &seconds),
                    near_wall,
                    [base, y, z],
                    &mut counts,
                );
            }
            index.counts.push(counts);
            row += 1;
        }
    }
    if let Some(first) = clean.take() {
        copy_rows(
            (&mut pc.segments, &mut pc.link_cells),
            index,
            (&prev_segments, &prev_links),
            &prev_index,
            first..row,
        );
    }
    index.segments.push(pc.segments.len() as u32);
    index.link_cells.push(pc.link_cells.len() as u32);
    index.valid = true;
    let sum = |k: usize| index.counts.iter().map(|c| c[k] as usize).sum::<usize>();
    (pc.fluid_cells, pc.near_boundary_cells, pc.near_particle_cells) = (sum(0), sum(1), sum(2));
    pc.spare.segments = prev_segments;
    pc.spare.link_cells = prev_links;
    pc.spare.index = prev_index;
    derived
}

/// Appends the link cells of row (y, z) (element index of its cell 0: `base`) from its link masks and
/// second-cell masks per word (see [`link_masks`]), in x order, and counts them: `counts[2]` every link
/// cell, `counts[1]` those not already near a wall (`near_wall`, the row's static near-wall bits).
fn push_link_cells(
    out: &mut Vec<LinkCell>,
    (masks, seconds): (&[[u64; Q]], &[[u64; Q]]),
    near_wall: &[u64],
    [base, y, z]: [usize; 3],
    counts: &mut [u32; 3],
) {
    for (w, (m, sm)) in masks.iter().zip(seconds).enumerate() {
        for x in bit_cells(m[0], w) {
            let bit = 1u64 << (x % 64);
            // The cell's directions: bit x % 64 of every direction's mask.
            let gather = |m: &[u64; Q]| (1..Q).fold(0u32, |d, q| d | ((((m[q] >> (x % 64)) & 1) as u32) << q));
            out.push(LinkCell {
                cell: (base + x) as u32,
                dirs: gather(m),
                second_fluid: gather(sm),
                xyz: [x as u32, y as u32, z as u32],
            });
            counts[2] += 1;
            if near_wall[w] & bit == 0 {
                counts[1] += 1;
            }
        }
    }
}

/// Per row (y, z) of a ghost-inclusive grid with `fy` × `fz` rows, from one flag per row in row order
/// (`y + fy z`): for the interior rows, whether the flag is set on the row or any of its eight neighbour
/// rows (y ± 1, z ± 1); false on the ghost rows.
fn around_rows(flags: impl Iterator<Item = bool>, fy: usize, fz: usize) -> Vec<bool> {
    let flags: Vec<bool> = flags.collect();
    let mut along_y = vec![false; flags.len()];
    for z in 0..fz {
        for y in 1..fy - 1 {
            let r = y + fy * z;
            along_y[r] = flags[r - 1] | flags[r] | flags[r + 1];
        }
    }
    let mut out = vec![false; flags.len()];
    for z in 1..fz - 1 {
        for y in 1..fy - 1 {
            let r = y + fy * z;
            out[r] = along_y[r - fy] | along_y[r] | along_y[r + fy];
        }
    }
    out
}

/// The link masks of word `w` of row (y, z) whose cells fluid now are `now`: bit x of `mask[q]` is set when
/// cell x + c_q is covered (a link), bit x of `second[q]` when that link's second cell x − c_q is fluid
/// now (static `fluid` and not covered); `mask[0]` gets the union of the links, which is also returned.
fn link_masks(
    fluid: &CellBits,
    occ: &CellBits,
    [y, z, w]: [usize; 3],
    now: u64,
    mask: &mut [u64; Q],
    second: &mut [u64; Q],
) -> u64 {
    let mut any = 0;
    for (q, c) in C.iter().enumerate().skip(1) {
        let ny = (y as i64 + c[1] as i64) as usize;
        let nz = (z as i64 + c[2] as i64) as usize;
        let m = occ.shifted(ny, nz, w, c[0]) & now;
        mask[q] = m;
        any |= m;
        second[q] = if m != 0 {
            let (sy, sz) = ((y as i64 - c[1] as i64) as usize, (z as i64 - c[2] as i64) as usize);
            m & fluid.shifted(sy, sz, w, -c[0]) & !occ.shifted(sy, sz, w, -c[0])
        } else {
            0
        };
    }
    mask[0] = any;
    any
}

/// Appends the entries of the previous mapping's `rows` (consecutive interior rows) to the new lists and
/// row index: one copy per list for the whole run.
fn copy_rows(
    (to_segments, to_links): (&mut Vec<Segment>, &mut Vec<LinkCell>),
    index: &mut RowIndex,
    (segments, links): (&[Segment], &[LinkCell]),
    prev: &RowIndex,
    rows: std::ops::Range<usize>,
) {
    let (s0, s1) = (prev.segments[rows.start] as usize, prev.segments[rows.end] as usize);
    let (k0, k1) = (prev.link_cells[rows.start] as usize, prev.link_cells[rows.end] as usize);
    let (ds, dk) = (to_segments.len() as u32, to_links.len() as u32);
    for r in rows.clone() {
        index.segments.push(prev.segments[r] - s0 as u32 + ds);
        index.link_cells.push(prev.link_cells[r] - k0 as u32 + dk);
    }
    index.counts.extend_from_slice(&prev.counts[rows]);
    to_segments.extend_from_slice(&segments[s0..s1]);
    to_links.extend_from_slice(&links[k0..k1]);
}

/// Appends the runs of set bits of a row (its words in order; element index of the row's cell 0:
/// `base`), a run that crosses a word boundary as one.
fn push_runs(segs: &mut Vec<Segment>, words: impl Iterator<Item = u64>, base: usize) {
    let mut open: Option<Segment> = None;
    for (w, word) in words.enumerate() {
        let mut x = 0;
        while x < 64 {
            let rest = word >> x;
            if rest & 1 == 0 {
                if let Some(s) = open.take() {
                    segs.push(s);
                }
                if rest == 0 {
                    break;
                }
                x += rest.trailing_zeros() as usize;
                continue;
            }
            let len = ((!rest).trailing_zeros() as usize).min(64 - x);
            match open.as_mut() {
                Some(s) => s.len += len,
                None => {
                    open = Some(Segment {
                        start: base + w * 64 + x,
                        len,
                    })
                }
            }
            x += len;
        }
    }
    if let Some(s) = open {
        segs.push(s);
    }
}
