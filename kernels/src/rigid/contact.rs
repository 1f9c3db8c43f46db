//! Contact detection (lines 1–5 of Algorithm 7): sphere–sphere and sphere–plane, by all pairs below a body
//! count threshold and by a grid (linked cells) above it, as section 3.2.5 describes. Both paths produce
//! the identical, deterministically sorted list. Across sub-steps, [`ContactCandidates`] keeps the pairs
//! within the margin plus a skin and tests only those (a Verlet list), with the same result.

use super::{Body, Plane};
use glam::DVec3;

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
    // Far apart by more than rounding could hide: no contact, decided without the square root (the
    // test below would reject the pair too: dist > r_a + r_b + max(margin, 0) by a relative 1e-9).
    let reach = ba.radius + bb.radius + margin.max(0.0);
    let d2 = d.length_squared();
    if d2 > reach * reach * (1.0 + 1e-9) {
        return None;
    }
    let dist = d2.sqrt();
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

/// Sort key: (id of a, 0 for sphere / 1 for plane, id of the partner, partner index). The key of each
/// contact is computed once (it reads two bodies); keys are distinct, so the order is the only one.
fn sort_contacts(bodies: &[Body], planes: &[Plane], c: &mut [Contact]) {
    c.sort_by_cached_key(|c| match (c.b, c.plane) {
        (Some(b), _) => (bodies[c.a].id, 0u8, bodies[b].id, b, c.a),
        (None, Some(k)) => (bodies[c.a].id, 1u8, planes[k].id, k, c.a),
        _ => unreachable!(),
    });
}

/// All-pairs detection, O(N²).
pub fn detect_all_pairs(bodies: &[Body], planes: &[Plane], margin: f64) -> Vec<Contact> {
    let mut out = Vec::new();
    let probes = Probe::of(bodies, margin);
    for i in 0..bodies.len() {
        pairs_with(bodies, &probes, i, i + 1..bodies.len(), margin, &mut out);
    }
    plane_contacts(bodies, planes, margin, &mut out);
    sort_contacts(bodies, planes, &mut out);
    out
}

/// Bodies binned into buckets by a counting sort: the bodies of bucket `k` are
/// `order[start[k]..start[k + 1]]`, in index order.
struct Bins {
    start: Vec<usize>,
    order: Vec<usize>,
}

impl Bins {
    fn new(buckets: usize, bucket_of: &[usize]) -> Self {
        let mut start = vec![0usize; buckets + 1];
        for &k in bucket_of {
            start[k + 1] += 1;
        }
        for k in 0..buckets {
            start[k + 1] += start[k];
        }
        let mut next = start.clone();
        let mut order = vec![0; bucket_of.len()];
        for (i, &k) in bucket_of.iter().enumerate() {
            order[next[k]] = i;
            next[k] += 1;
        }
        Bins { start, order }
    }
    /// Bodies of buckets `first..=last`.
    fn range(&self, first: usize, last: usize) -> &[usize] {
        &self.order[self.start[first]..self.start[last + 1]]
    }
}

/// What the grid's pair tests read of a body, packed (a [`Body`] spans several cache lines): centre,
/// reach (radius + max(margin, 0)) and whether it is fixed.
#[derive(Clone, Copy)]
struct Probe {
    position: DVec3,
    reach: f64,
    fixed: bool,
}

impl Probe {
    fn of(bodies: &[Body], margin: f64) -> Vec<Probe> {
        bodies
            .iter()
            .map(|b| Probe {
                position: b.position,
                reach: b.radius + margin.max(0.0),
                fixed: b.fixed,
            })
            .collect()
    }
}

/// Tests body `i` against the candidates `js`: a pair is generated only from its lower-index body (every
/// unordered pair is met from both of its bodies; the contact itself is oriented by (id, index) and the
/// list sorted afterwards).
fn pairs_of(bodies: &[Body], probes: &[Probe], i: usize, js: &[usize], margin: f64, out: &mut Vec<Contact>) {
    pairs_with(bodies, probes, i, js.iter().copied().filter(|&j| j > i), margin, out);
}

/// Tests body `i` against the bodies `js` (each pair once): the pre-test of [`sphere_sphere`] on the
/// packed probes, then the contact itself.
fn pairs_with(
    bodies: &[Body],
    probes: &[Probe],
    i: usize,
    js: impl Iterator<Item = usize>,
    margin: f64,
    out: &mut Vec<Contact>,
) {
    let pi = probes[i];
    let m = margin.max(0.0);
    for j in js {
        let pj = &probes[j];
        if pi.fixed && pj.fixed {
            continue;
        }
        // r_a + r_b + margin, up to rounding (the tolerance below covers it).
        let reach = pi.reach + pj.reach - m;
        if (pi.position - pj.position).length_squared() > reach * reach * (1.0 + 1e-8) {
            continue;
        }
        let (a, b) = sphere_pair(bodies, i, j);
        out.extend(sphere_sphere(bodies, a, b, margin));
    }
}

/// Grid (linked-cell) detection, O(N): cells of edge 2 r_max + margin, each body tested against the bodies of
/// the 27 cells around its own; a pair is generated only from its lower-(id, index) body, so exactly once.
/// The bodies are binned into cells by a counting sort: over the cells of their bounding box when it has at
/// most 4 N + 64 cells (the 3 cells of a row of neighbours are then adjacent in the bins), else into 2 N … 4 N
/// hashed buckets, of which only the bodies in truly neighbouring cells are tested. The same pairs as all
/// pairs, in the same sorted order.
pub fn detect_grid(bodies: &[Body], planes: &[Plane], margin: f64) -> Vec<Contact> {
    let mut out = Vec::new();
    let n = bodies.len();
    let probes = Probe::of(bodies, margin);
    let rmax = bodies.iter().map(|b| b.radius).fold(0.0, f64::max);
    let h = (2.0 * rmax + margin.max(0.0)).max(f64::MIN_POSITIVE);
    let cells: Vec<[i64; 3]> = bodies
        .iter()
        .map(|b| (b.position / h).floor().to_array().map(|c| c as i64))
        .collect();
    let (mut lo, mut hi) = ([i64::MAX; 3], [i64::MIN; 3]);
    for c in &cells {
        for k in 0..3 {
            lo[k] = lo[k].min(c[k]);
            hi[k] = hi[k].max(c[k]);
        }
    }
    let extent: [i128; 3] = std::array::from_fn(|k| hi[k] as i128 - lo[k] as i128 + 1);
    let dense = n > 0
        && extent
            .iter()
            .try_fold(1i128, |p, &e| p.checked_mul(e))
            .is_some_and(|p| p <= 4 * n as i128 + 64);
    if dense {
        let [ex, ey, ez] = extent.map(|e| e as usize);
        let rel = |c: &[i64; 3]| std::array::from_fn::<usize, 3, _>(|k| (c[k] - lo[k]) as usize);
        let bucket = |x: usize, y: usize, z: usize| x + ex * (y + ey * z);
        let bucket_of: Vec<usize> = cells
            .iter()
            .map(|c| {
                let [x, y, z] = rel(c);
                bucket(x, y, z)
            })
            .collect();
        let bins = Bins::new(ex * ey * ez, &bucket_of);
        for (i, c) in cells.iter().enumerate() {
            let [x, y, z] = rel(c);
            let (x0, x1) = (x.saturating_sub(1), (x + 1).min(ex - 1));
            for zz in z.saturating_sub(1)..=(z + 1).min(ez - 1) {
                for yy in y.saturating_sub(1)..=(y + 1).min(ey - 1) {
                    pairs_of(
                        bodies,
                        &probes,
                        i,
                        bins.range(bucket(x0, yy, zz), bucket(x1, yy, zz)),
                        margin,
                        &mut out,
                    );
                }
            }
        }
    } else if n > 0 {
        let buckets = (2 * n).next_power_of_two();
        let hash = |c: [i64; 3]| {
            let k = (c[0] as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
                ^ (c[1] as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
                ^ (c[2] as u64).wrapping_mul(0x1656_67B1_9E37_79F9);
            ((k ^ (k >> 29)) as usize) & (buckets - 1)
        };
        let bucket_of: Vec<usize> = cells.iter().map(|&c| hash(c)).collect();
        let bins = Bins::new(buckets, &bucket_of);
        let mut near = Vec::with_capacity(27);
        let mut js = Vec::new();
        for (i, &c) in cells.iter().enumerate() {
            near.clear();
            for dx in -1..=1i64 {
                for dy in -1..=1i64 {
                    for dz in -1..=1i64 {
                        near.push(hash([
                            c[0].wrapping_add(dx),
                            c[1].wrapping_add(dy),
                            c[2].wrapping_add(dz),
                        ]));
                    }
                }
            }
            near.sort_unstable();
            near.dedup();
            js.clear();
            for &k in &near {
                let neighbour = |j: &&usize| (0..3).all(|a| cells[**j][a].abs_diff(c[a]) <= 1);
                js.extend(bins.range(k, k).iter().filter(neighbour));
            }
            pairs_of(bodies, &probes, i, &js, margin, &mut out);
        }
    }
    plane_contacts(bodies, planes, margin, &mut out);
    sort_contacts(bodies, planes, &mut out);
    out
}

/// Detection: all pairs below `threshold` bodies, the grid at or above it. Output sorted by
/// (id a, kind, id b), identical for both paths.
pub fn detect(bodies: &[Body], planes: &[Plane], margin: f64, threshold: usize) -> Vec<Contact> {
    if bodies.len() < threshold {
        detect_all_pairs(bodies, planes, margin)
    } else {
        detect_grid(bodies, planes, margin)
    }
}

/// Skin of [`ContactCandidates`] as a fraction of the smallest radius among the bodies.
const SKIN_PER_RADIUS: f64 = 0.1;

/// Candidate pairs of [`detect`] kept between calls: a Verlet neighbour list with a skin, as LAMMPS's
/// `neighbor` keeps one. When the list is built, every pair of bodies whose gap is below margin + skin
/// is a candidate. As long as the bodies are the same, in the same order, and none has moved by half the
/// skin since, every pair within the margin is among the candidates, so testing only those gives the
/// same contacts, bit for bit, as [`detect`] over all bodies. Across the sub-steps of a step the bodies
/// move far less than a skin, so the list is built again only when a body enters or leaves the set or
/// moves that far.
#[derive(Clone, Debug, Default)]
pub struct ContactCandidates {
    /// Body centres when the pairs were found.
    centres: Vec<DVec3>,
    /// Candidate pairs (a, b), oriented as their contacts would be.
    pairs: Vec<(u32, u32)>,
    /// The skin the pairs were found with.
    skin: f64,
    /// The contact margin they were found for.
    margin: f64,
    /// Whether `pairs` belongs to `centres` (false before the first call).
    built: bool,
    /// Times the list was built (for tests and counters).
    builds: u64,
}

impl ContactCandidates {
    /// Times the list was built since it was created.
    pub fn builds(&self) -> u64 {
        self.builds
    }

    /// The contacts of [`detect`] (same arguments, the same list in the same order), from the candidate
    /// pairs where they are still valid. `same_bodies` is the caller's statement that `bodies` lists the
    /// same bodies in the same order as at the previous call (their positions may differ); without it the
    /// candidates are found again.
    pub fn detect(
        &mut self,
        bodies: &[Body],
        planes: &[Plane],
        margin: f64,
        threshold: usize,
        same_bodies: bool,
    ) -> Vec<Contact> {
        let m = margin.max(0.0);
        // A pair within the margin now was within margin + skin when the list was built if neither
        // body has moved by half the skin; 0.45 leaves room for the rounding of the displacements.
        let valid = self.built
            && same_bodies
            && self.margin.to_bits() == margin.to_bits()
            && self.centres.len() == bodies.len()
            && bodies
                .iter()
                .zip(&self.centres)
                .all(|(b, c)| (b.position - *c).length_squared() < (0.45 * self.skin).powi(2));
        if !valid {
            let r_min = bodies.iter().map(|b| b.radius).fold(f64::INFINITY, f64::min);
            self.skin = if r_min.is_finite() {
                SKIN_PER_RADIUS * r_min
            } else {
                0.0
            };
            self.centres.clear();
            self.centres.extend(bodies.iter().map(|b| b.position));
            self.pairs.clear();
            self.pairs.extend(
                detect(bodies, &[], m + self.skin, threshold)
                    .iter()
                    .filter_map(|c| c.b.map(|b| (c.a as u32, b as u32))),
            );
            self.margin = margin;
            self.built = true;
            self.builds += 1;
        }
        let mut out: Vec<Contact> = self
            .pairs
            .iter()
            .filter_map(|&(a, b)| sphere_sphere(bodies, a as usize, b as usize, margin))
            .collect();
        plane_contacts(bodies, planes, margin, &mut out);
        sort_contacts(bodies, planes, &mut out);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Spheres of radius 0.1 … 0.3 spread uniformly in a cube of edge `edge`, ids a permutation of indices.
    fn cloud(n: usize, edge: f64, seed: u64) -> Vec<Body> {
        let mut s = seed;
        let mut next = move || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        (0..n)
            .map(|i| {
                let x = DVec3::new(next(), next(), next()) * edge - DVec3::splat(0.5 * edge);
                let mut b = Body::sphere((i as u64 * 7919) % n as u64, x, 0.1 + 0.2 * next(), 1000.0);
                b.fixed = i % 5 == 0;
                b
            })
            .collect()
    }

    #[test]
    fn dense_and_hashed_bins_match_all_pairs() {
        let planes = [Plane::through(0, DVec3::splat(-4.0), DVec3::ONE)];
        // Dense: a compact cloud. Hashed: the same with a few bodies far away, which blows up the bounding box.
        for far in [false, true] {
            let mut bodies = cloud(600, 6.0, 3);
            if far {
                for b in bodies.iter_mut().take(40) {
                    b.position = DVec3::new(1e6, -3e7, 5e5) + 0.2 * b.position;
                }
            }
            let a = detect_all_pairs(&bodies, &planes, 0.05);
            assert!(a.iter().filter(|c| c.b.is_some()).count() > 200);
            assert_eq!(a, detect_grid(&bodies, &planes, 0.05), "far bodies: {far}");
        }
        assert!(detect_grid(&[], &planes, 0.0).is_empty());
    }

    #[test]
    fn candidate_lists_give_the_contacts_of_full_detection_at_every_call() {
        let planes = [Plane::through(0, DVec3::splat(-2.0), DVec3::ONE)];
        let mut bodies = cloud(300, 4.0, 7);
        let mut s = 11u64;
        let mut next = move || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let mut cand = ContactCandidates::default();
        let mut total = 0;
        for call in 0..200 {
            // Small random moves, a jump now and then (as a periodic wrap gives), and a changed set.
            for b in bodies.iter_mut() {
                b.position += 0.001 * DVec3::new(next(), next(), next());
            }
            if call % 37 == 36 {
                bodies[5].position += DVec3::X * 3.0;
            }
            let same = call % 50 != 49;
            if !same {
                bodies.swap(0, 1);
            }
            for margin in [0.0, 0.02] {
                let mut c = ContactCandidates::default();
                assert_eq!(
                    c.detect(&bodies, &planes, margin, 64, false),
                    detect(&bodies, &planes, margin, 64)
                );
            }
            let got = cand.detect(&bodies, &planes, 0.02, 64, same);
            let want = detect(&bodies, &planes, 0.02, 64);
            assert_eq!(got, want, "call {call}");
            total += want.len();
        }
        assert!(total > 2000, "the cloud must have contacts: {total}");
        // Built at the first call and after each of the 5 jumps and 4 changed sets (10), and again
        // when the random walk of some body adds up to half the skin (0.45 × 0.1 × the smallest radius,
        // 0.1): that takes dozens of calls, so most of the 200 calls reuse the list.
        assert!((10..60).contains(&cand.builds()), "{} builds", cand.builds());
    }
}
