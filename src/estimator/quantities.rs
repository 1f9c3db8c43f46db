//! The Table 1 quantities of a block, as this engine counts them, and the work counters of its tasks
//! that the `blockflow` model of the estimator regresses on.

use crate::physics::simulation::Simulation;
use blockflow_kernels::{Layout, Real, Segment};

/// Row pitches (elements [`Layout::sx`]) between the end of one fluid run and the start of the next beyond
/// which the next run counts as a new memory stream ([`Quantities::breaks`]). Within a plane the rows of a
/// block, however short a wall or a sphere cuts them, lie closer than that, and so do the last row of
/// one plane and the first of the next past the two ghost rows: the hardware prefetcher streams across
/// such gaps. A plane whose first fluid row lies several rows on (a wall sloping across y and z) does
/// restart the 19 arrays' streams, and it costs so whatever the rows' length (`sparse_runs` example of
/// the kernels crate: 7 full rows in each of 16 planes cost about 40 % more than 7 full planes).
pub const STREAM_GAP_ROWS: usize = 6;

/// The runs of `segs` (in memory order) that start more than `gap` elements after the end of the run
/// before them; the first run counts as one.
pub fn stream_breaks(segs: &[Segment], gap: usize) -> f64 {
    let mut end: Option<usize> = None;
    let mut n = 0usize;
    for s in segs {
        if end.is_none_or(|e| s.start > e + gap) {
            n += 1;
        }
        end = Some(s.start + s.len);
    }
    n as f64
}

/// The runs of `segs` that end in a vector tail step: the fluid kernel sweeps each run `lanes` cells
/// per vector step and its last `len mod lanes` cells in one more step whose other lanes write back what
/// they read, which costs about as much as a full one (a row cut short by a wall or a body leaves such a
/// tail; full rows of a block whose edge is a multiple of `lanes` do not).
pub fn tail_runs(segs: &[Segment], lanes: usize) -> f64 {
    segs.iter().filter(|s| s.len % lanes != 0).count() as f64
}

/// The runs of the planes (z) whose runs differ from those of the plane before (other positions within
/// the plane or other lengths; the first plane with runs does not count). From memory, a sweep whose
/// planes repeat one pattern of rows streams as the hardware prefetcher foresees; where a wall cuts the
/// planes differently from one to the next, as a sloped wall does, every row of those planes costs
/// about a third more (the `sparse_runs` example of the kernels crate).
pub fn shifted_runs(segs: &[Segment], l: &Layout) -> f64 {
    // A plane's runs as (position within the plane, length).
    let (mut prev, mut cur) = (Vec::<(usize, usize)>::new(), Vec::<(usize, usize)>::new());
    let (mut plane, mut seen, mut n) = (usize::MAX, false, 0usize);
    let mut close = |cur: &mut Vec<(usize, usize)>, prev: &mut Vec<(usize, usize)>| {
        if !cur.is_empty() {
            if seen && cur != prev {
                n += cur.len();
            }
            seen = true;
            std::mem::swap(prev, cur);
            cur.clear();
        }
    };
    for s in segs {
        if s.start / l.sxy != plane {
            close(&mut cur, &mut prev);
            plane = s.start / l.sxy;
        }
        cur.push((s.start % l.sxy, s.len));
    }
    close(&mut cur, &mut prev);
    n as f64
}

/// Table 1 quantities of one block in one step, plus what this engine's tasks did in it (all f64, so
/// that they enter the regressions directly).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Quantities {
    /// C: total number of cells on the block (eqs. 10–13).
    pub c: f64,
    /// F: number of cells flagged as fluid (eqs. 10, 12, 13).
    pub f: f64,
    /// NB: number of cells flagged as near boundary (Table 1's B; eq. 11).
    pub nb: f64,
    /// P_L: number of local particles (eqs. 12–14).
    pub pl: f64,
    /// P_S: number of shadow particles (eqs. 12–14).
    pub ps: f64,
    /// K: number of contacts between rigid bodies (eq. 14), owned by the block, per sub-step.
    pub k: f64,
    /// S: number of sub-cycles of the rigid-body simulation (the factor of eq. 14).
    pub s: f64,
    /// Runs of fluid cells the fluid kernel updates (each run costs a row set-up).
    #[serde(default)]
    pub runs: f64,
    /// Runs that start more than [`STREAM_GAP_ROWS`] row pitches past the end of the run before them
    /// ([`stream_breaks`]): each one restarts the memory streams of the 19 arrays instead of continuing
    /// them (the first row of a plane that a sloping wall cuts, not a row cut by a sphere).
    #[serde(default)]
    pub breaks: f64,
    /// Bounce-back links at walls (resting and moving).
    #[serde(default)]
    pub wall_links: f64,
    /// Cache lines the wall links touch: a wall across the rows (normal along x) costs a line per link,
    /// one along the rows shares lines between links.
    #[serde(default)]
    pub wall_lines: f64,
    /// Links from fluid cells into particle cells (each gets δ_q and the momentum exchange).
    #[serde(default)]
    pub particle_links: f64,
    /// Fluid cells with at least one particle link (the link lists' entries).
    #[serde(default)]
    pub link_cells: f64,
    /// 1 when the mapping ran beyond its fast path (a body near before or now), else 0.
    #[serde(default)]
    pub map_active: f64,
    /// Bodies the mapping wrote (locals and shadows).
    #[serde(default)]
    pub map_bodies: f64,
    /// Bounding-box cells the mapping visited.
    #[serde(default)]
    pub box_cells: f64,
    /// Rows the mapping derived again (not copied from the previous mapping).
    #[serde(default)]
    pub rows_derived: f64,
    /// Cells turned from solid to fluid (reconstructed) in the step.
    #[serde(default)]
    pub turned: f64,
    /// Cells covered by a body in the step.
    #[serde(default)]
    pub covered: f64,
    /// 1 when the block ran rigid-body tasks in the step, else 0.
    #[serde(default)]
    pub rb_active: f64,
    /// Contacts the block's rigid-body task solved (its own and those among its shadows: the contacts
    /// it *sees*, the paper's K), per sub-step.
    #[serde(default)]
    pub contacts_seen: f64,
    /// Entries of the neighbours' published lists read to gather locals and shadows, per sub-step.
    #[serde(default)]
    pub scanned: f64,
    /// Runs whose last cells the kernel updates in a vector tail step ([`tail_runs`]).
    #[serde(default)]
    pub tail_runs: f64,
    /// Runs of planes whose runs differ from the plane before's ([`shifted_runs`]).
    #[serde(default)]
    pub shifted_runs: f64,
    /// Elements between consecutive rows of the block's arrays ([`Layout::sx`]: the interior row, its
    /// ghosts and the padding to the vector width), what one row of each of the 19 streams spans.
    #[serde(default)]
    pub row_pitch: f64,
}

impl Quantities {
    /// The quantities of block `b` of `sim` after the last step: C, F, NB, the fluid runs and links
    /// from the block and its particle overlay, the mapping's counters from the last mapping (0 where the
    /// block had no particle tasks), P_L and
    /// P_S from the block's last rigid-body sub-step, K, the contacts seen and the list entries scanned
    /// averaged over the step's sub-steps, S the sub-steps (0 for a block without rigid-body tasks).
    /// Call between graph runs.
    pub fn of<T: Real>(sim: &Simulation<T>, b: usize) -> Quantities {
        let blk = &sim.blocks[b];
        let mut q = Quantities {
            c: blk.layout.interior_cells() as f64,
            wall_links: (blk.links.noslip.len() + blk.links.moving.len()) as f64,
            wall_lines: blk.wall_lines as f64,
            row_pitch: blk.layout.sx as f64,
            ..Default::default()
        };
        match blk.particle_cells() {
            Some(pc) => {
                q.f = pc.fluid_cells as f64;
                q.nb = pc.near_boundary_cells as f64;
                q.runs = pc.segments.len() as f64;
                q.breaks = stream_breaks(&pc.segments, STREAM_GAP_ROWS * blk.layout.sx);
                q.tail_runs = tail_runs(&pc.segments, T::LANES);
                q.shifted_runs = shifted_runs(&pc.segments, &blk.layout);
                q.link_cells = pc.link_cells.len() as f64;
                q.particle_links = pc.link_cells.iter().map(|l| l.dirs.count_ones() as f64).sum();
                // The mapping ran in the last step only where the block was active (else the overlay
                // is the one of an earlier step, or of the set-up).
                if sim.particles.as_ref().is_some_and(|p| p.active[b]) {
                    q.map_active = f64::from(u8::from(pc.map_work.active));
                    q.map_bodies = pc.bodies.len() as f64;
                    q.box_cells = pc.map_work.box_cells as f64;
                    q.rows_derived = pc.map_work.rows_derived as f64;
                    q.turned = pc.turned.len() as f64;
                    q.covered = pc.covered.len() as f64;
                }
            }
            None => {
                q.f = blk.fluid_cells as f64;
                q.nb = blk.near_boundary_cells as f64;
                q.runs = blk.segments.len() as f64;
                q.breaks = stream_breaks(&blk.segments, STREAM_GAP_ROWS * blk.layout.sx);
                q.tail_runs = tail_runs(&blk.segments, T::LANES);
                q.shifted_runs = shifted_runs(&blk.segments, &blk.layout);
            }
        }
        if let Some(p) = sim.particles.as_ref().filter(|p| p.active[b]) {
            // SAFETY: called between graph runs.
            let w = unsafe { p.blocks[b].work() };
            let s = p.subcycles as f64;
            q.pl = w.locals as f64;
            q.ps = (w.bodies.len() - w.locals) as f64;
            q.k = w.contacts_step as f64 / s;
            q.contacts_seen = w.seen_step as f64 / s;
            q.scanned = w.scanned_step as f64 / s;
            q.s = s;
            q.rb_active = 1.0;
        }
        q
    }

    /// The quantities a balancing step weighs block `b` by: [`Quantities::of`] with the mapping's
    /// counters that jump from step to step (bodies mapped, bounding-box cells, rows derived, cells
    /// turned and covered) replaced by their averages over the recent mappings
    /// ([`crate::physics::particle_cells::MapAverage`]). Call between graph runs.
    pub fn for_weights<T: Real>(sim: &Simulation<T>, b: usize) -> Quantities {
        let q = Quantities::of(sim, b);
        match sim.blocks[b].particle_cells() {
            Some(pc) if q.rb_active > 0.0 => q.with_map_average(pc.map_average.as_array()),
            _ => q,
        }
    }

    /// These quantities with the mapping's counters set to `average` (in the order of
    /// [`crate::physics::particle_cells::MapAverage::as_array`]).
    pub fn with_map_average(self, average: [f64; 5]) -> Quantities {
        let [map_bodies, box_cells, rows_derived, turned, covered] = average;
        Quantities {
            map_bodies,
            box_cells,
            rows_derived,
            turned,
            covered,
            ..self
        }
    }

    /// The mapping's counters that [`Quantities::for_weights`] averages, in the order of
    /// [`Quantities::with_map_average`].
    pub fn map_counts(&self) -> [f64; 5] {
        [
            self.map_bodies,
            self.box_cells,
            self.rows_derived,
            self.turned,
            self.covered,
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn seg(start: usize, len: usize) -> Segment {
        Segment { start, len }
    }

    /// Rows of a 32³ block (row pitch 36, plane pitch 36 · 34), full or cut short by a wall across x, and
    /// the planes after them past the two ghost rows continue one stream; a plane whose runs start seven
    /// rows further on starts a new one, and a gap of exactly six rows does not.
    #[test]
    fn stream_breaks_count_runs_that_restart_the_streams() {
        let (sx, sxy) = (36, 36 * 34);
        let gap = STREAM_GAP_ROWS * sx;
        assert_eq!(stream_breaks(&[], gap), 0.0);
        let full: Vec<Segment> = (0..32)
            .flat_map(|z| (0..32).map(move |y| seg(39 + sx * y + sxy * z, 32)))
            .collect();
        assert_eq!(stream_breaks(&full, gap), 1.0);
        let cut: Vec<Segment> = (0..20).map(|y| seg(39 + sx * y, 4)).collect();
        assert_eq!(stream_breaks(&cut, gap), 1.0);
        assert_eq!(stream_breaks(&[seg(39, 10), seg(39 + 10 + gap, 6)], gap), 1.0);
        assert_eq!(stream_breaks(&[seg(39, 10), seg(39 + 10 + gap + 1, 6)], gap), 2.0);
        // A wall sloping across y and z: plane z holds rows y >= 8 + z of 32 cells (rows 8.. of plane 0,
        // rows 9.. of plane 1, ...): between planes lie the rows below the wall and the ghost rows.
        let sloped: Vec<Segment> = (0..4)
            .flat_map(|z| (8 + z..32).map(move |y| seg(39 + sx * y + sxy * z, 32)))
            .collect();
        assert_eq!(stream_breaks(&sloped, gap), 4.0);
    }

    /// A full row of 32 cells is all full vector steps of 4 (or 8); rows cut to 13 and 10 cells end in a
    /// tail step at either width, one of 8 cells at neither, one of 4 only at 8 lanes.
    #[test]
    fn tail_runs_follow_the_vector_width() {
        let (full, cut, late, whole) = (seg(36, 32), seg(36 + 36, 13), seg(36 + 72 + 6, 10), seg(36 + 144, 8));
        assert_eq!(tail_runs(&[full], 4), 0.0);
        assert_eq!(tail_runs(&[full, cut, late, whole], 4), 2.0);
        assert_eq!(tail_runs(&[full, cut, late, whole], 8), 2.0);
        assert_eq!(tail_runs(&[seg(36, 4)], 8), 1.0);
        assert_eq!(tail_runs(&[], 4), 0.0);
    }

    /// On a 16³ block: planes that repeat the rows of the plane before count nothing, whole or cut the
    /// same; a plane with one row more (a sloped wall), a row moved along x or cut shorter counts all
    /// its runs; an empty plane between two equal ones does not break the repetition.
    #[test]
    fn shifted_runs_count_the_runs_of_planes_unlike_the_one_before() {
        let l = Layout::new::<f64>([16, 16, 16]);
        let plane = |z: usize, rows: &[(usize, usize, usize)]| -> Vec<Segment> {
            rows.iter().map(|&(y, x, n)| seg(l.idx(x, y, z), n)).collect()
        };
        let rows = |k: usize| -> Vec<(usize, usize, usize)> { (1..=k).map(|y| (y, 1, 16)).collect() };
        let block = |planes: &[Vec<(usize, usize, usize)>]| -> Vec<Segment> {
            planes.iter().enumerate().flat_map(|(z, r)| plane(z + 1, r)).collect()
        };
        assert_eq!(shifted_runs(&[], &l), 0.0);
        assert_eq!(shifted_runs(&block(&vec![rows(16); 16]), &l), 0.0);
        assert_eq!(shifted_runs(&block(&vec![rows(7); 16]), &l), 0.0);
        // A sloped wall: planes of 3, 4, 5 rows; the first plane does not count.
        assert_eq!(shifted_runs(&block(&[rows(3), rows(4), rows(5)]), &l), 9.0);
        // Alternating 6 and 7 rows: every plane but the first.
        let alt: Vec<_> = (0..4).map(|z| rows(6 + z % 2)).collect();
        assert_eq!(shifted_runs(&block(&alt), &l), 7.0 + 6.0 + 7.0);
        // The same count of rows, one moved along x, or cut short.
        let mut moved = rows(2);
        moved[1].1 = 2;
        assert_eq!(shifted_runs(&block(&[rows(2), moved.clone(), moved]), &l), 2.0);
        let mut short = rows(2);
        short[0].2 = 15;
        assert_eq!(shifted_runs(&block(&[rows(2), short]), &l), 2.0);
        let gap = [plane(1, &rows(3)), plane(3, &rows(3))].concat();
        assert_eq!(shifted_runs(&gap, &l), 0.0);
    }
}
