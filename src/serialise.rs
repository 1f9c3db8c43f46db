//! One block as bytes: the serialisation behind block migration between virtual processes, per-block
//! checkpoints and (one day) an MPI backend. [`encode_block`] writes the state of one block after
//! `sim.step` steps, [`decode_block`] rebuilds it in place, [`encoded_len`] prices it.
//!
//! # Format (version [`BLOCK_FORMAT_VERSION`]), all integers and floats little-endian
//!
//! | bytes | field |
//! |---|---|
//! | 5 | magic `b"BFBLK"` |
//! | u32 | format version |
//! | u64 | total length of the encoding, checksum included (so a truncated copy is told from a corrupt one) |
//! | u8 | precision of the PDFs: 4 = f32, 8 = f64 |
//! | u64 | block id |
//! | 3 × u32 | block size (interior cells along x, y, z) |
//! | u64 | step: the state is the one after this many steps |
//! | u32 | number of sections |
//! | per section | name length u8, name (ASCII), payload length u64 (a reader skips names it does not know) |
//! | ... | the payloads, in table order |
//! | u64 | checksum of every byte before it (see [`checksum`]) |
//!
//! Cell indices below are *layout-free*: `c = x + (nx+2)·(y + (ny+2)·z)` over the ghost-inclusive grid
//! (`0` and `n+1` are the ghost layers), written as u32; the in-memory padding of rows never travels.
//! Vectors are 3 × f64 (x, y, z), quaternions 4 × f64 (x, y, z, w); every f64 is its exact bits.
//!
//! Sections:
//! - `pdf` (only for a block with fluid cells): the post-collision PDFs of the *interior* cells of the
//!   current field (`fields[step % 2]`), zero-centred as stored (`f_q − w_q`), in the precision of the
//!   header: direction q = 0..19 slowest, then z, y, x fastest (x, y, z = 1..=n). Cells that are not fluid
//!   now (walls, cells covered by a particle) are written as 0: their values are dead (the next step's
//!   boundary passes and reconstruction rewrite every one that is read), and zeroing them makes the
//!   bytes a function of the live state only. No ghost layer: the next step's exchange fills it. The
//!   other field is not carried either: the next step overwrites every cell of it that is ever read.
//! - `flags`: the flag byte of every cell *with* its ghost layer, x fastest. Flags are static geometry; the
//!   decoder does not write them but checks them against the block it decodes into (`Mismatch`).
//! - `overlay` (only if the block has a particle overlay): everything of [`ParticleCells`] except its
//!   scratch buffers. `owner` (read by the next mapping to find the cells that turn fluid, and by the
//!   reconstruction) run-length coded over the ghost-inclusive cells; `owned`; the fluid-cell counts;
//!   segments, mapped bodies, links, turned and covered cells, exchanged momentum and the last forces.
//!   Most of it is rebuilt by the next `map` task, but not all blocks get one (fixed bodies are mapped
//!   once; inactive blocks keep their overlay), the checksum and Table 1 read segments and counts
//!   between steps, and total forces read `forces`: carrying it all keeps every reader exact.
//! - `bodies` (with particles): the block's published list of the current parity — the bodies this block
//!   published after the last sub-step, each with every [`Body`] field (force/torque and the averaging
//!   history `force_prev`/`torque_prev` included) and its home block (u32). These are the block's local
//!   bodies (a body that just crossed a face is published by its old home, which is where the next
//!   sub-step looks for it). Each body lives in exactly one block's list, so the lists of all blocks
//!   together are all bodies.
//! - `particle_state` (with particles): the block's last rigid-body result ([`Work`]): local and shadow
//!   bodies, velocity changes, and the contact counters (K of Table 1, statistics for the summary).
//!
//! Not carried, on purpose: the ghost layers and the other PDF field (rewritten before they are read;
//! the continuation tests prove it bitwise), the static block structure (segments, links, receive lists,
//! neighbour lists and planes of the rigid-body bookkeeping: rebuilt from the geometry, which `flags`
//! checks), the other parity's published list (stale: overwritten by the next sub-step before anyone
//! reads it; the decoder clears it), and the global particle state in [`crate::particles::Particles`]:
//! `active` (recomputed before every graph run), `counters` (run totals) and pending errors. A
//! checkpoint must store `counters` beside its blocks if it wants them continued.

use crate::block::Block;
use crate::coupling::{BodyForce, MapBody, ParticleCells, ParticleLink};
use crate::particles::{Delta, Published, Work};
use crate::sim::Simulation;
use blockflow_kernels::d3q19::Q;
use blockflow_kernels::rigid::Body;
use blockflow_kernels::sweep::Segment;
use blockflow_kernels::{Layout, Real};
use glam::{DQuat, DVec3};
use std::fmt;

/// Version of the block format written by [`encode_block`]; the decoder accepts only this one.
pub const BLOCK_FORMAT_VERSION: u32 = 1;
/// First bytes of every encoded block.
pub const MAGIC: [u8; 5] = *b"BFBLK";
/// Bytes of the fixed header (before the section table).
const HEADER_LEN: usize = 5 + 4 + 8 + 1 + 8 + 12 + 8 + 4;
/// Section names.
const PDF: &str = "pdf";
const FLAGS: &str = "flags";
const OVERLAY: &str = "overlay";
const BODIES: &str = "bodies";
const PARTICLE_STATE: &str = "particle_state";

/// Why bytes could not be decoded into a block. Decoding checks everything before it changes the block,
/// so after an error the block is as it was.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FormatError {
    /// Fewer bytes than the header announces (or than a header needs).
    Truncated {
        /// Bytes needed.
        needed: usize,
        /// Bytes given.
        found: usize,
    },
    /// The bytes do not start with [`MAGIC`].
    BadMagic,
    /// Written by another format version.
    Version {
        /// Version in the bytes.
        found: u32,
        /// The version this build reads.
        expected: u32,
    },
    /// The checksum does not match the content (a flipped or lost byte).
    Checksum {
        /// Checksum stored in the bytes.
        stored: u64,
        /// Checksum of the content.
        computed: u64,
    },
    /// Valid bytes for another block, precision, block size, step, geometry or particle setting.
    Mismatch(String),
    /// A section is inconsistent although the checksum matches (a writer bug or crafted input).
    Malformed(String),
}

impl fmt::Display for FormatError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FormatError::Truncated { needed, found } => {
                write!(f, "encoded block truncated: {found} bytes, {needed} needed")
            }
            FormatError::BadMagic => write!(f, "not an encoded block (the magic bytes BFBLK are missing)"),
            FormatError::Version { found, expected } => {
                write!(
                    f,
                    "encoded block has format version {found}; this build reads version {expected}"
                )
            }
            FormatError::Checksum { stored, computed } => write!(
                f,
                "encoded block corrupt: checksum {stored:016x} stored, {computed:016x} computed"
            ),
            FormatError::Mismatch(m) => write!(f, "encoded block does not fit: {m}"),
            FormatError::Malformed(m) => write!(f, "encoded block malformed: {m}"),
        }
    }
}

impl std::error::Error for FormatError {}

/// The fixed header of an encoded block.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BlockHeader {
    /// Format version.
    pub version: u32,
    /// Total length of the encoding in bytes (checksum included).
    pub total_len: usize,
    /// Bytes per PDF value: 4 (f32) or 8 (f64).
    pub precision_bytes: u8,
    /// Block id.
    pub id: usize,
    /// Interior cells along x, y, z.
    pub block_size: [usize; 3],
    /// Steps taken when the block was encoded.
    pub step: u64,
}

/// The checksum of the format: FNV-1a 64 over little-endian 8-byte words (the tail zero-padded to a
/// word), then the byte length folded in the same way: `h = 0xcbf29ce484222325`, per word
/// `h = (h ^ w) · 0x100000001b3` (wrapping). Any change of a single word changes it.
pub fn checksum(bytes: &[u8]) -> u64 {
    const PRIME: u64 = 0x0000_0100_0000_01b3;
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut words = bytes.chunks_exact(8);
    for w in &mut words {
        h = (h ^ u64::from_le_bytes(w.try_into().expect("8 bytes"))).wrapping_mul(PRIME);
    }
    let rest = words.remainder();
    if !rest.is_empty() {
        let mut w = [0u8; 8];
        w[..rest.len()].copy_from_slice(rest);
        h = (h ^ u64::from_le_bytes(w)).wrapping_mul(PRIME);
    }
    (h ^ bytes.len() as u64).wrapping_mul(PRIME)
}

/// Reads the fixed header (magic, version, lengths, block id, size, step) without checking the rest.
pub fn peek_header(bytes: &[u8]) -> Result<BlockHeader, FormatError> {
    if bytes.len() < MAGIC.len() {
        return Err(FormatError::Truncated {
            needed: HEADER_LEN,
            found: bytes.len(),
        });
    }
    if bytes[..MAGIC.len()] != MAGIC {
        return Err(FormatError::BadMagic);
    }
    if bytes.len() < MAGIC.len() + 4 {
        return Err(FormatError::Truncated {
            needed: HEADER_LEN,
            found: bytes.len(),
        });
    }
    let version = u32::from_le_bytes(bytes[5..9].try_into().expect("4 bytes"));
    if version != BLOCK_FORMAT_VERSION {
        return Err(FormatError::Version {
            found: version,
            expected: BLOCK_FORMAT_VERSION,
        });
    }
    if bytes.len() < HEADER_LEN {
        return Err(FormatError::Truncated {
            needed: HEADER_LEN,
            found: bytes.len(),
        });
    }
    let mut r = Reader::new(&bytes[9..HEADER_LEN], "header");
    let total = r.u64()?;
    let precision_bytes = r.u8()?;
    let id = r.u64()?;
    let size = [r.u32()? as usize, r.u32()? as usize, r.u32()? as usize];
    let step = r.u64()?;
    let total_len = usize::try_from(total).map_err(|_| FormatError::Malformed(format!("total length {total}")))?;
    if total_len < HEADER_LEN + 8 {
        return Err(FormatError::Malformed(format!(
            "total length {total_len} is shorter than a header"
        )));
    }
    Ok(BlockHeader {
        version,
        total_len,
        precision_bytes,
        id: id as usize,
        block_size: size,
        step,
    })
}

// ---------------------------------------------------------------------------------------------------
// Writing

/// Where encoded bytes go: a byte vector, or a counter for [`encoded_len`].
trait Sink {
    fn put(&mut self, b: &[u8]);
    /// Announces `n` bytes of bulk data; returns true when the sink only counts (the caller skips them).
    fn bulk(&mut self, n: usize) -> bool;
}

impl Sink for Vec<u8> {
    fn put(&mut self, b: &[u8]) {
        self.extend_from_slice(b);
    }
    fn bulk(&mut self, n: usize) -> bool {
        self.reserve(n);
        false
    }
}

struct Counter(usize);

impl Sink for Counter {
    fn put(&mut self, b: &[u8]) {
        self.0 += b.len();
    }
    fn bulk(&mut self, n: usize) -> bool {
        self.0 += n;
        true
    }
}

fn put_u8(s: &mut impl Sink, v: u8) {
    s.put(&[v]);
}
fn put_u32(s: &mut impl Sink, v: u32) {
    s.put(&v.to_le_bytes());
}
fn put_u64(s: &mut impl Sink, v: u64) {
    s.put(&v.to_le_bytes());
}
fn put_f64(s: &mut impl Sink, v: f64) {
    s.put(&v.to_bits().to_le_bytes());
}
fn put_v3(s: &mut impl Sink, v: DVec3) {
    for x in v.to_array() {
        put_f64(s, x);
    }
}
fn put_count(s: &mut impl Sink, n: usize) {
    put_u32(s, u32::try_from(n).expect("fewer than 2^32 entries per section"));
}

/// Layout-free cell index of element index `i`.
fn cell_of(l: &Layout, i: usize) -> u32 {
    let [x, y, z] = l.coords(i);
    let [fx, fy, _] = l.full();
    u32::try_from(x + fx * (y + fy * z)).expect("block below 2^32 cells")
}

fn put_body(s: &mut impl Sink, b: &Body) {
    put_u64(s, b.id);
    put_v3(s, b.position);
    for x in b.orientation.to_array() {
        put_f64(s, x);
    }
    put_v3(s, b.velocity);
    put_v3(s, b.angular_velocity);
    put_f64(s, b.radius);
    put_f64(s, b.density);
    put_u8(s, b.fixed as u8);
    put_v3(s, b.force);
    put_v3(s, b.torque);
    put_v3(s, b.force_prev);
    put_v3(s, b.torque_prev);
}
const BODY_BYTES: usize = 8 + 8 * (3 + 4 + 3 + 3 + 1 + 1) + 1 + 8 * 12;

fn put_body_force(s: &mut impl Sink, f: &BodyForce) {
    put_u64(s, f.id);
    put_v3(s, f.force);
    put_v3(s, f.torque);
}
const BODY_FORCE_BYTES: usize = 8 + 48;

fn write_pdf<T: Real>(s: &mut impl Sink, b: &Block<T>, p: usize) {
    let l = b.layout;
    let [nx, ny, nz] = l.size;
    if s.bulk(Q * nx * ny * nz * T::BYTES) {
        return;
    }
    let data = b.field(p).data();
    let segs = b.fluid_segments();
    let zero = T::ZERO.bits().to_le_bytes();
    let mut row = Vec::with_capacity(nx * T::BYTES);
    for q in 0..Q {
        // Segments are sorted by cell (z, then y, then x): walk them along with the rows.
        let mut k = 0;
        for z in 1..=nz {
            for y in 1..=ny {
                let first = l.idx(1, y, z);
                row.clear();
                let mut x = first;
                while k < segs.len() && segs[k].start < first + nx {
                    let seg = segs[k];
                    for _ in x..seg.start {
                        row.extend_from_slice(&zero[..T::BYTES]);
                    }
                    let at = q * l.stride + seg.start;
                    for v in &data[at..at + seg.len] {
                        row.extend_from_slice(&v.bits().to_le_bytes()[..T::BYTES]);
                    }
                    x = seg.start + seg.len;
                    k += 1;
                }
                for _ in x..first + nx {
                    row.extend_from_slice(&zero[..T::BYTES]);
                }
                s.put(&row);
            }
        }
        debug_assert_eq!(k, segs.len());
    }
}

fn write_flags<T: Real>(s: &mut impl Sink, b: &Block<T>) {
    let l = b.layout;
    let [fx, fy, fz] = l.full();
    if s.bulk(fx * fy * fz) {
        return;
    }
    for z in 0..fz {
        for y in 0..fy {
            let i = l.idx(0, y, z);
            s.put(&b.flags[i..i + fx]);
        }
    }
}

fn write_overlay(s: &mut impl Sink, l: &Layout, pc: &ParticleCells) {
    let [fx, fy, fz] = l.full();
    if pc.owner.len() == l.sxy * fz {
        put_u8(s, 1);
        let mut runs: Vec<(u64, u32)> = Vec::new();
        for z in 0..fz {
            for y in 0..fy {
                let i = l.idx(0, y, z);
                for &o in &pc.owner[i..i + fx] {
                    match runs.last_mut() {
                        Some(r) if r.0 == o => r.1 += 1,
                        _ => runs.push((o, 1)),
                    }
                }
            }
        }
        put_count(s, runs.len());
        for (v, n) in runs {
            put_u64(s, v);
            put_u32(s, n);
        }
    } else {
        debug_assert!(pc.owner.is_empty(), "owner covers the ghost-inclusive block or nothing");
        put_u8(s, 0);
    }
    put_u8(s, pc.owned() as u8);
    put_u64(s, pc.fluid_cells as u64);
    put_u64(s, pc.near_particle_cells as u64);
    put_u64(s, pc.near_boundary_cells as u64);
    put_count(s, pc.segments.len());
    for seg in &pc.segments {
        put_u32(s, cell_of(l, seg.start));
        put_count(s, seg.len);
    }
    put_count(s, pc.bodies.len());
    for m in &pc.bodies {
        put_u64(s, m.id);
        put_v3(s, m.position);
        put_v3(s, m.velocity);
        put_v3(s, m.angular_velocity);
        put_f64(s, m.radius);
    }
    put_count(s, pc.links.len());
    for k in &pc.links {
        put_u32(s, cell_of(l, k.fluid));
        put_u8(s, k.q);
        put_u32(s, k.body);
        put_f64(s, k.delta);
        put_u32(s, k.second.map_or(u32::MAX, |i| cell_of(l, i)));
        put_v3(s, k.rel);
    }
    for list in [&pc.turned, &pc.covered] {
        put_count(s, list.len());
        for &(i, id) in list {
            put_u32(s, cell_of(l, i));
            put_u64(s, id);
        }
    }
    for list in [&pc.exchanged, &pc.forces] {
        put_count(s, list.len());
        for f in list {
            put_body_force(s, f);
        }
    }
}

fn write_bodies(s: &mut impl Sink, list: &Published) {
    debug_assert_eq!(list.bodies.len(), list.homes.len());
    put_count(s, list.bodies.len());
    for (b, &h) in list.bodies.iter().zip(&list.homes) {
        put_body(s, b);
        put_u32(s, h);
    }
}

fn write_work(s: &mut impl Sink, w: &Work) {
    put_count(s, w.locals);
    put_count(s, w.bodies.len());
    for b in &w.bodies {
        put_body(s, b);
    }
    put_count(s, w.deltas.len());
    for d in &w.deltas {
        put_u64(s, d.id);
        put_v3(s, d.dv);
        put_v3(s, d.dw);
    }
    put_u64(s, w.contacts as u64);
    put_f64(s, w.max_penetration);
    put_u64(s, w.contacts_total);
    put_f64(s, w.max_penetration_total);
    put_u64(s, w.contacts_step);
}

/// The sections block `id` of `sim` has, in the order they are written.
fn section_names<T: Real>(sim: &Simulation<T>, id: usize) -> Vec<&'static str> {
    let b = &sim.blocks[id];
    let mut names = Vec::with_capacity(5);
    if b.fluid_cells > 0 {
        names.push(PDF);
    }
    names.push(FLAGS);
    if b.particle_cells().is_some() {
        names.push(OVERLAY);
    }
    if sim.particles.is_some() {
        names.push(BODIES);
        names.push(PARTICLE_STATE);
    }
    names
}

fn write_section<T: Real>(s: &mut impl Sink, sim: &Simulation<T>, id: usize, name: &str) {
    let b = &sim.blocks[id];
    match name {
        PDF => write_pdf(s, b, sim.parity()),
        FLAGS => write_flags(s, b),
        OVERLAY => write_overlay(s, &b.layout, b.particle_cells().expect("listed only with an overlay")),
        BODIES => {
            let parts = sim.particles.as_ref().expect("listed only with particles");
            // SAFETY: the caller runs no task (encode_block's contract).
            write_bodies(s, unsafe { parts.blocks[id].published(parts.parity(sim.step)) })
        }
        PARTICLE_STATE => {
            let parts = sim.particles.as_ref().expect("listed only with particles");
            // SAFETY: as above.
            write_work(s, unsafe { parts.blocks[id].work() })
        }
        _ => unreachable!("unknown section {name}"),
    }
}

fn write_header<T: Real>(s: &mut impl Sink, sim: &Simulation<T>, id: usize, names: &[&str]) {
    s.put(&MAGIC);
    put_u32(s, BLOCK_FORMAT_VERSION);
    put_u64(s, 0); // total length, patched
    put_u8(s, T::BYTES as u8);
    put_u64(s, id as u64);
    for n in sim.domain.block_size {
        put_u32(s, n as u32);
    }
    put_u64(s, sim.step);
    put_count(s, names.len());
    for n in names {
        put_u8(s, n.len() as u8);
        s.put(n.as_bytes());
        put_u64(s, 0); // payload length, patched
    }
}

/// Serialises block `id` of `sim` (its state after `sim.step` steps) and appends it to `out`. Same state,
/// same bytes. Call between graph runs (no task may run).
pub fn encode_block<T: Real>(sim: &Simulation<T>, id: usize, out: &mut Vec<u8>) {
    let start = out.len();
    let names = section_names(sim, id);
    write_header(out, sim, id, &names);
    let mut table = start + HEADER_LEN;
    for name in &names {
        let at = out.len();
        write_section(out, sim, id, name);
        let len = (out.len() - at) as u64;
        let slot = table + 1 + name.len();
        out[slot..slot + 8].copy_from_slice(&len.to_le_bytes());
        table = slot + 8;
    }
    let total = (out.len() - start + 8) as u64;
    out[start + 9..start + 17].copy_from_slice(&total.to_le_bytes());
    let sum = checksum(&out[start..]);
    out.extend_from_slice(&sum.to_le_bytes());
}

/// The number of bytes [`encode_block`] would write for block `id`, without writing them (for pricing a
/// migration). Scans the particle overlay; the PDFs and flags are priced from the block size.
pub fn encoded_len<T: Real>(sim: &Simulation<T>, id: usize) -> usize {
    let names = section_names(sim, id);
    let mut c = Counter(0);
    write_header(&mut c, sim, id, &names);
    for name in &names {
        write_section(&mut c, sim, id, name);
    }
    c.0 + 8
}

// ---------------------------------------------------------------------------------------------------
// Reading

struct Reader<'a> {
    b: &'a [u8],
    pos: usize,
    section: &'static str,
}

impl<'a> Reader<'a> {
    fn new(b: &'a [u8], section: &'static str) -> Self {
        Reader { b, pos: 0, section }
    }
    fn bad(&self, what: impl fmt::Display) -> FormatError {
        FormatError::Malformed(format!("section {}: {what}", self.section))
    }
    fn take(&mut self, n: usize) -> Result<&'a [u8], FormatError> {
        if self.b.len() - self.pos < n {
            return Err(self.bad(format_args!("ends after {} of {} bytes", self.b.len(), self.pos + n)));
        }
        let s = &self.b[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }
    fn u8(&mut self) -> Result<u8, FormatError> {
        Ok(self.take(1)?[0])
    }
    fn u32(&mut self) -> Result<u32, FormatError> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into().expect("4 bytes")))
    }
    fn u64(&mut self) -> Result<u64, FormatError> {
        Ok(u64::from_le_bytes(self.take(8)?.try_into().expect("8 bytes")))
    }
    fn f64(&mut self) -> Result<f64, FormatError> {
        Ok(f64::from_bits(self.u64()?))
    }
    fn v3(&mut self) -> Result<DVec3, FormatError> {
        Ok(DVec3::new(self.f64()?, self.f64()?, self.f64()?))
    }
    fn bool(&mut self) -> Result<bool, FormatError> {
        match self.u8()? {
            0 => Ok(false),
            1 => Ok(true),
            v => Err(self.bad(format_args!("flag byte {v}"))),
        }
    }
    /// An entry count, checked against the bytes left (each entry takes at least `entry` bytes).
    fn count(&mut self, entry: usize) -> Result<usize, FormatError> {
        let n = self.u32()? as usize;
        if n.saturating_mul(entry) > self.b.len() - self.pos {
            return Err(self.bad(format_args!("{n} entries of {entry} bytes do not fit")));
        }
        Ok(n)
    }
    fn finish(&self) -> Result<(), FormatError> {
        if self.pos != self.b.len() {
            return Err(self.bad(format_args!("{} bytes left over", self.b.len() - self.pos)));
        }
        Ok(())
    }
    /// A layout-free cell index as an element index; `interior` asks for an interior cell.
    fn cell(&mut self, l: &Layout, interior: bool) -> Result<usize, FormatError> {
        let c = self.u32()?;
        self.cell_at(c, l, interior)
    }
    /// Element index of the layout-free cell index `c`.
    fn cell_at(&self, c: u32, l: &Layout, interior: bool) -> Result<usize, FormatError> {
        let c = c as usize;
        let [fx, fy, fz] = l.full();
        let (x, y, z) = (c % fx, (c / fx) % fy, c / (fx * fy));
        let inside = |v: usize, n: usize| if interior { (1..n - 1).contains(&v) } else { v < n };
        if !(inside(x, fx) && inside(y, fy) && inside(z, fz)) {
            return Err(self.bad(format_args!("cell {c} outside the block")));
        }
        Ok(l.idx(x, y, z))
    }
    fn body(&mut self) -> Result<Body, FormatError> {
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
    fn body_force(&mut self) -> Result<BodyForce, FormatError> {
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
        let mut owner = vec![0u64; l.sxy * fz];
        let (mut x, mut y, mut z) = (0usize, 0usize, 0usize);
        let total = fx * fy * fz;
        let mut seen = 0usize;
        for _ in 0..runs {
            let v = r.u64()?;
            let n = r.u32()? as usize;
            if n > total - seen {
                return Err(r.bad("owner runs cover more than the block"));
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
            return Err(r.bad(format_args!("owner runs cover {seen} of {total} cells")));
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
            return Err(r.bad(format_args!("segment of {len} cells leaves its row")));
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
    let n = r.count(45)?;
    pc.links.reserve(n);
    for _ in 0..n {
        let fluid = r.cell(l, true)?;
        let q = r.u8()?;
        let body = r.u32()?;
        let delta = r.f64()?;
        let second = match r.u32()? {
            u32::MAX => None,
            c => Some(r.cell_at(c, l, false)?),
        };
        if q == 0 || q as usize >= Q || body as usize >= pc.bodies.len() {
            return Err(r.bad(format_args!("link with direction {q} into body slot {body}")));
        }
        pc.links.push(ParticleLink {
            fluid,
            q,
            body,
            delta,
            second,
            rel: r.v3()?,
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
    r.finish()?;
    Ok(pc)
}

fn read_bodies(r: &mut Reader, blocks: usize) -> Result<Published, FormatError> {
    let n = r.count(BODY_BYTES + 4)?;
    let mut list = Published {
        bodies: Vec::with_capacity(n),
        homes: Vec::with_capacity(n),
    };
    for _ in 0..n {
        list.bodies.push(r.body()?);
        let h = r.u32()?;
        if h as usize >= blocks {
            return Err(r.bad(format_args!("home block {h} of {blocks}")));
        }
        list.homes.push(h);
    }
    r.finish()?;
    Ok(list)
}

fn read_work(r: &mut Reader) -> Result<Work, FormatError> {
    let locals = r.u32()? as usize;
    let n = r.count(BODY_BYTES)?;
    let mut bodies = Vec::with_capacity(n);
    for _ in 0..n {
        bodies.push(r.body()?);
    }
    if locals > bodies.len() {
        return Err(r.bad(format_args!("{locals} locals among {} bodies", bodies.len())));
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
        contacts: r.u64()? as usize,
        max_penetration: r.f64()?,
        contacts_total: r.u64()?,
        max_penetration_total: r.f64()?,
        contacts_step: r.u64()?,
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
        let name = std::str::from_utf8(r.take(len)?).map_err(|_| r.bad("section name is not UTF-8"))?;
        table.push((name, r.u64()?));
    }
    let mut at = HEADER_LEN - 4 + r.pos;
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
    // PDFs into fresh fields, first touched here.
    let mut cur = blk.fresh_field(p);
    let mut other = blk.fresh_field(1 - p);
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
            other.data_mut().fill(T::ZERO);
            let stride = l.stride;
            let data = cur.data_mut();
            data.fill(T::ZERO);
            let mut chunks = s.chunks_exact(T::BYTES);
            for q in 0..Q {
                for z in 1..=nz {
                    for y in 1..=ny {
                        let start = q * stride + l.idx(1, y, z);
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
    blk.replace_field(1 - p, other);
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
