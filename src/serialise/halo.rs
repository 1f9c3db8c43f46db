//! The particle state of a block that crosses ranks, in the codec of the block format: its published
//! list (bodies, home blocks, contact impulses and counts, as in the block format), the
//! velocity changes of its last rigid-body task and the body forces of its last boundary pass. A rank
//! keeps copies of these for the blocks of other ranks next to its own, and the bytes carry the exact
//! bits, so a copy reads as the original.

use super::read::{read_listed, BlockReader};
use super::write::{put_body, put_body_force, put_count, put_v3, write_bodies};
use super::FormatError;
use crate::physics::particle_cells::BodyForce;
use crate::physics::particles::{Delta, Published};
use crate::util::bytes::{put_u64, Reader};
use blockflow_kernels::rigid::Body;

/// Appends a published list.
pub fn encode_published(list: &Published, out: &mut Vec<u8>) {
    write_bodies(out, list);
}

/// Reads a published list of [`encode_published`] (home blocks below `blocks`).
pub fn decode_published(r: &mut Reader, blocks: usize) -> Result<Published, FormatError> {
    read_listed(r, blocks)
}

/// Appends bodies (every field).
pub fn encode_bodies(bodies: &[Body], out: &mut Vec<u8>) {
    put_count(out, bodies.len());
    for b in bodies {
        put_body(out, b);
    }
}

/// Reads the bodies of [`encode_bodies`].
pub fn decode_bodies(r: &mut Reader) -> Result<Vec<Body>, FormatError> {
    let n = r.count(super::BODY_BYTES)?;
    let mut v = Vec::with_capacity(n);
    for _ in 0..n {
        v.push(r.body()?);
    }
    Ok(v)
}

/// Appends velocity changes.
pub fn encode_deltas(deltas: &[Delta], out: &mut Vec<u8>) {
    put_count(out, deltas.len());
    for d in deltas {
        put_u64(out, d.id);
        put_v3(out, d.dv);
        put_v3(out, d.dw);
    }
}

/// Reads the velocity changes of [`encode_deltas`].
pub fn decode_deltas(r: &mut Reader) -> Result<Vec<Delta>, FormatError> {
    let n = r.count(56)?;
    let mut v = Vec::with_capacity(n);
    for _ in 0..n {
        v.push(Delta {
            id: r.u64()?,
            dv: r.v3()?,
            dw: r.v3()?,
        });
    }
    Ok(v)
}

/// Appends body forces.
pub fn encode_forces(forces: &[BodyForce], out: &mut Vec<u8>) {
    put_count(out, forces.len());
    for f in forces {
        put_body_force(out, f);
    }
}

/// Reads the body forces of [`encode_forces`].
pub fn decode_forces(r: &mut Reader) -> Result<Vec<BodyForce>, FormatError> {
    let n = r.count(super::BODY_FORCE_BYTES)?;
    let mut v = Vec::with_capacity(n);
    for _ in 0..n {
        v.push(r.body_force()?);
    }
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::particles::OwnedImpulse;
    use glam::DVec3;

    #[test]
    fn halo_state_round_trips_bit_for_bit() {
        let mut body = Body::sphere(7, DVec3::new(1.5, -0.25, 3.0), 0.75, 2.5);
        body.velocity = DVec3::new(1e-17, -0.0, f64::MIN_POSITIVE);
        body.force_prev = DVec3::new(0.1, 0.2, 0.3);
        let list = Published {
            bodies: vec![body, Body::sphere(9, DVec3::ONE, 1.0, 1.0)],
            homes: vec![3, 4],
            owned: vec![OwnedImpulse {
                a: 7,
                b: crate::physics::particles::PLANE_KEY | 2,
                impulse: DVec3::new(-1.0, 0.5, 1e-300),
            }],
            counts: vec![2, 0],
        };
        let deltas = vec![Delta {
            id: 9,
            dv: DVec3::new(1.0, 2.0, 3.0),
            dw: DVec3::new(-0.0, 0.0, 5e-324),
        }];
        let forces = vec![BodyForce {
            id: 7,
            force: DVec3::new(0.5, 0.25, 0.125),
            torque: DVec3::NEG_ONE,
        }];
        let mut out = Vec::new();
        encode_published(&list, &mut out);
        encode_deltas(&deltas, &mut out);
        encode_forces(&forces, &mut out);
        encode_bodies(&list.bodies, &mut out);
        let mut r = Reader::new(&out, "halo");
        let back = decode_published(&mut r, 5).unwrap();
        assert_eq!(format!("{back:?}"), format!("{list:?}"));
        assert_eq!(decode_deltas(&mut r).unwrap(), deltas);
        assert_eq!(decode_forces(&mut r).unwrap(), forces);
        assert_eq!(
            format!("{:?}", decode_bodies(&mut r).unwrap()),
            format!("{:?}", list.bodies)
        );
        r.finish().unwrap();
        // A home block outside the grid is refused.
        let mut r = Reader::new(&out, "halo");
        assert!(decode_published(&mut r, 4).is_err());
    }
}
