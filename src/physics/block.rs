//! One block: its PDF field(s) (one under AA streaming, source and destination under pull), cell flags, fluid segments, bounce-back links and
//! the list of ghost regions it must receive. Built once per block layout from the scene geometry.

use crate::physics::domain::{DomainSpec, NEIGHBOURS};
use crate::physics::geometry::{flags, CellKind, Geometry};
use blockflow_kernels::bounce_back::Links;
use blockflow_kernels::d3q19::{crossing_directions, C, Q};
use blockflow_kernels::sweep::Segment;
use blockflow_kernels::{Layout, Pattern, PdfField, Real, Slots};
use std::cell::UnsafeCell;

/// Byte skew of a block's second field against the first, so source and destination arrays do not alias
/// on 4 KiB pages either.
const DST_SKEW_BYTES: usize = 2048 + 96;

/// The page skew of field `k` (0 or 1) of a block.
fn skew(k: usize) -> usize {
    if k == 0 {
        0
    } else {
        DST_SKEW_BYTES
    }
}

/// A ghost region this block receives: the neighbour at `offset` sends the `directions` that cross.
#[derive(Clone, Debug)]
pub struct GhostRecv {
    /// Offset of the neighbour block (each component in -1..=1).
    pub offset: [i32; 3],
    /// The neighbour's block id (may be this block itself on a periodic axis with one block).
    pub from: usize,
    /// PDF directions that stream from the ghost region into this block.
    pub directions: Vec<usize>,
    /// What an in-process copy moves: for direction `directions[k]`, the runs
    /// `runs[run_starts[k] .. run_starts[k + 1]]`, ghost cells whose value in that direction streams
    /// into an interior fluid cell (the rest of the region is never read).
    pub runs: Vec<GhostRun>,
    /// Start of each direction's runs in `runs`, plus one entry past the last.
    pub run_starts: Vec<u32>,
}

/// Consecutive cells along x of a ghost region and the sender's cells that fill them (element indices
/// without the direction's offset).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GhostRun {
    /// First cell in the sender's interior.
    pub src: u32,
    /// First ghost cell of the receiver.
    pub dst: u32,
    /// Number of cells.
    pub len: u32,
}

/// Per-block state of the fluid.
pub struct Block<T: Real> {
    /// Block id (x fastest over the block grid).
    pub id: usize,
    /// Block coordinates.
    pub coords: [usize; 3],
    /// Global coordinates of the first interior cell.
    pub origin: [usize; 3],
    /// Index arithmetic of the fields.
    pub layout: Layout,
    /// How the PDFs stream: one field in place (AA) or two (pull).
    pub pattern: Pattern,
    /// Where the state after an even (`[0]`) or odd (`[1]`) number of steps keeps each post-collision
    /// population ([`Slots`]).
    slots: [Slots; 2],
    /// The PDF fields: one under AA; under pull two, the state after `s` steps in `fields[s % 2]`. A step
    /// fills the state's ghost layer and wall cells, then streams and collides (in place under AA, into
    /// the other field under pull). Behind `UnsafeCell` so tasks of the step graph can work on disjoint
    /// regions concurrently.
    fields: Vec<UnsafeCell<PdfField<T>>>,
    /// Flag byte per cell, indexed like the fields (ghost layer included).
    pub flags: Vec<u8>,
    /// Runs of fluid cells along x: what the kernels sweep.
    pub segments: Vec<Segment>,
    /// Bounce-back links of the fluid cells.
    pub links: Links<T>,
    /// Ghost regions to receive before the boundary pass.
    pub recv: Vec<GhostRecv>,
    /// Number of interior fluid cells.
    pub fluid_cells: usize,
    /// Number of interior fluid cells with a wall neighbour.
    pub near_boundary_cells: usize,
    /// Cache lines the wall links touch ([`Links::lines`]), counted once at set-up.
    pub wall_lines: usize,
    /// Whether every interior cell is fluid (then segments are whole rows).
    pub obstacle_free: bool,
    /// Cells covered by particles, their links and forces (absent without particles in the fluid).
    /// Rebuilt by the `map` task, read by the boundary and sweep tasks (ordered by the graph).
    particles: UnsafeCell<Option<crate::physics::particle_cells::ParticleCells>>,
    /// For a block another rank holds: a copy of the body forces of its particle overlay's last boundary
    /// pass ([`Block::body_forces`]), filled from that rank's messages.
    remote_forces: UnsafeCell<Vec<crate::physics::particle_cells::BodyForce>>,
}

/// What a block takes from the scene's static geometry (walls, planes, no-fluid regions): cell flags
/// (ghost layer included), fluid runs, bounce-back links and the cell counts. Derived once per block in
/// [`Block::new`] ("a scene maps its static geometry once", DESIGN.md principle 2); `--no-skip`
/// re-derives it every step ([`Block::check_static_geometry`]) to measure what that saves.
#[derive(Clone, Debug)]
pub struct StaticGeometry<T: Real> {
    /// Index arithmetic of the block's fields.
    pub layout: Layout,
    /// Flag byte per cell, indexed like the fields (ghost layer included).
    pub flags: Vec<u8>,
    /// Runs of fluid cells along x.
    pub segments: Vec<Segment>,
    /// Bounce-back links of the fluid cells.
    pub links: Links<T>,
    /// Interior fluid cells.
    pub fluid_cells: usize,
    /// Interior fluid cells with a wall neighbour.
    pub near_boundary_cells: usize,
}

impl<T: Real> StaticGeometry<T> {
    /// Classifies every cell of block `id` of `d` (ghost layer included) against the geometry, cell by
    /// cell, and derives flags, fluid runs and links (laid out for `pattern`) from it.
    pub fn derive(d: &DomainSpec, geo: &Geometry, id: usize, pattern: Pattern) -> Self {
        let layout = Layout::new::<T>(d.block_size);
        let origin = d.origin(id);
        let [fx, fy, fz] = layout.full();
        let mut kind = vec![CellKind::Fluid; fx * fy * fz];
        let lin = |x: usize, y: usize, z: usize| x + fx * (y + fy * z);
        for z in 0..fz {
            for y in 0..fy {
                for x in 0..fx {
                    let g = [
                        origin[0] as i64 + x as i64 - 1,
                        origin[1] as i64 + y as i64 - 1,
                        origin[2] as i64 + z as i64 - 1,
                    ];
                    kind[lin(x, y, z)] = geo.classify(d, g);
                }
            }
        }
        let mut fl = vec![0u8; layout.slots()];
        for z in 0..fz {
            for y in 0..fy {
                for x in 0..fx {
                    let i = layout.idx(x, y, z);
                    fl[i] = match kind[lin(x, y, z)] {
                        CellKind::Fluid => flags::FLUID,
                        CellKind::Wall(_) => flags::OUTSIDE,
                    };
                }
            }
        }
        let mut links = Links::new(pattern);
        let mut segments = Vec::new();
        let mut fluid_cells = 0;
        let mut near = 0;
        for z in 1..fz - 1 {
            for y in 1..fy - 1 {
                let mut run: Option<Segment> = None;
                for x in 1..fx - 1 {
                    let i = layout.idx(x, y, z);
                    if fl[i] & flags::FLUID == 0 {
                        if let Some(s) = run.take() {
                            segments.push(s);
                        }
                        continue;
                    }
                    fluid_cells += 1;
                    match run.as_mut() {
                        Some(s) => s.len += 1,
                        None => run = Some(Segment { start: i, len: 1 }),
                    }
                    let mut is_near = false;
                    for (q, c) in C.iter().enumerate().skip(1) {
                        let (wx, wy, wz) = (
                            (x as i64 - c[0] as i64) as usize,
                            (y as i64 - c[1] as i64) as usize,
                            (z as i64 - c[2] as i64) as usize,
                        );
                        if let CellKind::Wall(v) = kind[lin(wx, wy, wz)] {
                            links.push(&layout, i, q, v);
                            is_near = true;
                            let w = layout.idx(wx, wy, wz);
                            fl[w] = if v == [0.0; 3] {
                                flags::NOSLIP
                            } else {
                                flags::MOVING_WALL
                            };
                        }
                    }
                    if is_near {
                        fl[i] |= flags::NEAR_BOUNDARY;
                        near += 1;
                    }
                }
                if let Some(s) = run.take() {
                    segments.push(s);
                }
            }
        }
        StaticGeometry {
            layout,
            flags: fl,
            segments,
            links,
            fluid_cells,
            near_boundary_cells: near,
        }
    }
}

impl<T: Real> Block<T> {
    /// Builds block `id` of `d` from the geometry: flags (ghost layer included), segments, links and the
    /// ghost regions it needs, with the fields of streaming `pattern`. Fields start at rest; call
    /// [`Block::init`] to set an initial state.
    pub fn new(d: &DomainSpec, geo: &Geometry, id: usize, pattern: Pattern) -> Self {
        let StaticGeometry {
            layout,
            flags: fl,
            segments,
            links,
            fluid_cells,
            near_boundary_cells: near,
        } = StaticGeometry::derive(d, geo, id, pattern);
        let origin = d.origin(id);
        let mut recv = Vec::new();
        if fluid_cells > 0 {
            for &off in NEIGHBOURS.iter() {
                let dirs = crossing_directions(off);
                if dirs.is_empty() {
                    continue;
                }
                let Some(from) = d.neighbour(id, off) else {
                    continue;
                };
                // Needed only if a fluid ghost cell in this region streams into an interior fluid cell.
                let needed = ghost_region(&layout, off).any(|(x, y, z)| {
                    fl[layout.idx(x, y, z)] & flags::FLUID != 0
                        && dirs.iter().any(|&q| {
                            let t = layout.idx(
                                (x as i64 + C[q][0] as i64) as usize,
                                (y as i64 + C[q][1] as i64) as usize,
                                (z as i64 + C[q][2] as i64) as usize,
                            );
                            fl[t] & flags::FLUID != 0
                        })
                });
                if needed {
                    let (runs, run_starts) = ghost_runs(&layout, &fl, off, &dirs);
                    recv.push(GhostRecv {
                        offset: off,
                        from,
                        directions: dirs,
                        runs,
                        run_starts,
                    });
                }
            }
        }
        let obstacle_free = fluid_cells == layout.interior_cells();
        let wall_lines = links.lines();
        Block {
            id,
            coords: d.coords(id),
            origin,
            layout,
            pattern,
            slots: [Slots::new(pattern, &layout, 0), Slots::new(pattern, &layout, 1)],
            fields: (0..pattern.fields())
                .map(|p| UnsafeCell::new(PdfField::new(layout, skew(p))))
                .collect(),
            flags: fl,
            segments,
            links,
            recv,
            fluid_cells,
            near_boundary_cells: near,
            wall_lines,
            obstacle_free,
            particles: UnsafeCell::new(None),
            remote_forces: UnsafeCell::new(Vec::new()),
        }
    }

    /// Whether this process holds the block's data (PDF fields, particle overlay). Under virtual
    /// processes every block is held; under ranks only the blocks the rank owns, the others keep their
    /// static structure (flags, runs, links, receive lists) and nothing else.
    pub fn is_held(&self) -> bool {
        // SAFETY: a shared view of the field's bookkeeping; fields are swapped only when no task runs.
        unsafe { (*self.fields[0].get()).is_allocated() }
    }

    /// Gives up the block's data: the PDF fields (memory returned) and the particle overlay. The block
    /// keeps its static structure; [`Block::hold`] or a decoded block gives it data again.
    ///
    /// # Safety
    /// No task may run on this block, and no reference to its fields or overlay may be alive.
    pub unsafe fn release(&self) {
        for f in &self.fields {
            *f.get() = PdfField::unallocated(self.layout);
        }
        *self.particles.get() = None;
        (*self.remote_forces.get()).clear();
    }

    /// Gives the block fresh fields at rest (pages mapped lazily: the thread that writes them first
    /// places them) if it has none.
    ///
    /// # Safety
    /// As [`Block::release`].
    pub unsafe fn hold(&self) {
        if self.is_held() {
            return;
        }
        for (k, f) in self.fields.iter().enumerate() {
            *f.get() = PdfField::new(self.layout, skew(k));
        }
        (*self.remote_forces.get()).clear();
    }

    /// The body forces of the block's last boundary pass (eqs. 8, 9 restricted to its links, sorted by
    /// body id): from its particle overlay when this process holds the block, else the copy another
    /// rank sent ([`Block::set_remote_forces`]); empty without an overlay.
    pub fn body_forces(&self) -> &[crate::physics::particle_cells::BodyForce] {
        match self.particle_cells() {
            Some(pc) => &pc.forces,
            // SAFETY: a shared view; the copy is replaced only between the tasks that read it (by the
            // graph's message edges) or between graph runs.
            None if !self.is_held() => unsafe { &*self.remote_forces.get() },
            None => &[],
        }
    }

    /// Replaces the copy of the body forces of a block another rank holds.
    ///
    /// # Safety
    /// No task may read [`Block::body_forces`] of this block concurrently.
    pub unsafe fn set_remote_forces(&self, forces: Vec<crate::physics::particle_cells::BodyForce>) {
        *self.remote_forces.get() = forces;
    }

    /// The particle overlay, if particles are mapped into this block's fluid.
    pub fn particle_cells(&self) -> Option<&crate::physics::particle_cells::ParticleCells> {
        // SAFETY: a shared view; the overlay is written only by this block's map and boundary tasks,
        // which the graph orders against every reader.
        unsafe { (*self.particles.get()).as_ref() }
    }

    /// The particle overlay for writing (created on first use).
    ///
    /// # Safety
    /// No other reference to the overlay may be alive until the returned one is dropped.
    #[allow(clippy::mut_from_ref)]
    pub unsafe fn particle_cells_mut(&self) -> &mut crate::physics::particle_cells::ParticleCells {
        (*self.particles.get()).get_or_insert_with(Default::default)
    }

    /// Runs of interior cells that are fluid now: the static segments, minus cells covered by particles.
    pub fn fluid_segments(&self) -> &[Segment] {
        match self.particle_cells() {
            Some(pc) => &pc.segments,
            None => &self.segments,
        }
    }

    /// Interior fluid cells now (static fluid cells not covered by a particle).
    pub fn current_fluid_cells(&self) -> usize {
        self.particle_cells().map_or(self.fluid_cells, |pc| pc.fluid_cells)
    }

    /// The field holding the state after a number of steps of parity `p` (0 or 1), for reading. Callers
    /// must not hold it across a concurrent writer of the same elements; the step graph guarantees that
    /// (see `pipeline`).
    #[inline]
    pub fn field(&self, p: usize) -> &PdfField<T> {
        // SAFETY: a shared view; concurrent writes only go through raw pointers to elements that no
        // reader of this view touches at the same time (ordered by the task graph).
        unsafe { &*self.fields[self.pattern.field_of(p)].get() }
    }

    /// The field of parity `p` for writing through a shared block reference.
    ///
    /// # Safety
    /// No other reference to that field may be alive or created until the returned one is dropped.
    #[inline]
    #[allow(clippy::mut_from_ref)]
    pub unsafe fn field_mut(&self, p: usize) -> &mut PdfField<T> {
        &mut *self.fields[self.pattern.field_of(p)].get()
    }

    /// Where the state after a number of steps of parity `p` keeps each post-collision population.
    #[inline]
    pub fn slots(&self, p: usize) -> &Slots {
        &self.slots[p & 1]
    }

    /// Sets every fluid cell of the state after 0 steps to the post-collision state `f(global cell)`
    /// (zero-centred PDFs).
    pub fn init(&mut self, mut f: impl FnMut([usize; 3]) -> [f64; Q]) {
        let l = self.layout;
        let slots = self.slots[0];
        let field = self.fields[0].get_mut();
        for s in &self.segments {
            let [x0, y, z] = l.coords(s.start);
            for x in x0..x0 + s.len {
                let g = [self.origin[0] + x - 1, self.origin[1] + y - 1, self.origin[2] + z - 1];
                let v = f(g);
                let cell: [T; Q] = std::array::from_fn(|q| T::from_f64(v[q]));
                field.set_post_cell(&slots, l.idx(x, y, z), &cell);
            }
        }
    }

    /// Calls `visit(global cell, element index)` for every interior fluid cell, in x-fastest order.
    pub fn for_each_fluid(&self, mut visit: impl FnMut([usize; 3], usize)) {
        let l = self.layout;
        for s in self.fluid_segments() {
            let [x0, y, z] = l.coords(s.start);
            for x in x0..x0 + s.len {
                visit(
                    [self.origin[0] + x - 1, self.origin[1] + y - 1, self.origin[2] + z - 1],
                    l.idx(x, y, z),
                );
            }
        }
    }

    /// A fresh field at rest for the state of parity `p` (0 or 1), with its field's page skew. Its pages
    /// are mapped lazily: the first thread that writes them places them (first touch).
    pub fn fresh_field(&self, p: usize) -> PdfField<T> {
        PdfField::new(self.layout, skew(self.pattern.field_of(p)))
    }

    /// Replaces the field of parity `p` (e.g. by one rebuilt from a serialised block) and returns the old
    /// one.
    ///
    /// # Safety
    /// No other reference to that field may be alive, and no task may run on this block.
    pub unsafe fn replace_field(&self, p: usize, f: PdfField<T>) -> PdfField<T> {
        assert_eq!(f.layout, self.layout, "replacement field of another layout");
        std::mem::replace(&mut *self.fields[self.pattern.field_of(p)].get(), f)
    }

    /// Replaces the particle overlay (`None`: no particles mapped into this block) and returns the old one.
    ///
    /// # Safety
    /// No other reference to the overlay may be alive, and no task may run on this block.
    pub unsafe fn replace_particle_cells(
        &self,
        pc: Option<crate::physics::particle_cells::ParticleCells>,
    ) -> Option<crate::physics::particle_cells::ParticleCells> {
        std::mem::replace(&mut *self.particles.get(), pc)
    }

    /// `--no-skip`'s stand-in for "static geometry mapped once": re-derives this block's flags, fluid
    /// runs and links from the scene geometry, cell by cell, and checks them against the stored ones
    /// (which every task keeps using, so results do not change). Panics if they differ: the static
    /// geometry is then not static.
    pub fn check_static_geometry(&self, d: &DomainSpec, geo: &Geometry) {
        let s = StaticGeometry::<T>::derive(d, geo, self.id, self.pattern);
        let same_moving = s.links.moving.len() == self.links.moving.len()
            && s.links
                .moving
                .iter()
                .zip(&self.links.moving)
                .all(|(a, b)| a.0 == b.0 && a.1.to_f64().to_bits() == b.1.to_f64().to_bits());
        assert!(
            s.layout == self.layout
                && s.flags == self.flags
                && s.segments == self.segments
                && s.links.noslip == self.links.noslip
                && same_moving
                && s.fluid_cells == self.fluid_cells
                && s.near_boundary_cells == self.near_boundary_cells,
            "block {}: the static geometry derived again differs from the one mapped at set-up",
            self.id
        );
    }

    /// The general path of the sweep's cell selection (`--no-skip`): visits every interior cell, checks
    /// its flag (and the particle overlay's owner) one by one, and writes the runs of fluid cells into
    /// `out`: the same runs as [`Block::fluid_segments`], which are otherwise computed once per mapping.
    /// Returns the number of fluid cells found.
    pub fn scan_fluid_runs(&self, out: &mut Vec<Segment>) -> usize {
        out.clear();
        let l = self.layout;
        let [fx, fy, fz] = l.full();
        let owner = self
            .particle_cells()
            .map(|pc| pc.owner.as_slice())
            .filter(|o| o.len() == l.slots());
        let mut n = 0;
        for z in 1..fz - 1 {
            for y in 1..fy - 1 {
                let mut run: Option<Segment> = None;
                for x in 1..fx - 1 {
                    let i = l.idx(x, y, z);
                    let fluid = self.flags[i] & flags::FLUID != 0 && owner.is_none_or(|o| o[i] == 0);
                    if !fluid {
                        if let Some(s) = run.take() {
                            out.push(s);
                        }
                        continue;
                    }
                    n += 1;
                    match run.as_mut() {
                        Some(s) => s.len += 1,
                        None => run = Some(Segment { start: i, len: 1 }),
                    }
                }
                if let Some(s) = run.take() {
                    out.push(s);
                }
            }
        }
        n
    }

    /// The general path of the boundary task's cell selection (`--no-skip`): visits every interior cell
    /// and counts those flagged near a wall (a block without boundary cells finds none, cell by cell).
    pub fn scan_near_boundary(&self) -> usize {
        let l = self.layout;
        let [fx, fy, fz] = l.full();
        let mut n = 0;
        for z in 1..fz - 1 {
            for y in 1..fy - 1 {
                for x in 1..fx - 1 {
                    let f = self.flags[l.idx(x, y, z)];
                    n += usize::from(f & flags::FLUID != 0 && f & flags::NEAR_BOUNDARY != 0);
                }
            }
        }
        n
    }

    /// Bytes of PDF storage this process holds for the block (all its fields; none when another rank
    /// holds the block).
    pub fn pdf_bytes(&self) -> usize {
        if !self.is_held() {
            return 0;
        }
        self.fields.len() * self.layout.len() * std::mem::size_of::<T>()
    }
}

/// Ghost-inclusive coordinate ranges (x, y, z) of the ghost region at neighbour offset `off`.
pub fn ghost_ranges(l: &Layout, off: [i32; 3]) -> [std::ops::RangeInclusive<usize>; 3] {
    std::array::from_fn(|a| match off[a] {
        -1 => 0..=0,
        0 => 1..=l.size[a],
        _ => l.size[a] + 1..=l.size[a] + 1,
    })
}

/// Coordinate ranges of the interior cells of a sending block that fill a receiver's ghost region at
/// offset `off` (the layer next to the opposite face); same shape and order as [`ghost_ranges`].
pub fn source_ranges(l: &Layout, off: [i32; 3]) -> [std::ops::RangeInclusive<usize>; 3] {
    std::array::from_fn(|a| match off[a] {
        -1 => l.size[a]..=l.size[a],
        0 => 1..=l.size[a],
        _ => 1..=1,
    })
}

// SAFETY: a block is shared between the worker threads of the step graph. Everything except the two
// fields is read-only while the graph runs; the fields are written only (a) through raw pointers to ghost
// cells and wall cells by the exchange and boundary tasks and (b) through `field_mut` by the sweep, which
// writes the field nobody else reads during that step. The graph's edges order every pair of tasks whose
// accesses to the same elements conflict (documented in `pipeline`).
unsafe impl<T: Real> Sync for Block<T> {}

/// The copy plan of the ghost region at offset `off` (see [`GhostRecv::runs`]): per direction of `dirs`,
/// the runs of ghost cells g that are fluid and whose g + c_q is an interior fluid cell, row by row.
fn ghost_runs(l: &Layout, fl: &[u8], off: [i32; 3], dirs: &[usize]) -> (Vec<GhostRun>, Vec<u32>) {
    let [gx, gy, gz] = ghost_ranges(l, off);
    let [sx, sy, sz] = source_ranges(l, off);
    let full = l.full();
    let interior = |c: [i64; 3]| (0..3).all(|a| c[a] >= 1 && c[a] <= full[a] as i64 - 2);
    let (mut runs, mut starts) = (Vec::new(), Vec::with_capacity(dirs.len() + 1));
    for &q in dirs {
        starts.push(runs.len() as u32);
        for (zg, zs) in gz.clone().zip(sz.clone()) {
            for (yg, ys) in gy.clone().zip(sy.clone()) {
                let mut open: Option<GhostRun> = None;
                for (xg, xs) in gx.clone().zip(sx.clone()) {
                    let t = [
                        xg as i64 + C[q][0] as i64,
                        yg as i64 + C[q][1] as i64,
                        zg as i64 + C[q][2] as i64,
                    ];
                    let needed = fl[l.idx(xg, yg, zg)] & flags::FLUID != 0
                        && interior(t)
                        && fl[l.idx(t[0] as usize, t[1] as usize, t[2] as usize)] & flags::FLUID != 0;
                    match (&mut open, needed) {
                        (Some(r), true) => r.len += 1,
                        (None, true) => {
                            open = Some(GhostRun {
                                src: l.idx(xs, ys, zs) as u32,
                                dst: l.idx(xg, yg, zg) as u32,
                                len: 1,
                            })
                        }
                        (Some(_), false) => runs.extend(open.take()),
                        (None, false) => {}
                    }
                }
                runs.extend(open);
            }
        }
    }
    starts.push(runs.len() as u32);
    (runs, starts)
}

/// The ghost cells of the region at neighbour offset `off`, z slowest.
pub fn ghost_region(l: &Layout, off: [i32; 3]) -> impl Iterator<Item = (usize, usize, usize)> {
    let [rx, ry, rz] = ghost_ranges(l, off);
    rz.flat_map(move |z| {
        let rx = rx.clone();
        ry.clone().flat_map(move |y| rx.clone().map(move |x| (x, y, z)))
    })
}
