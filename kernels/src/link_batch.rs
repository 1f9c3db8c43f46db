//! The per-link boundary rule of eq. (6) for many links at once: δ_q by the ray–sphere intersection
//! ([`crate::coupling::crossing_fraction`]), the boundary point and its velocity
//! ([`crate::coupling::surface_velocity`]) and the returned population by CLI or simple bounce-back
//! ([`crate::coupling::cli_link`], [`crate::coupling::sbb_link`]), over a structure of arrays so that the
//! loop runs in vector lanes (AVX2 when the CPU has it, detected at run time).
//!
//! Every lane performs exactly the scalar functions' IEEE operations in their order (no fused
//! multiply-adds), so a batch gives the same bits as the scalar functions, on any machine and in any lane;
//! the tests check it.

/// Links per batch.
pub const LINK_BATCH: usize = 64;

/// A batch of links: what the caller fills for links `0..len` (inputs) and what [`LinkBatch::solve`]
/// returns. Vectors are split into their components (`[x, y, z]` arrays of lanes).
#[derive(Clone, Debug)]
pub struct LinkBatch {
    /// Number of links in use (at most [`LINK_BATCH`]).
    pub len: usize,
    /// Input: the fluid cell centre relative to the body centre, x_f − X (nearest image).
    pub rel: [[f64; LINK_BATCH]; 3],
    /// Input: the body radius R.
    pub radius: [f64; LINK_BATCH],
    /// Input: the body velocity V.
    pub velocity: [[f64; LINK_BATCH]; 3],
    /// Input: the body angular velocity W.
    pub angular_velocity: [[f64; LINK_BATCH]; 3],
    /// Input: the lattice velocity c_q of the link's outgoing direction q.
    pub c: [[f64; LINK_BATCH]; 3],
    /// Input: 12 w_q ρ0 (the CLI's moving-wall coefficient times 1 + 2δ_q).
    pub w12: [f64; LINK_BATCH],
    /// Input: 6 w_q ρ0 (simple bounce-back's moving-wall coefficient).
    pub w6: [f64; LINK_BATCH],
    /// Input: whether the link takes the CLI (else simple bounce-back, δ_q = 1/2).
    pub cli: [bool; LINK_BATCH],
    /// Input: the stored post-collision f̃_q(x_f) towards the body.
    pub f_out: [f64; LINK_BATCH],
    /// Input: f̃_q̄(x_f) (CLI links; any finite value for the others).
    pub f_opp: [f64; LINK_BATCH],
    /// Input: f̃_q(x_f − c_q) of the second fluid cell (CLI links; any finite value for the others).
    pub f_second: [f64; LINK_BATCH],
    /// Output: the stored f_q̄(x_f, t + Δt) the boundary sends back.
    pub f_in: [f64; LINK_BATCH],
    /// Output: the boundary point relative to the body centre, x_b − X = x_f − X + δ_q c_q.
    pub rel_b: [[f64; LINK_BATCH]; 3],
    /// Output: the surface velocity at x_b, v_b = V + W × (x_b − X).
    pub v_b: [[f64; LINK_BATCH]; 3],
}

impl Default for LinkBatch {
    fn default() -> Self {
        let z = [0.0; LINK_BATCH];
        LinkBatch {
            len: 0,
            rel: [z; 3],
            radius: z,
            velocity: [z; 3],
            angular_velocity: [z; 3],
            c: [z; 3],
            w12: z,
            w6: z,
            cli: [false; LINK_BATCH],
            f_out: z,
            f_opp: z,
            f_second: z,
            f_in: z,
            rel_b: [z; 3],
            v_b: [z; 3],
        }
    }
}

impl LinkBatch {
    /// Computes the outputs of links `0..len` (see the module notes).
    pub fn solve(&mut self) {
        #[cfg(target_arch = "x86_64")]
        {
            #[target_feature(enable = "avx2")]
            unsafe fn avx2(b: &mut LinkBatch) {
                b.lanes()
            }
            if std::is_x86_feature_detected!("avx2") {
                // SAFETY: the CPU supports AVX2.
                unsafe { avx2(self) };
                return;
            }
        }
        self.lanes()
    }

    /// The loop over the links, written lane-wise (no branches, one array per quantity); the arrays go
    /// in as separate references so that the compiler knows they do not overlap.
    #[inline(always)]
    fn lanes(&mut self) {
        let LinkBatch {
            len,
            rel,
            radius,
            velocity,
            angular_velocity,
            c,
            w12,
            w6,
            cli,
            f_out,
            f_opp,
            f_second,
            f_in,
            rel_b,
            v_b,
        } = self;
        let inputs = Inputs {
            rel,
            radius,
            velocity,
            angular_velocity,
            c,
            w12,
            w6,
            cli,
            f_out,
            f_opp,
            f_second,
        };
        lanes((*len).min(LINK_BATCH), &inputs, f_in, rel_b, v_b);
    }
}

/// The inputs of a batch, borrowed.
struct Inputs<'a> {
    rel: &'a [[f64; LINK_BATCH]; 3],
    radius: &'a [f64; LINK_BATCH],
    velocity: &'a [[f64; LINK_BATCH]; 3],
    angular_velocity: &'a [[f64; LINK_BATCH]; 3],
    c: &'a [[f64; LINK_BATCH]; 3],
    w12: &'a [f64; LINK_BATCH],
    w6: &'a [f64; LINK_BATCH],
    cli: &'a [bool; LINK_BATCH],
    f_out: &'a [f64; LINK_BATCH],
    f_opp: &'a [f64; LINK_BATCH],
    f_second: &'a [f64; LINK_BATCH],
}

#[inline(always)]
fn lanes(
    n: usize,
    x: &Inputs<'_>,
    f_in: &mut [f64; LINK_BATCH],
    rel_b: &mut [[f64; LINK_BATCH]; 3],
    v_b: &mut [[f64; LINK_BATCH]; 3],
) {
    for j in 0..n {
        let (rx, ry, rz) = (x.rel[0][j], x.rel[1][j], x.rel[2][j]);
        let (cx, cy, cz) = (x.c[0][j], x.c[1][j], x.c[2][j]);
        // crossing_fraction: δ = k / (−b + √(b² − a k)), clamped to (0, 1]. Its `max(0.0)` and
        // `clamp(f64::MIN_POSITIVE, 1.0)` as compares and selects, which vectorise (the same values: a
        // negative or NaN discriminant gives 0, the sign of a zero there cannot reach δ, and NaN passes
        // the clamp).
        let a = cx * cx + cy * cy + cz * cz;
        let b = cx * rx + cy * ry + cz * rz;
        let k = (rx * rx + ry * ry + rz * rz) - x.radius[j] * x.radius[j];
        let disc = b * b - a * k;
        let disc = if disc > 0.0 { disc } else { 0.0 };
        let crossing = k / (-b + disc.sqrt());
        let crossing = if crossing < f64::MIN_POSITIVE {
            f64::MIN_POSITIVE
        } else {
            crossing
        };
        let crossing = if crossing > 1.0 { 1.0 } else { crossing };
        let cli = x.cli[j];
        let delta = if cli { crossing } else { 0.5 };
        // x_b − X and v_b = V + W × (x_b − X).
        let (bx, by, bz) = (rx + delta * cx, ry + delta * cy, rz + delta * cz);
        let (wx, wy, wz) = (
            x.angular_velocity[0][j],
            x.angular_velocity[1][j],
            x.angular_velocity[2][j],
        );
        let vx = x.velocity[0][j] + (wy * bz - by * wz);
        let vy = x.velocity[1][j] + (wz * bx - bz * wx);
        let vz = x.velocity[2][j] + (wx * by - bx * wy);
        let c_dot_v = cx * vx + cy * vy + cz * vz;
        // cli_link and sbb_link.
        let f_out = x.f_out[j];
        let kappa = (1.0 - 2.0 * delta) / (1.0 + 2.0 * delta);
        let wall = x.w12[j] / (1.0 + 2.0 * delta);
        let by_cli = f_out + kappa * (x.f_second[j] - x.f_opp[j]) - wall * c_dot_v;
        let by_sbb = f_out - x.w6[j] * c_dot_v;
        f_in[j] = if cli { by_cli } else { by_sbb };
        rel_b[0][j] = bx;
        rel_b[1][j] = by;
        rel_b[2][j] = bz;
        v_b[0][j] = vx;
        v_b[1][j] = vy;
        v_b[2][j] = vz;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::coupling::{cli_link, crossing_fraction, lattice_velocity, sbb_link, surface_velocity, RHO0};
    use crate::d3q19::{C, Q, W};
    use glam::DVec3;

    /// Every lane gives the bits of the scalar functions, for CLI and simple bounce-back links, on
    /// links that cross a sphere surface (x_f outside, x_f + c_q inside).
    #[test]
    fn batch_matches_the_scalar_rule_bit_for_bit() {
        let mut s = 0x2545_F491_4F6C_DD1Du64;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let mut b = LinkBatch::default();
        let mut expect = Vec::new();
        while b.len < LINK_BATCH {
            let radius = 2.0 + 3.0 * (next() + 0.5);
            let centre = DVec3::new(next(), next(), next());
            let x_f = DVec3::new(next(), next(), next()) * 4.0 * radius;
            let q = 1 + (((next() + 0.5) * 18.0) as usize).min(17);
            let rel = x_f - centre;
            let inside = |x: DVec3| (x - centre).length_squared() <= radius * radius;
            if inside(x_f) || !inside(x_f + lattice_velocity(q)) {
                continue;
            }
            let j = b.len;
            let cli = j % 3 != 0;
            let (v, w) = (
                DVec3::new(next(), next(), next()) * 0.1,
                DVec3::new(next(), next(), next()) * 0.01,
            );
            let (f_out, f_opp, f_second) = (next() * 0.1, next() * 0.1, next() * 0.1);
            for a in 0..3 {
                b.rel[a][j] = rel[a];
                b.velocity[a][j] = v[a];
                b.angular_velocity[a][j] = w[a];
                b.c[a][j] = C[q][a] as f64;
            }
            b.radius[j] = radius;
            b.w12[j] = 12.0 * W[q] * RHO0;
            b.w6[j] = 6.0 * W[q] * RHO0;
            b.cli[j] = cli;
            b.f_out[j] = f_out;
            b.f_opp[j] = f_opp;
            b.f_second[j] = f_second;
            let delta = if cli { crossing_fraction(rel, q, radius) } else { 0.5 };
            let rel_b = rel + delta * lattice_velocity(q);
            let v_b = surface_velocity(v, w, DVec3::ZERO, rel_b);
            let f_in = if cli {
                cli_link(q, f_out, f_opp, f_second, delta, v_b)
            } else {
                sbb_link(q, f_out, v_b)
            };
            expect.push((f_in, rel_b, v_b));
            b.len += 1;
        }
        const { assert!(Q == 19) };
        b.solve();
        for (j, (f_in, rel_b, v_b)) in expect.into_iter().enumerate() {
            assert_eq!(b.f_in[j].to_bits(), f_in.to_bits(), "link {j}");
            for a in 0..3 {
                assert_eq!(b.rel_b[a][j].to_bits(), rel_b[a].to_bits(), "link {j}");
                assert_eq!(b.v_b[a][j].to_bits(), v_b[a].to_bits(), "link {j}");
            }
        }
    }
}
