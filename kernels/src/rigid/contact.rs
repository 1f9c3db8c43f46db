//! Contact detection (lines 1–5 of Algorithm 7): sphere–sphere and sphere–plane, by all pairs below a body
//! count threshold and by a hash grid (linked cells) above it, as section 3.2.5 describes. Both paths produce
//! the identical, deterministically sorted list.

use super::{Body, Plane};
use glam::DVec3;
use std::collections::HashMap;

/// One contact between body `a` and either body `b` or plane `plane`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Contact {
    /// Index of the first body (the lower id for sphere pairs).
    pub a: usize,
    /// Index of the second body; `None` for a plane contact.
    pub b: Option<usize>,
    /// Index of the plane; `None` for a sphere pair.
    pub plane: Option<usize>,
    /// Unit normal pointing from `b` (or the plane) to `a`.
    pub normal: DVec3,
    /// Contact point (middle of the overlap).
    pub point: DVec3,
    /// Penetration depth (> 0), or minus the gap (within the margin).
    pub depth: f64,
}

fn sphere_pair(bodies: &[Body], i: usize, j: usize) -> (usize, usize) {
    if (bodies[i].id, i) < (bodies[j].id, j) {
        (i, j)
    } else {
        (j, i)
    }
}

/// Contact of the ordered pair (a, b) if the gap is below `margin`.
fn sphere_sphere(bodies: &[Body], a: usize, b: usize, margin: f64) -> Option<Contact> {
    let (ba, bb) = (&bodies[a], &bodies[b]);
    let d = ba.position - bb.position;
    let dist = d.length();
    let depth = ba.radius + bb.radius - dist;
    if depth <= 0.0 && -depth >= margin {
        return None;
    }
    let normal = if dist > 0.0 { d / dist } else { DVec3::Z };
    let point = ba.position - normal * (ba.radius - 0.5 * depth);
    Some(Contact {
        a,
        b: Some(b),
        plane: None,
        normal,
        point,
        depth,
    })
}

fn sphere_plane(bodies: &[Body], planes: &[Plane], a: usize, k: usize, margin: f64) -> Option<Contact> {
    let (b, pl) = (&bodies[a], &planes[k]);
    let depth = b.radius - pl.distance(b.position);
    if depth <= 0.0 && -depth >= margin {
        return None;
    }
    let normal = pl.normal;
    let point = b.position - normal * (b.radius - 0.5 * depth);
    Some(Contact {
        a,
        b: None,
        plane: Some(k),
        normal,
        point,
        depth,
    })
}

fn plane_contacts(bodies: &[Body], planes: &[Plane], margin: f64, out: &mut Vec<Contact>) {
    for a in 0..bodies.len() {
        for k in 0..planes.len() {
            if bodies[a].fixed {
                continue;
            }
            out.extend(sphere_plane(bodies, planes, a, k, margin));
        }
    }
}

/// Sort key: (id of a, 0 for sphere / 1 for plane, id of the partner, partner index).
fn sort_contacts(bodies: &[Body], planes: &[Plane], c: &mut [Contact]) {
    c.sort_by_key(|c| match (c.b, c.plane) {
        (Some(b), _) => (bodies[c.a].id, 0u8, bodies[b].id, b, c.a),
        (None, Some(k)) => (bodies[c.a].id, 1u8, planes[k].id, k, c.a),
        _ => unreachable!(),
    });
}

/// All-pairs detection, O(N²).
pub fn detect_all_pairs(bodies: &[Body], planes: &[Plane], margin: f64) -> Vec<Contact> {
    let mut out = Vec::new();
    for i in 0..bodies.len() {
        for j in i + 1..bodies.len() {
            if bodies[i].fixed && bodies[j].fixed {
                continue;
            }
            let (a, b) = sphere_pair(bodies, i, j);
            out.extend(sphere_sphere(bodies, a, b, margin));
        }
    }
    plane_contacts(bodies, planes, margin, &mut out);
    sort_contacts(bodies, planes, &mut out);
    out
}

/// Hash-grid (linked-cell) detection, O(N): cells of edge 2 r_max + margin, each body tested against the 27
/// neighbouring cells; a pair is generated only from its lower-(id, index) body, so exactly once.
pub fn detect_grid(bodies: &[Body], planes: &[Plane], margin: f64) -> Vec<Contact> {
    let mut out = Vec::new();
    let rmax = bodies.iter().map(|b| b.radius).fold(0.0, f64::max);
    let h = (2.0 * rmax + margin.max(0.0)).max(f64::MIN_POSITIVE);
    let cell = |x: DVec3| {
        (
            (x.x / h).floor() as i64,
            (x.y / h).floor() as i64,
            (x.z / h).floor() as i64,
        )
    };
    let mut grid: HashMap<(i64, i64, i64), Vec<usize>> = HashMap::new();
    for (i, b) in bodies.iter().enumerate() {
        grid.entry(cell(b.position)).or_default().push(i);
    }
    for i in 0..bodies.len() {
        let (cx, cy, cz) = cell(bodies[i].position);
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    let Some(list) = grid.get(&(cx + dx, cy + dy, cz + dz)) else {
                        continue;
                    };
                    for &j in list {
                        if (bodies[j].id, j) <= (bodies[i].id, i) || (bodies[i].fixed && bodies[j].fixed) {
                            continue;
                        }
                        out.extend(sphere_sphere(bodies, i, j, margin));
                    }
                }
            }
        }
    }
    plane_contacts(bodies, planes, margin, &mut out);
    sort_contacts(bodies, planes, &mut out);
    out
}

/// Detection: all pairs below `threshold` bodies, hash grid at or above it. Output sorted by
/// (id a, kind, id b), identical for both paths.
pub fn detect(bodies: &[Body], planes: &[Plane], margin: f64, threshold: usize) -> Vec<Contact> {
    if bodies.len() < threshold {
        detect_all_pairs(bodies, planes, margin)
    } else {
        detect_grid(bodies, planes, margin)
    }
}
