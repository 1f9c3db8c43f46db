//! Reading one block in the format of [`super`] back into a simulation.

use super::{
    checksum, peek_header, FormatError, BODIES, BODY_BYTES, BODY_FORCE_BYTES, FLAGS, HEADER_LEN, OVERLAY,
    PARTICLE_STATE, PDF,
};
use crate::physics::particle_cells::{BodyForce, LinkCell, MapBody, MapWork, ParticleCells};
use crate::physics::particles::{Delta, OwnedImpulse, Published, Work};
use crate::physics::simulation::Simulation;
use crate::util::bytes::{ReadError, Reader};
use blockflow_kernels::d3q19::Q;
use blockflow_kernels::rigid::Body;
use blockflow_kernels::sweep::Segment;
use blockflow_kernels::{Layout, Real};
use glam::{DQuat, DVec3};

impl From<ReadError> for FormatError {
    fn from(e: ReadError) -> Self {
        FormatError::Malformed(e.0)
    }
}

/// What the block format reads beyond the primitives: vectors, cells, bodies.
pub(super) trait BlockReader {
    /// A vector of 3 × f64.
    fn v3(&mut self) -> Result<DVec3, ReadError>;
    /// A layout-free cell index as an element index; `interior` asks for an interior cell.
    fn cell(&mut self, l: &Layout, interior: bool) -> Result<usize, ReadError>;
    /// Element index of the layout-free cell index `c`.
    fn cell_at(&self, c: u32, l: &Layout, interior: bool) -> Result<usize, ReadError>;
    /// A body with every field.
    fn body(&mut self) -> Result<Body, ReadError>;
    /// A body force (id, force, torque).
    fn body_force(&mut self) -> Result<BodyForce, ReadError>;
}

impl BlockReader for Reader<'_> {
    fn v3(&mut self) -> Result<DVec3, ReadError> {
        Ok(DVec3::new(self.f64()?, self.f64()?, self.f64()?))
    }
    fn cell(&mut self, l: &Layout, interior: bool) -> Result<usize, ReadError> {
        let c = self.u32()?;
        self.cell_at(c, l, interior)
    }
    fn cell_at(&self, c: u32, l: &Layout, interior: bool) -> Result<usize, ReadError> {
        let c = c as usize;
        let [fx, fy, fz] = l.full();
        let (x, y, z) = (c % fx, (c / fx) % fy, c / (fx * fy));
        let inside = |v: usize, n: usize| if interior { (1..n - 1).contains(&v) } else { v < n };
        if !(inside(x, fx) && inside(y, fy) && inside(z, fz)) {
            return Err(self.bad(format_args!("cell {c} outside the block")));
        }
        Ok(l.idx(x, y, z))
    }
    fn body(&mut self) -> Result<Body, ReadError> {
        let id = self.u64()?;
        let position = self.v3()?;
        let orientation = DQuat::from_xyzw(self.f64()?, self.f64()?, self.f64()?, self.f64()?);
        Ok(Body {
            id,
            position,
            orientation,
            velocity: self.v3()?,
            angular_velocity: self.v3()?,
            radius: self.f64()?,
            density: self.f64()?,
            fixed: self.bool()?,
            force: self.v3()?,
            torque: self.v3()?,
            force_prev: self.v3()?,
            torque_prev: self.v3()?,
        })
    }
    fn body_force(&mut self) -> Result<BodyForce, ReadError> {
        Ok(BodyForce {
            id: self.u64()?,
            force: self.v3()?,
            torque: self.v3()?,
        })
    }
}

/// A PDF value from its little-endian bytes (exact bits).
#[inline]
fn real_from_le<T: Real>(b: &[u8]) -> T {
    assert_eq!(
        std::mem::size_of::<T>(),
        T::BYTES,
        "Real is implemented for f32 and f64 only"
    );
    if T::BYTES == 8 {
        let v = u64::from_le_bytes(b.try_into().expect("8 bytes"));
        // SAFETY: T is f64 (8 bytes, every bit pattern valid), as the assertion above and `Real` say.
        unsafe { std::mem::transmute_copy::<u64, T>(&v) }
    } else {
        assert_eq!(T::BYTES, 4, "Real is implemented for f32 and f64 only");
        let v = u32::from_le_bytes(b.try_into().expect("4 bytes"));
        // SAFETY: T is f32 (4 bytes, every bit pattern valid).
        unsafe { std::mem::transmute_copy::<u32, T>(&v) }
    }
}

fn read_overlay(r: &mut Reader, l: &Layout) -> Result<ParticleCells, FormatError> {
    let [fx, fy, fz] = l.full();
    let mut pc = ParticleCells::default();
    if r.bool()? {
        let runs = r.count(12)?;
        let mut owner = vec![0u64; l.slots()];
        let (mut x, mut y, mut z) = (0usize, 0usize, 0usize);
        let total = fx * fy * fz;
        let mut seen = 0usize;
        for _ in 0..runs {
            let v = r.u64()?;
            let n = r.u32()? as usize;
            if n > total - seen {
                return Err(r.bad("owner runs cover more than the block").into());
            }
            seen += n;
            for _ in 0..n {
                owner[l.idx(x, y, z)] = v;
                x += 1;
                if x == fx {
                    x = 0;
                    y += 1;
                    if y == fy {
                        y = 0;
                        z += 1;
                    }
                }
            }
        }
        if seen != total {
            return Err(r.bad(format_args!("owner runs cover {seen} of {total} cells")).into());
        }
        pc.owner = owner;
    }
    pc.set_owned(r.bool()?);
    pc.fluid_cells = r.u64()? as usize;
    pc.near_particle_cells = r.u64()? as usize;
    pc.near_boundary_cells = r.u64()? as usize;
    let n = r.count(8)?;
    pc.segments.reserve(n);
    for _ in 0..n {
        let start = r.cell(l, true)?;
        let len = r.u32()? as usize;
        if len == 0 || l.coords(start)[0] + len > fx - 1 {
            return Err(r.bad(format_args!("segment of {len} cells leaves its row")).into());
        }
        pc.segments.push(Segment { start, len });
    }
    let n = r.count(88)?;
    pc.bodies.reserve(n);
    for _ in 0..n {
        pc.bodies.push(MapBody {
            id: r.u64()?,
            position: r.v3()?,
            velocity: r.v3()?,
            angular_velocity: r.v3()?,
            radius: r.f64()?,
        });
    }
    let n = r.count(8)?;
    pc.link_cells.reserve(n);
    for _ in 0..n {
        let cell = r.cell(l, true)? as u32;
        let dirs = r.u32()?;
        // Bits 1..=18: the D3Q19 directions other than rest.
        if dirs == 0 || dirs & !(((1u32 << Q) - 1) & !1) != 0 {
            return Err(r.bad(format_args!("link cell with directions {dirs:#x}")).into());
        }
        let xyz = l.coords(cell as usize).map(|c| c as u32);
        // `second_fluid` follows from the owners and the block's flags once the block is known.
        pc.link_cells.push(LinkCell {
            cell,
            dirs,
            second_fluid: 0,
            xyz,
        });
    }
    for list in [&mut pc.turned, &mut pc.covered] {
        let n = r.count(12)?;
        list.reserve(n);
        for _ in 0..n {
            let i = r.cell(l, true)?;
            list.push((i, r.u64()?));
        }
    }
    for list in [&mut pc.exchanged, &mut pc.forces] {
        let n = r.count(BODY_FORCE_BYTES)?;
        list.reserve(n);
        for _ in 0..n {
            list.push(r.body_force()?);
        }
    }
    pc.map_work = MapWork {
        active: r.bool()?,
        box_cells: r.u64()?,
        rows_derived: r.u64()?,
    };
    r.finish()?;
    Ok(pc)
}

fn read_bodies(r: &mut Reader, blocks: usize) -> Result<Published, FormatError> {
    let list = read_listed(r, blocks)?;
    r.finish()?;
    Ok(list)
}

/// A published list's bodies and their home blocks (below `blocks`), as [`super::write`] puts them.
pub(super) fn read_listed(r: &mut Reader, blocks: usize) -> Result<Published, FormatError> {
    let n = r.count(BODY_BYTES + 4)?;
    let mut list = Published {
        bodies: Vec::with_capacity(n),
        homes: Vec::with_capacity(n),
        owned: Vec::new(),
        counts: Vec::new(),
    };
    for _ in 0..n {
        list.bodies.push(r.body()?);
        let h = r.u32()?;
        if h as usize >= blocks {
            return Err(r.bad(format_args!("home block {h} of {blocks}")).into());
        }
        list.homes.push(h);
    }
    list.owned = read_list(r, 40, |r| {
        Ok(OwnedImpulse {
            a: r.u64()?,
            b: r.u64()?,
            impulse: r.v3()?,
        })
    })?;
    list.counts = read_list(r, 4, |r| r.u32())?;
    Ok(list)
}

/// A count, then that many items of at least `bytes` bytes each, read by `item`.
fn read_list<T>(
    r: &mut Reader,
    bytes: usize,
    mut item: impl FnMut(&mut Reader) -> Result<T, ReadError>,
) -> Result<Vec<T>, FormatError> {
    let n = r.count(bytes)?;
    let mut v = Vec::with_capacity(n);
    for _ in 0..n {
        v.push(item(r)?);
    }
    Ok(v)
}

fn read_work(r: &mut Reader) -> Result<Work, FormatError> {
    let locals = r.u32()? as usize;
    let n = r.count(BODY_BYTES)?;
    let mut bodies = Vec::with_capacity(n);
    for _ in 0..n {
        bodies.push(r.body()?);
    }
    if locals > bodies.len() {
        return Err(r
            .bad(format_args!("{locals} locals among {} bodies", bodies.len()))
            .into());
    }
    let n = r.count(56)?;
    let mut deltas = Vec::with_capacity(n);
    for _ in 0..n {
        deltas.push(Delta {
            id: r.u64()?,
            dv: r.v3()?,
            dw: r.v3()?,
        });
    }
    let w = Work {
        bodies,
        locals,
        deltas,
        contact_list: Vec::new(),
        targets: Vec::new(),
        solved: Vec::new(),
        owned: Vec::new(),
        origins: Vec::new(),
        jacobi: Default::default(),
        contacts: r.u64()? as usize,
        max_penetration: r.f64()?,
        contacts_total: r.u64()?,
        max_penetration_total: r.f64()?,
        contacts_step: r.u64()?,
        seen_step: r.u64()?,
        scanned_step: r.u64()?,
        shadow_scratch: Vec::new(),
        local_scratch: Vec::new(),
        // Not kept in a checkpoint: the first sub-step after a restore finds the candidates again.
        candidates: Default::default(),
        gathered: Vec::new(),
        same_bodies: false,
    };
    r.finish()?;
    Ok(w)
}

/// Checks the header, the checksum and that the bytes are block `id` of `sim` as it is now; returns the
/// sections by name.
fn open<'a, T: Real>(sim: &Simulation<T>, id: usize, bytes: &'a [u8]) -> Result<Vec<(&'a str, &'a [u8])>, FormatError> {
    let h = peek_header(bytes)?;
    if bytes.len() < h.total_len {
        return Err(FormatError::Truncated {
            needed: h.total_len,
            found: bytes.len(),
        });
    }
    if bytes.len() > h.total_len {
        return Err(FormatError::Mismatch(format!(
            "{} bytes follow the block's {} (pass exactly one block)",
            bytes.len() - h.total_len,
            h.total_len
        )));
    }
    let body = &bytes[..h.total_len - 8];
    let stored = u64::from_le_bytes(bytes[h.total_len - 8..].try_into().expect("8 bytes"));
    let computed = checksum(body);
    if stored != computed {
        return Err(FormatError::Checksum { stored, computed });
    }
    let name = |b: u8| match b {
        4 => "f32",
        8 => "f64",
        _ => "unknown",
    };
    if h.precision_bytes as usize != T::BYTES {
        return Err(FormatError::Mismatch(format!(
            "precision: the bytes hold {} PDFs, the simulation is {}",
            name(h.precision_bytes),
            T::NAME
        )));
    }
    if id >= sim.blocks.len() {
        return Err(FormatError::Mismatch(format!(
            "block {id} does not exist ({} blocks)",
            sim.blocks.len()
        )));
    }
    if h.id != id {
        return Err(FormatError::Mismatch(format!(
            "the bytes hold block {}, not block {id}",
            h.id
        )));
    }
    if h.block_size != sim.domain.block_size {
        return Err(FormatError::Mismatch(format!(
            "block size {:?} in the bytes, {:?} in the simulation",
            h.block_size, sim.domain.block_size
        )));
    }
    if h.step != sim.step {
        return Err(FormatError::Mismatch(format!(
            "the bytes hold the state after step {}, the simulation is at step {}",
            h.step, sim.step
        )));
    }
    let mut r = Reader::new(&body[HEADER_LEN - 4..], "table");
    let n = r.count(9)?;
    let mut table = Vec::with_capacity(n);
    for _ in 0..n {
        let len = r.u8()? as usize;
        let name =
            std::str::from_utf8(r.take(len)?).map_err(|_| FormatError::from(r.bad("section name is not UTF-8")))?;
        table.push((name, r.u64()?));
    }
    let mut at = HEADER_LEN - 4 + r.pos();
    let mut out = Vec::with_capacity(n);
    for (name, len) in table {
        let len = usize::try_from(len).unwrap_or(usize::MAX);
        if len > body.len() - at {
            return Err(FormatError::Malformed(format!("section {name} runs past the end")));
        }
        out.push((name, &body[at..at + len]));
        at += len;
    }
    if at != body.len() {
        return Err(FormatError::Malformed(format!(
            "{} bytes after the last section",
            body.len() - at
        )));
    }
    Ok(out)
}

/// Rebuilds block `id` of `sim` from `bytes` (one block as [`encode_block`] wrote it) on the calling
/// thread: fresh allocations for both PDF fields, written here first (first touch: this is how a block
/// moves to a thread of its new owner), the current field's interior, the particle overlay and the
/// block's particle state (published list of the current parity, last rigid-body result) replaced; the
/// other parity's published list is cleared. Ghost layers are left to the next step's exchange. On an
/// error nothing is changed.
///
/// # Safety
/// No task runs; no other thread touches block `id` or its particle state concurrently (other blocks may
/// be decoded concurrently on other threads).
pub unsafe fn decode_block<T: Real>(sim: &Simulation<T>, id: usize, bytes: &[u8]) -> Result<(), FormatError> {
    let sections = open(sim, id, bytes)?;
    let get = |name: &str| sections.iter().find(|s| s.0 == name).map(|s| s.1);
    let blk = &sim.blocks[id];
    let l = blk.layout;
    let p = sim.parity();
    // Flags: the same geometry.
    let [fx, fy, fz] = l.full();
    let flags = get(FLAGS).ok_or_else(|| FormatError::Malformed("no flags section".into()))?;
    if flags.len() != fx * fy * fz {
        return Err(FormatError::Malformed(format!(
            "flags section of {} bytes for {} cells",
            flags.len(),
            fx * fy * fz
        )));
    }
    for z in 0..fz {
        for y in 0..fy {
            let i = l.idx(0, y, z);
            let row = &flags[(z * fy + y) * fx..(z * fy + y + 1) * fx];
            if let Some(x) = (0..fx).find(|&x| row[x] != blk.flags[i + x]) {
                return Err(FormatError::Mismatch(format!(
                    "geometry: flag {:#04x} in the bytes, {:#04x} in block {id} at cell ({x}, {y}, {z}) (ghost layer = 0)",
                    row[x],
                    blk.flags[i + x]
                )));
            }
        }
    }
    // Particle sections.
    let overlay = match get(OVERLAY) {
        Some(s) => {
            if blk.fluid_cells == 0 {
                return Err(FormatError::Mismatch(format!(
                    "an overlay for block {id}, which has no fluid"
                )));
            }
            Some(read_overlay(&mut Reader::new(s, "overlay"), &l)?)
        }
        None => None,
    };
    let particle = match (&sim.particles, get(BODIES), get(PARTICLE_STATE)) {
        (Some(parts), Some(b), Some(w)) => Some((
            read_bodies(&mut Reader::new(b, "bodies"), parts.blocks.len())?,
            read_work(&mut Reader::new(w, "particle_state"))?,
        )),
        (None, None, None) => None,
        (Some(_), _, _) => {
            return Err(FormatError::Mismatch(
                "the simulation has particles, the bytes have no particle state".into(),
            ))
        }
        (None, _, _) => {
            return Err(FormatError::Mismatch(
                "the bytes carry particle state, the simulation has no particles".into(),
            ))
        }
    };
    // PDFs into fresh fields, first touched here (pull's other field only when the pattern has one).
    let mut cur = blk.fresh_field(p);
    let mut other = (blk.pattern.fields() == 2).then(|| blk.fresh_field(1 - p));
    match get(PDF) {
        Some(s) => {
            let [nx, ny, nz] = l.size;
            if blk.fluid_cells == 0 {
                return Err(FormatError::Mismatch(format!(
                    "PDFs for block {id}, which has no fluid"
                )));
            }
            if s.len() != Q * nx * ny * nz * T::BYTES {
                return Err(FormatError::Malformed(format!(
                    "pdf section of {} bytes for {} interior cells",
                    s.len(),
                    nx * ny * nz
                )));
            }
            if let Some(o) = other.as_mut() {
                o.data_mut().fill(T::ZERO);
            }
            let sl = *blk.slots(p);
            let data = cur.data_mut();
            data.fill(T::ZERO);
            let mut chunks = s.chunks_exact(T::BYTES);
            for q in 0..Q {
                for z in 1..=nz {
                    for y in 1..=ny {
                        let start = sl.at(q, l.idx(1, y, z));
                        for (v, c) in data[start..start + nx].iter_mut().zip(&mut chunks) {
                            *v = real_from_le::<T>(c);
                        }
                    }
                }
            }
        }
        None if blk.fluid_cells > 0 => {
            return Err(FormatError::Mismatch(format!(
                "no PDFs in the bytes for block {id}, which has fluid"
            )))
        }
        None => {}
    }
    if overlay.is_some() && sim.particles.is_none() {
        return Err(FormatError::Mismatch("an overlay without particles".into()));
    }
    // Commit.
    blk.replace_field(p, cur);
    if let Some(o) = other {
        blk.replace_field(1 - p, o);
    }
    let overlay = overlay.map(|mut pc| {
        crate::physics::coupling::mapping::derive_second_fluid(blk, &mut pc);
        pc
    });
    blk.replace_particle_cells(overlay);
    if let (Some(parts), Some((list, work))) = (&sim.particles, particle) {
        let pb = &parts.blocks[id];
        let par = parts.parity(sim.step);
        pb.replace_published(par, list);
        pb.replace_published(1 - par, Published::default());
        pb.replace_work(work);
    }
    Ok(())
}
