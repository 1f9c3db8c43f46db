//! Writing one block in the format of [`super`].

use super::{checksum, BLOCK_FORMAT_VERSION, BODIES, FLAGS, HEADER_LEN, MAGIC, OVERLAY, PARTICLE_STATE, PDF};
use crate::physics::block::Block;
use crate::physics::particle_cells::{BodyForce, ParticleCells};
use crate::physics::particles::{Published, Work};
use crate::physics::simulation::Simulation;
use crate::util::bytes::{put_f64, put_u32, put_u64, put_u8, Counter, Sink};
use blockflow_kernels::d3q19::Q;
use blockflow_kernels::rigid::Body;
use blockflow_kernels::{Layout, Real};
use glam::DVec3;

pub(super) fn put_v3(s: &mut impl Sink, v: DVec3) {
    for x in v.to_array() {
        put_f64(s, x);
    }
}
pub(super) fn put_count(s: &mut impl Sink, n: usize) {
    put_u32(s, u32::try_from(n).expect("fewer than 2^32 entries per section"));
}

/// Layout-free cell index of element index `i`.
fn cell_of(l: &Layout, i: usize) -> u32 {
    let [x, y, z] = l.coords(i);
    let [fx, fy, _] = l.full();
    u32::try_from(x + fx * (y + fy * z)).expect("block below 2^32 cells")
}

pub(super) fn put_body(s: &mut impl Sink, b: &Body) {
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

pub(super) fn put_body_force(s: &mut impl Sink, f: &BodyForce) {
    put_u64(s, f.id);
    put_v3(s, f.force);
    put_v3(s, f.torque);
}

fn write_pdf<T: Real>(s: &mut impl Sink, b: &Block<T>, p: usize) {
    let l = b.layout;
    let [nx, ny, nz] = l.size;
    if s.bulk(Q * nx * ny * nz * T::BYTES) {
        return;
    }
    let data = b.field(p).data();
    let sl = b.slots(p);
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
                    let at = sl.at(q, seg.start);
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
    if pc.owner.len() == l.slots() {
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
    put_count(s, pc.link_cells.len());
    for k in &pc.link_cells {
        put_u32(s, cell_of(l, k.cell as usize));
        put_u32(s, k.dirs);
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
    put_u8(s, pc.map_work.active as u8);
    put_u64(s, pc.map_work.box_cells);
    put_u64(s, pc.map_work.rows_derived);
}

pub(super) fn write_bodies(s: &mut impl Sink, list: &Published) {
    debug_assert_eq!(list.bodies.len(), list.homes.len());
    put_count(s, list.bodies.len());
    for (b, &h) in list.bodies.iter().zip(&list.homes) {
        put_body(s, b);
        put_u32(s, h);
    }
    put_count(s, list.owned.len());
    for o in &list.owned {
        put_u64(s, o.a);
        put_u64(s, o.b);
        put_v3(s, o.impulse);
    }
    put_count(s, list.counts.len());
    for &n in &list.counts {
        put_u32(s, n);
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
    put_u64(s, w.seen_step);
    put_u64(s, w.scanned_step);
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
