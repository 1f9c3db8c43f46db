//! Two-relaxation-time collision, eq. (2), with the incompressible equilibrium of eq. (3), the magic
//! parameter of eq. (5) and Guo's body-force term.
//!
//! Storage is zero-centred (`f_q - w_q`, ρ0 = 1), so δρ = Σ f_q and ρ0 u = Σ c_q f_q as in eq. (1). With a
//! body force F the velocity entering the equilibrium is u = (Σ c_q f_q + F/2) / ρ0 (Guo et al. 2002), and
//! the source S_q is split into its symmetric and antisymmetric parts, relaxed with (1 - ω±/2).

use crate::d3q19::{C, Q, W};
use crate::real::Real;
use crate::simd::Vector;

/// Physical parameters of the collision: τ+ (→ ν = (τ+ - 1/2)/3), the magic parameter Λ of eq. (5) and a
/// uniform body force density (lattice units).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrtParams {
    /// Symmetric relaxation time τ+ (must exceed 1/2).
    pub tau: f64,
    /// Magic parameter Λ = (τ+ - 1/2)(τ- - 1/2); 3/16 puts bounce-back walls exactly half-way.
    pub magic: f64,
    /// Body force per unit volume (Guo forcing); zero selects the force-free kernel.
    pub force: [f64; 3],
}

impl TrtParams {
    /// Kinematic viscosity ν = (τ+ - 1/2)/3, eq. (5).
    pub fn viscosity(&self) -> f64 {
        (self.tau - 0.5) / 3.0
    }
    /// τ+ for a given viscosity.
    pub fn tau_for_viscosity(nu: f64) -> f64 {
        3.0 * nu + 0.5
    }
    /// Antisymmetric relaxation time τ- from Λ, eq. (5).
    pub fn tau_minus(&self) -> f64 {
        self.magic / (self.tau - 0.5) + 0.5
    }
    /// Whether the body force is non-zero.
    pub fn has_force(&self) -> bool {
        self.force.iter().any(|&f| f != 0.0)
    }
}

/// Collision constants in the storage precision, pre-multiplied so the per-pair work is small.
///
/// For a pair (q, q̄) with c·u = cu and base = δρ - 3/2 u·u, eq. (2) with eq. (3) reads
/// `f_q ← α f_q + β f_q̄ + t + b cu` and `f_q̄ ← α f_q̄ + β f_q + t - b cu`, where α = 1 - (ω+ + ω-)/2,
/// β = (ω- - ω+)/2, t = ω+ w (base + 9/2 cu²) and b = 3 ω- w. Guo's source adds
/// `(1 - ω+/2) S+ ± (1 - ω-/2) S-`, which for a uniform force is `g cu - uf ± h` per pair.
#[derive(Clone, Copy, Debug)]
pub struct TrtConsts<T> {
    /// 1 - ω+ (rest direction).
    pub one_m_wp: T,
    /// α = 1 - (ω+ + ω-)/2.
    pub alpha: T,
    /// β = (ω- - ω+)/2.
    pub beta: T,
    /// ω+ w_q for rest, axis and diagonal classes.
    pub wpw: [T; 3],
    /// 9/2 ω+ w_q for axis and diagonal classes.
    pub a: [T; 2],
    /// 3 ω- w_q for axis and diagonal classes.
    pub b: [T; 2],
    /// 3 (1 - ω+/2) w_q for rest, axis and diagonal classes (multiplies u·F).
    pub uf: [T; 3],
    /// Per pair k = 0..9: 9 (1 - ω+/2) w (c·F) (multiplies c·u).
    pub g: [T; 9],
    /// Per pair: 3 (1 - ω-/2) w (c·F).
    pub h: [T; 9],
    /// Body force F.
    pub f: [T; 3],
    /// F/2.
    pub half_f: [T; 3],
}

impl TrtParams {
    /// Constants in the kernel's precision.
    pub fn consts<T: Real>(&self) -> TrtConsts<T> {
        let wp = 1.0 / self.tau;
        let wm = 1.0 / self.tau_minus();
        let kp = 1.0 - 0.5 * wp;
        let km = 1.0 - 0.5 * wm;
        let w = [W[0], W[1], W[7]];
        let t = T::from_f64;
        let pair_cf = |k: usize| {
            let q = 2 * k + 1;
            (0..3).map(|a| C[q][a] as f64 * self.force[a]).sum::<f64>()
        };
        let pw = |k: usize| W[2 * k + 1];
        TrtConsts {
            one_m_wp: t(1.0 - wp),
            alpha: t(1.0 - 0.5 * (wp + wm)),
            beta: t(0.5 * (wm - wp)),
            wpw: [t(wp * w[0]), t(wp * w[1]), t(wp * w[2])],
            a: [t(4.5 * wp * w[1]), t(4.5 * wp * w[2])],
            b: [t(3.0 * wm * w[1]), t(3.0 * wm * w[2])],
            uf: [t(3.0 * kp * w[0]), t(3.0 * kp * w[1]), t(3.0 * kp * w[2])],
            g: std::array::from_fn(|k| t(9.0 * kp * pw(k) * pair_cf(k))),
            h: std::array::from_fn(|k| t(3.0 * km * pw(k) * pair_cf(k))),
            f: [t(self.force[0]), t(self.force[1]), t(self.force[2])],
            half_f: [t(0.5 * self.force[0]), t(0.5 * self.force[1]), t(0.5 * self.force[2])],
        }
    }
}

/// [`TrtConsts`] broadcast into vector registers once per sweep.
#[derive(Clone, Copy)]
pub struct VConsts<V> {
    one_m_wp: V,
    alpha: V,
    beta: V,
    wpw: [V; 3],
    a: [V; 2],
    b: [V; 2],
    uf: [V; 3],
    g: [V; 9],
    h: [V; 9],
    f: [V; 3],
    half_f: [V; 3],
    m15: V,
    zero: V,
}

impl<V: Vector> VConsts<V> {
    /// Broadcasts the constants.
    #[inline(always)]
    pub fn new(k: &TrtConsts<V::S>) -> Self {
        let s = V::splat;
        VConsts {
            one_m_wp: s(k.one_m_wp),
            alpha: s(k.alpha),
            beta: s(k.beta),
            wpw: k.wpw.map(s),
            a: k.a.map(s),
            b: k.b.map(s),
            uf: k.uf.map(s),
            g: k.g.map(s),
            h: k.h.map(s),
            f: k.f.map(s),
            half_f: k.half_f.map(s),
            m15: s(V::S::from_f64(1.5)),
            zero: s(V::S::ZERO),
        }
    }
}

/// Running statistics of a sweep: the largest |u|² seen and an accumulator that turns NaN as soon as
/// any density or velocity was non-finite (x * 0 is NaN for NaN and ±inf, 0 otherwise).
#[derive(Clone, Copy)]
pub struct LaneStats<V> {
    /// Largest u·u per lane.
    pub max_u2: V,
    /// Sum of (δρ + u·u) * 0 per lane: 0 while everything is finite.
    pub poison: V,
}

impl<V: Vector> LaneStats<V> {
    /// Neutral statistics.
    #[inline(always)]
    pub fn new() -> Self {
        LaneStats {
            max_u2: V::splat(V::S::ZERO),
            poison: V::splat(V::S::ZERO),
        }
    }
}

impl<V: Vector> Default for LaneStats<V> {
    fn default() -> Self {
        Self::new()
    }
}

/// TRT collision (eq. 2 with the equilibrium of eq. 3 and Guo forcing) of `V::LANES` cells at once.
///
/// `load(q)` returns direction q of the cells (zero-centred), `store(q, v)` writes the post-collision
/// value. The moments are taken in a first pass; the second pass reloads each pair (q, q̄) just before it
/// is updated and stored, so only a few vectors are live at a time (no spills). `load` must keep returning
/// the pre-collision values of directions not yet stored (true for a separate destination and for an
/// in-place update alike). Every operation is a plain IEEE operation (fused multiply-adds when `FMA`), so
/// each lane yields the same bits as a scalar call on that cell with the same `FMA` setting.
#[inline(always)]
pub fn trt_cell<V: Vector, const FORCE: bool, const FMA: bool>(
    load: impl Fn(usize) -> V,
    mut store: impl FnMut(usize, V),
    k: &VConsts<V>,
    st: &mut LaneStats<V>,
) {
    let (f7, f8, f9, f10) = (load(7), load(8), load(9), load(10));
    let (s78, d78, s910, d910) = (f7 + f8, f7 - f8, f9 + f10, f9 - f10);
    let (f11, f12, f13, f14) = (load(11), load(12), load(13), load(14));
    let (s1112, d1112, s1314, d1314) = (f11 + f12, f11 - f12, f13 + f14, f13 - f14);
    let (f15, f16, f17, f18) = (load(15), load(16), load(17), load(18));
    let (s1516, d1516, s1718, d1718) = (f15 + f16, f15 - f16, f17 + f18, f17 - f18);
    let (f1, f2, f3, f4, f5, f6) = (load(1), load(2), load(3), load(4), load(5), load(6));
    let rho = (load(0) + (f1 + f2) + (f3 + f4) + (f5 + f6)) + ((s78 + s910) + (s1112 + s1314)) + (s1516 + s1718);
    let mut ux = (f1 - f2) + (d78 + d910) + (d1112 + d1314);
    let mut uy = (f3 - f4) + (d78 - d910) + (d1516 + d1718);
    let mut uz = (f5 - f6) + (d1112 - d1314) + (d1516 - d1718);
    if FORCE {
        ux = ux + k.half_f[0];
        uy = uy + k.half_f[1];
        uz = uz + k.half_f[2];
    }
    let usq = ux.madd::<FMA>(ux, uy.madd::<FMA>(uy, uz * uz));
    st.max_u2 = st.max_u2.max(usq);
    st.poison = (rho + usq).madd::<FMA>(k.zero, st.poison);
    let base = k.m15.nmadd::<FMA>(usq, rho);
    let mut r = [k.wpw[0] * base, k.wpw[1] * base, k.wpw[2] * base];
    if FORCE {
        let uf = ux.madd::<FMA>(k.f[0], uy.madd::<FMA>(k.f[1], uz * k.f[2]));
        r = [
            k.uf[0].nmadd::<FMA>(uf, r[0]),
            k.uf[1].nmadd::<FMA>(uf, r[1]),
            k.uf[2].nmadd::<FMA>(uf, r[2]),
        ];
    }
    store(0, k.one_m_wp.madd::<FMA>(load(0), r[0]));
    macro_rules! pair {
        ($p:expr, $a:expr, $b:expr, $cu:expr, $c:expr) => {{
            let cu = $cu;
            let mut t = k.a[$c].madd::<FMA>(cu * cu, r[$c + 1]);
            let (e, ebar);
            if FORCE {
                t = k.g[$p].madd::<FMA>(cu, t);
                let m = k.b[$c].madd::<FMA>(cu, k.h[$p]);
                e = t + m;
                ebar = t - m;
            } else {
                e = k.b[$c].madd::<FMA>(cu, t);
                ebar = k.b[$c].nmadd::<FMA>(cu, t);
            }
            let fa = load($a);
            let fb = load($b);
            store($a, k.alpha.madd::<FMA>(fa, k.beta.madd::<FMA>(fb, e)));
            store($b, k.alpha.madd::<FMA>(fb, k.beta.madd::<FMA>(fa, ebar)));
        }};
    }
    pair!(0, 1, 2, ux, 0);
    pair!(1, 3, 4, uy, 0);
    pair!(2, 5, 6, uz, 0);
    pair!(3, 7, 8, ux + uy, 1);
    pair!(4, 9, 10, ux - uy, 1);
    pair!(5, 11, 12, ux + uz, 1);
    pair!(6, 13, 14, ux - uz, 1);
    pair!(7, 15, 16, uy + uz, 1);
    pair!(8, 17, 18, uy - uz, 1);
}

/// Zero-centred equilibrium of eq. (3): w_q (δρ + 3 c·u + 9/2 (c·u)² - 3/2 u·u), ρ0 = 1.
pub fn equilibrium(drho: f64, u: [f64; 3]) -> [f64; Q] {
    let usq = u[0] * u[0] + u[1] * u[1] + u[2] * u[2];
    std::array::from_fn(|q| {
        let cu = C[q][0] as f64 * u[0] + C[q][1] as f64 * u[1] + C[q][2] as f64 * u[2];
        W[q] * (drho + 3.0 * cu + 4.5 * cu * cu - 1.5 * usq)
    })
}

/// The post-collision state of a cell that sits exactly at (forced) equilibrium with density δρ and
/// velocity u: the pre-collision state f_eq(u) - S/2 collides to f_eq(u) + S/2 with S Guo's source. This is
/// how blocks are initialised, so that [`moments`] of the stored state returns exactly (δρ, u).
pub fn post_collision_equilibrium(drho: f64, u: [f64; 3], p: &TrtParams) -> [f64; Q] {
    let mut f = equilibrium(drho, u);
    if p.has_force() {
        let uf = u[0] * p.force[0] + u[1] * p.force[1] + u[2] * p.force[2];
        for (q, fq) in f.iter_mut().enumerate() {
            let c = [C[q][0] as f64, C[q][1] as f64, C[q][2] as f64];
            let cu = c[0] * u[0] + c[1] * u[1] + c[2] * u[2];
            let cf = c[0] * p.force[0] + c[1] * p.force[1] + c[2] * p.force[2];
            *fq += 0.5 * W[q] * (9.0 * cu * cf - 3.0 * uf + 3.0 * cf);
        }
    }
    f
}

/// Density deviation δρ and velocity u of a *post-collision* state (what blocks store between steps):
/// Σ c f* = ρ0 u + F/2 after a Guo collision, so u = Σ c f* - F/2 (eq. 1 with the force correction).
pub fn moments<T: Real>(f: &[T; Q], force: [f64; 3]) -> (f64, [f64; 3]) {
    let mut rho = 0.0;
    let mut j = [0.0; 3];
    for q in 0..Q {
        let v = f[q].to_f64();
        rho += v;
        for a in 0..3 {
            j[a] += C[q][a] as f64 * v;
        }
    }
    (
        rho,
        [j[0] - 0.5 * force[0], j[1] - 0.5 * force[1], j[2] - 0.5 * force[2]],
    )
}

/// Cells [`moments_run`] handles at once.
pub const MOMENTS_RUN: usize = 64;

/// δρ and u (eq. 1 with the force correction, as [`moments`]) of up to [`MOMENTS_RUN`] consecutive cells.
#[derive(Clone, Debug)]
pub struct RunMoments {
    /// Cells held.
    pub len: usize,
    /// δρ of each cell.
    pub rho: [f64; MOMENTS_RUN],
    /// u of each cell, one array per axis.
    pub u: [[f64; MOMENTS_RUN]; 3],
}

impl Default for RunMoments {
    fn default() -> Self {
        RunMoments {
            len: 0,
            rho: [0.0; MOMENTS_RUN],
            u: [[0.0; MOMENTS_RUN]; 3],
        }
    }
}

/// [`moments`] of `n ≤ MOMENTS_RUN` consecutive cells whose post-collision populations f*_q lie at
/// `data[start[q]..start[q] + n]`, into `out`. Each cell gets the same operations in the same order as
/// [`moments`], so the same bits; only the loops are exchanged (directions outside, cells inside), which
/// turns 19 gathers per cell into 19 contiguous loads per run.
pub fn moments_run<T: Real>(data: &[T], start: &[usize; Q], n: usize, force: [f64; 3], out: &mut RunMoments) {
    assert!(n <= MOMENTS_RUN, "a run of {n} cells is longer than MOMENTS_RUN");
    let (rho, u) = (&mut out.rho[..n], &mut out.u);
    rho.fill(0.0);
    for a in u.iter_mut() {
        a[..n].fill(0.0);
    }
    for q in 0..Q {
        let f = &data[start[q]..start[q] + n];
        let c = C[q].map(|c| c as f64);
        for (k, v) in f.iter().enumerate() {
            let v = v.to_f64();
            rho[k] += v;
            u[0][k] += c[0] * v;
            u[1][k] += c[1] * v;
            u[2][k] += c[2] * v;
        }
    }
    for (a, ua) in u.iter_mut().enumerate() {
        for x in ua[..n].iter_mut() {
            *x -= 0.5 * force[a];
        }
    }
    out.len = n;
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The run version gives the bits of the cell version, for every cell of a run (zeros, negative
    /// zeros and a non-finite value included).
    #[test]
    fn moments_run_equals_moments() {
        let n = 37;
        let mut data = vec![0.0f64; Q * n];
        let mut s = 12345u64;
        for v in data.iter_mut() {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            *v = ((s >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 0.1;
        }
        data[3] = -0.0;
        data[5 * n + 7] = f64::INFINITY;
        let start: [usize; Q] = std::array::from_fn(|q| q * n);
        let force = [1e-5, -2e-5, 3e-6];
        let mut out = RunMoments::default();
        moments_run(&data, &start, n, force, &mut out);
        assert_eq!(out.len, n);
        for k in 0..n {
            let cell: [f64; Q] = std::array::from_fn(|q| data[q * n + k]);
            let (r, u) = moments(&cell, force);
            assert_eq!(out.rho[k].to_bits(), r.to_bits(), "cell {k}");
            for (a, ua) in u.iter().enumerate() {
                assert_eq!(out.u[a][k].to_bits(), ua.to_bits(), "cell {k}, axis {a}");
            }
        }
    }

    fn collide_one(f: &[f64; Q], p: &TrtParams) -> [f64; Q] {
        let k = VConsts::<f64>::new(&p.consts::<f64>());
        let mut g = *f;
        let mut st = LaneStats::<f64>::new();
        if p.has_force() {
            trt_cell::<f64, true, false>(|q| f[q], |q, v| g[q] = v, &k, &mut st);
        } else {
            trt_cell::<f64, false, false>(|q| f[q], |q, v| g[q] = v, &k, &mut st);
        }
        g
    }

    #[test]
    fn equilibrium_is_fixed_point_and_moments_conserved() {
        let p = TrtParams {
            tau: 0.8,
            magic: 3.0 / 16.0,
            force: [0.0; 3],
        };
        let feq = equilibrium(0.01, [0.03, -0.02, 0.01]);
        let out = collide_one(&feq, &p);
        for q in 0..Q {
            assert!((out[q] - feq[q]).abs() < 1e-17);
        }
        // arbitrary state: mass and momentum conserved to rounding
        let f: [f64; Q] = std::array::from_fn(|q| 0.001 * ((q * 7 % 5) as f64 - 2.0));
        let out = collide_one(&f, &p);
        let (r0, u0) = moments(&f, [0.0; 3]);
        let (r1, u1) = moments(&out, [0.0; 3]);
        assert!((r0 - r1).abs() < 1e-17);
        for a in 0..3 {
            assert!((u0[a] - u1[a]).abs() < 1e-17);
        }
    }

    #[test]
    fn guo_force_adds_momentum_f() {
        let p = TrtParams {
            tau: 0.7,
            magic: 0.25,
            force: [1e-4, -2e-4, 3e-5],
        };
        let f: [f64; Q] = std::array::from_fn(|q| 0.002 * ((q * 3 % 7) as f64 - 3.0));
        let out = collide_one(&f, &p);
        let (r0, j0) = moments(&f, [0.0; 3]);
        let (r1, j1) = moments(&out, [0.0; 3]);
        assert!((r0 - r1).abs() < 1e-17);
        for a in 0..3 {
            assert!((j1[a] - j0[a] - p.force[a]).abs() < 1e-17, "momentum gains exactly F");
        }
        // the initial post-collision equilibrium reports back the velocity it was built with
        let u = [0.02, 0.01, -0.03];
        let fe = post_collision_equilibrium(0.003, u, &p);
        let (r, uu) = moments(&fe, p.force);
        assert!((r - 0.003).abs() < 1e-16);
        for a in 0..3 {
            assert!((uu[a] - u[a]).abs() < 1e-16);
        }
    }

    #[test]
    fn magic_parameter_relation() {
        let p = TrtParams {
            tau: 0.9,
            magic: 3.0 / 16.0,
            force: [0.0; 3],
        };
        assert!(((p.tau - 0.5) * (p.tau_minus() - 0.5) - 3.0 / 16.0).abs() < 1e-15);
        assert!((p.viscosity() - 0.4 / 3.0).abs() < 1e-15);
    }
}
