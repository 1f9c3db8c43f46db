//! `blockflow bench rigid`: cost of the rigid-body sub-step.
//!
//! What is measured, single-threaded, on dense granular packings of N equal spheres (diameter 1, density
//! 1000) for N = 100, 300, 1000, 3000, 10 000, 20 000 (`--quick`: 100, 1000, 3000):
//! - the packing is a simple-cubic lattice of spacing 0.99 with every coordinate jittered by up to ±0.008,
//!   inside a box of six [`Plane`]s that squeezes it by the same 1 % (most lattice neighbours and wall
//!   neighbours overlap by up to about 1.5 % of D, so there are ~6 contacts per sphere, counting each
//!   pair for both spheres), random velocities up to 0.05 and angular velocities up to 0.1 (all drawn
//!   from a hand-written splitmix64, so every run sees the same bodies); gravity on, `RigidParams::default()`
//!   (20 projected Gauss–Seidel sweeps), dt = 1e-4;
//! - one [`substep`] (forces, detection, resolution, positions) with the grid (`grid_threshold` = 0)
//!   and with all pairs (`grid_threshold` = `usize::MAX`; skipped above N = 3000 in full mode, where its
//!   O(N²) detection would dominate the run time). Each repetition starts from the same packing and runs the
//!   same number of sub-steps, so both paths see bitwise the same contacts (checked);
//! - its parts separately on the initial packing: [`detect_grid`], [`detect_all_pairs`] and [`resolve`];
//! - contacts per second (contacts summed over the timed sub-steps / their time) and ns per sphere per
//!   sub-step, which is flat when the sub-step scales linearly in N;
//! - the crossover: [`detect_all_pairs`] against [`detect_grid`] on the same kind of packing for N = 8 … 256,
//!   and the N from which the grid is faster, to set `RigidParams::grid_threshold`.
//!
//! Every figure is the best (smallest) mean over several repetitions: the machine is shared and noisy, and
//! the minimum is the least disturbed estimate of the cost itself. Cloning the packing is never timed.

use crate::error::{Error, Result};
use crate::util::hash::SplitMix;
use blockflow_kernels::rigid::{detect_all_pairs, detect_grid, resolve, substep, Body, Plane, RigidParams};
use glam::DVec3;
use std::hint::black_box;
use std::time::Instant;

/// Sphere counts of the full run.
pub const SIZES: [usize; 6] = [100, 300, 1000, 3000, 10_000, 20_000];
/// Sphere counts of the quick run.
pub const QUICK_SIZES: [usize; 3] = [100, 1000, 3000];
/// Sphere counts of the crossover measurement.
pub const CROSSOVER_SIZES: [usize; 6] = [8, 16, 32, 64, 128, 256];
/// Largest N at which the full run times all pairs.
pub const ALL_PAIRS_MAX: usize = 3000;
/// Time step of the timed sub-steps.
pub const DT: f64 = 1e-4;
/// Lattice spacing of the packing (diameter 1).
const SPACING: f64 = 0.99;
/// Largest jitter of each coordinate.
const JITTER: f64 = 0.008;

/// Figures for one sphere count.
#[derive(Clone, Debug)]
pub struct RigidRow {
    /// Number of spheres.
    pub n: usize,
    /// Sphere–sphere contacts of the initial packing.
    pub pairs: usize,
    /// Sphere–wall contacts of the initial packing.
    pub walls: usize,
    /// Mean contacts (pairs and walls) per timed sub-step.
    pub timed_contacts: f64,
    /// Sub-steps per timed repetition.
    pub substeps: usize,
    /// Seconds per sub-step with the grid.
    pub substep_grid_s: f64,
    /// Seconds per sub-step with all pairs; `None` when skipped.
    pub substep_all_s: Option<f64>,
    /// Seconds per [`detect_grid`] on the initial packing.
    pub detect_grid_s: f64,
    /// Seconds per [`detect_all_pairs`] on the initial packing; `None` when skipped.
    pub detect_all_s: Option<f64>,
    /// Seconds per [`resolve`] of the initial packing's contacts.
    pub resolve_s: f64,
}

impl RigidRow {
    /// Contacts handled per second by the grid sub-step.
    pub fn contacts_per_s(&self) -> f64 {
        self.timed_contacts / self.substep_grid_s
    }
    /// Contacts per sphere of the initial packing (coordination number: a pair counts for both spheres).
    pub fn per_sphere(&self) -> f64 {
        (2 * self.pairs + self.walls) as f64 / self.n as f64
    }
    /// Nanoseconds per sphere per grid sub-step.
    pub fn ns_per_sphere(&self) -> f64 {
        self.substep_grid_s * 1e9 / self.n as f64
    }
}

/// Detection times for one small N.
#[derive(Clone, Debug)]
pub struct CrossoverRow {
    /// Number of spheres.
    pub n: usize,
    /// Seconds per [`detect_all_pairs`].
    pub all_pairs_s: f64,
    /// Seconds per [`detect_grid`].
    pub grid_s: f64,
}

/// Everything `blockflow bench rigid` measured.
#[derive(Clone, Debug)]
pub struct RigidReport {
    /// Quick run.
    pub quick: bool,
    /// Projected Gauss–Seidel sweeps used.
    pub iterations: usize,
    /// Rows for the sphere counts.
    pub rows: Vec<RigidRow>,
    /// Detection times for N = 8 … 256.
    pub crossover: Vec<CrossoverRow>,
    /// Estimated N at which both detections cost the same (log-log interpolation between the measured N);
    /// `None` if one path wins everywhere.
    pub crossover_n: Option<f64>,
    /// Recommended `RigidParams::grid_threshold`.
    pub recommended_threshold: usize,
    /// The current default `RigidParams::grid_threshold`.
    pub current_threshold: usize,
}

/// A vector with each component uniform in [-amplitude, amplitude).
fn jitter(rng: &mut SplitMix, amplitude: f64) -> DVec3 {
    DVec3::new(rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0)) * amplitude
}

/// Lattice dimensions nx ≤ ny ≤ nz for `n` spheres: the most cubic exact factorisation nx ny nz = n (a full
/// box, squeezed on all sides) if its aspect ratio nz / nx is at most 4, else a cube of side ⌈∛n⌉ with a
/// partial top layer.
fn lattice(n: usize) -> [usize; 3] {
    let mut best: Option<[usize; 3]> = None;
    for nx in (1..=n).take_while(|&a| a * a * a <= n) {
        for ny in (nx..=n / nx).take_while(|&b| nx * b * b <= n) {
            if n.is_multiple_of(nx * ny) && best.is_none_or(|b| n / (nx * ny) * b[0] < b[2] * nx) {
                best = Some([nx, ny, n / (nx * ny)]);
            }
        }
    }
    match best {
        Some(b) if b[2] <= 4 * b[0] => b,
        _ => {
            let side = (n as f64).cbrt().ceil().max(1.0) as usize;
            [side, side, n.div_ceil(side * side)]
        }
    }
}

/// The dense packing of `n` spheres and its box: an nx × ny × nz simple-cubic lattice (`lattice`) filled
/// row by row from the floor, spacing 0.99, jittered, squeezed by the walls by 1 %.
pub fn packing(n: usize, seed: u64) -> (Vec<Body>, Vec<Plane>) {
    let [nx, ny, nz] = lattice(n);
    let mut rng = SplitMix(seed);
    let first = 0.5 - 0.5 * (1.0 - SPACING);
    let bodies = (0..n)
        .map(|i| {
            let ijk = DVec3::new((i % nx) as f64, ((i / nx) % ny) as f64, (i / (nx * ny)) as f64);
            let x = DVec3::splat(first) + ijk * SPACING + jitter(&mut rng, JITTER);
            let mut b = Body::sphere(i as u64, x, 0.5, 1000.0);
            b.velocity = jitter(&mut rng, 0.05);
            b.angular_velocity = jitter(&mut rng, 0.1);
            b
        })
        .collect();
    let extent = |k: usize| (k - 1) as f64 * SPACING + 2.0 * first;
    let hi = DVec3::new(extent(nx), extent(ny), extent(nz));
    let mut planes = Vec::new();
    for (axis, e) in [DVec3::X, DVec3::Y, DVec3::Z].into_iter().enumerate() {
        planes.push(Plane::through(2 * axis as u64, DVec3::ZERO, e));
        planes.push(Plane::through(2 * axis as u64 + 1, hi, -e));
    }
    (bodies, planes)
}

/// Timing budget: repetitions and the target seconds of one repetition.
#[derive(Clone, Copy)]
struct Budget {
    reps: usize,
    target_s: f64,
    max_calls: usize,
}

/// Calls per repetition so that one repetition lasts about `target_s`, from one (warm-up) call of `f`.
fn calls_for(budget: Budget, f: &mut impl FnMut()) -> usize {
    let t0 = Instant::now();
    f();
    let once = t0.elapsed().as_secs_f64().max(1e-9);
    ((budget.target_s / once).ceil() as usize).clamp(1, budget.max_calls)
}

/// Best mean seconds per call of `f` over `budget.reps` repetitions of `calls` calls.
fn best_of(budget: Budget, calls: usize, mut f: impl FnMut()) -> f64 {
    let mut best = f64::MAX;
    for _ in 0..budget.reps {
        let t0 = Instant::now();
        for _ in 0..calls {
            f();
        }
        best = best.min(t0.elapsed().as_secs_f64() / calls as f64);
    }
    best
}

/// Best seconds per sub-step over `budget.reps` repetitions of `steps` sub-steps, each from a fresh copy of
/// `bodies`; also the contacts summed over one repetition's sub-steps.
fn time_substeps(bodies: &[Body], planes: &[Plane], p: &RigidParams, steps: usize, reps: usize) -> (f64, usize) {
    let mut best = f64::MAX;
    let mut contacts = 0;
    for _ in 0..reps {
        let mut b = bodies.to_vec();
        let mut sum = 0;
        let t0 = Instant::now();
        for _ in 0..steps {
            sum += substep(&mut b, planes, p, DT).contacts;
        }
        best = best.min(t0.elapsed().as_secs_f64() / steps as f64);
        black_box(&b);
        contacts = sum;
    }
    (best, contacts)
}

fn measure_row(n: usize, budget: Budget, all_pairs: bool) -> Result<RigidRow> {
    let (bodies, planes) = packing(n, 0x5EED ^ n as u64);
    let base = RigidParams::default();
    let grid_p = RigidParams {
        grid_threshold: 0,
        ..base
    };
    let all_p = RigidParams {
        grid_threshold: usize::MAX,
        ..base
    };
    // Sub-steps per repetition from one warm-up sub-step.
    let mut warm = bodies.clone();
    let steps = calls_for(budget, &mut || {
        substep(&mut warm, &planes, &grid_p, DT);
    });
    let (substep_grid_s, grid_contacts) = time_substeps(&bodies, &planes, &grid_p, steps, budget.reps);
    let substep_all_s = if all_pairs {
        let (t, all_contacts) = time_substeps(&bodies, &planes, &all_p, steps, budget.reps);
        if all_contacts != grid_contacts {
            return Err(Error::Config(format!(
                "bench rigid: N = {n}: grid and all pairs saw {grid_contacts} and {all_contacts} contacts"
            )));
        }
        Some(t)
    } else {
        None
    };

    let contacts = detect_grid(&bodies, &planes, base.contact_margin);
    let mut f = || {
        black_box(detect_grid(black_box(&bodies), &planes, base.contact_margin));
    };
    let calls = calls_for(budget, &mut f);
    let detect_grid_s = best_of(budget, calls, f);
    let detect_all_s = if all_pairs {
        let mut f = || {
            black_box(detect_all_pairs(black_box(&bodies), &planes, base.contact_margin));
        };
        let calls = calls_for(budget, &mut f);
        Some(best_of(budget, calls, f))
    } else {
        None
    };
    // The solver's work does not depend on the velocities (fixed sweeps), so one copy serves every call.
    let mut b = bodies.clone();
    let mut f = || {
        black_box(resolve(&mut b, &contacts, &base, DT));
    };
    let calls = calls_for(budget, &mut f);
    let resolve_s = best_of(budget, calls, f);
    let pairs = contacts.iter().filter(|c| c.b.is_some()).count();
    Ok(RigidRow {
        n,
        pairs,
        walls: contacts.len() - pairs,
        timed_contacts: grid_contacts as f64 / steps as f64,
        substeps: steps,
        substep_grid_s,
        substep_all_s,
        detect_grid_s,
        detect_all_s,
        resolve_s,
    })
}

/// N at which `all pairs / grid` rises through 1 for the last time, interpolated linearly in log N and log
/// ratio between the two measured points around it; `None` if all pairs wins or loses everywhere.
fn crossover_n(rows: &[CrossoverRow]) -> Option<f64> {
    let r: Vec<(f64, f64)> = rows
        .iter()
        .map(|c| ((c.n as f64).ln(), (c.all_pairs_s / c.grid_s).ln()))
        .collect();
    let k = r.iter().rposition(|&(_, lr)| lr < 0.0)?;
    let &(x0, y0) = &r[k];
    let &(x1, y1) = r.get(k + 1)?;
    Some((x0 + (x1 - x0) * (-y0) / (y1 - y0)).exp())
}

/// Runs the benchmark.
pub fn run(quick: bool) -> Result<RigidReport> {
    let budget = if quick {
        Budget {
            reps: 3,
            target_s: 0.03,
            max_calls: 50,
        }
    } else {
        Budget {
            reps: 5,
            target_s: 0.15,
            max_calls: 200,
        }
    };
    let sizes: &[usize] = if quick { &QUICK_SIZES } else { &SIZES };
    let mut rows = Vec::new();
    for &n in sizes {
        rows.push(measure_row(n, budget, quick || n <= ALL_PAIRS_MAX)?);
    }

    let small = Budget {
        reps: if quick { 5 } else { 9 },
        target_s: if quick { 0.01 } else { 0.03 },
        max_calls: 100_000,
    };
    let margin = RigidParams::default().contact_margin;
    let mut crossover = Vec::new();
    for &n in &CROSSOVER_SIZES {
        let (bodies, planes) = packing(n, 0xC055 ^ n as u64);
        let mut fa = || {
            black_box(detect_all_pairs(black_box(&bodies), &planes, margin));
        };
        let mut fg = || {
            black_box(detect_grid(black_box(&bodies), &planes, margin));
        };
        let (ca, cg) = (calls_for(small, &mut fa), calls_for(small, &mut fg));
        // Alternate the two so that a noisy phase of the machine hits both.
        let (mut all_pairs_s, mut grid_s) = (f64::MAX, f64::MAX);
        for _ in 0..small.reps {
            let one = Budget { reps: 1, ..small };
            all_pairs_s = all_pairs_s.min(best_of(one, ca, &mut fa));
            grid_s = grid_s.min(best_of(one, cg, &mut fg));
        }
        crossover.push(CrossoverRow { n, all_pairs_s, grid_s });
    }
    let crossover_n = crossover_n(&crossover);
    let current_threshold = RigidParams::default().grid_threshold;
    let recommended_threshold = recommend(&crossover, crossover_n);
    Ok(RigidReport {
        quick,
        iterations: RigidParams::default().iterations,
        rows,
        crossover,
        crossover_n,
        recommended_threshold,
        current_threshold,
    })
}

/// The smallest power of two at or above the crossover (detection near the crossover costs about the same
/// either way, so the round number is as good); all pairs' range if it never loses, 0 if it never wins.
fn recommend(rows: &[CrossoverRow], crossover: Option<f64>) -> usize {
    match crossover {
        Some(x) => (x.ceil() as usize).next_power_of_two(),
        None if rows.iter().all(|c| c.grid_s <= c.all_pairs_s) => rows.first().map_or(0, |c| c.n),
        None => rows.last().map_or(0, |c| 2 * c.n),
    }
}

fn ms(s: f64) -> String {
    let v = s * 1e3;
    if v >= 100.0 {
        format!("{v:.0}")
    } else if v >= 10.0 {
        format!("{v:.1}")
    } else if v >= 1.0 {
        format!("{v:.2}")
    } else {
        format!("{v:.3}")
    }
}

/// The tables `blockflow bench rigid` prints.
pub fn to_markdown(r: &RigidReport) -> String {
    let mut s = format!(
        "Rigid-body sub-step on dense sphere packings (diameter 1, jittered simple-cubic lattice squeezed by 1 % in \
         a box of 6 planes, gravity on, {} PGS sweeps, dt = {DT:e}), one thread; best of several repetitions{}\n\n\
         | N | contacts (pairs + walls) | contacts / sphere | sub-step grid (ms) | sub-step all pairs (ms) | \
         detect grid (ms) | detect all pairs (ms) | resolve (ms) | contacts / s (M) | ns / sphere / sub-step |\n\
         |---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
        r.iterations,
        if r.quick { " (quick)" } else { "" }
    );
    let na = |v: Option<f64>| v.map_or_else(|| "n/a".to_string(), ms);
    for row in &r.rows {
        s += &format!(
            "| {} | {} + {} | {:.2} | {} | {} | {} | {} | {} | {:.2} | {:.0} |\n",
            row.n,
            row.pairs,
            row.walls,
            row.per_sphere(),
            ms(row.substep_grid_s),
            na(row.substep_all_s),
            ms(row.detect_grid_s),
            na(row.detect_all_s),
            ms(row.resolve_s),
            row.contacts_per_s() / 1e6,
            row.ns_per_sphere(),
        );
    }
    s += "\n- contacts, contacts / sphere (2 pairs + walls, per sphere), detect and resolve: the initial packing; \
          sub-steps: each repetition runs the same sub-steps from it (both paths saw the same contacts); \
          contacts / s: contacts summed over the timed grid sub-steps / their time.\n";
    let measured = r.rows.iter().rfind(|row| row.detect_all_s.is_some());
    let skipped: Vec<&RigidRow> = r.rows.iter().filter(|row| row.detect_all_s.is_none()).collect();
    if let (Some(m), false) = (measured, skipped.is_empty()) {
        let at = |row: &RigidRow| {
            let f = (row.n as f64 / m.n as f64).powi(2);
            format!("{} ms at N = {}", ms(m.detect_all_s.unwrap_or(0.0) * f), row.n)
        };
        s += &format!(
            "- all pairs: n/a above N = {ALL_PAIRS_MAX}, skipped in the full run (O(N²) detection; extrapolated from \
             N = {} with (N / {})²: {}).\n",
            m.n,
            m.n,
            skipped.iter().map(|row| at(row)).collect::<Vec<_>>().join(", ")
        );
    }
    if let (Some(a), Some(b)) = (r.rows.first(), r.rows.last()) {
        s += &format!(
            "- linear scaling: ns per sphere per sub-step {:.0} at N = {} and {:.0} at N = {} (x{:.2} for x{:.0} \
             spheres).\n",
            a.ns_per_sphere(),
            a.n,
            b.ns_per_sphere(),
            b.n,
            b.ns_per_sphere() / a.ns_per_sphere(),
            b.n as f64 / a.n as f64
        );
    }
    s += "\nCrossover of the detections (same kind of packing)\n\n\
          | N | all pairs (us) | grid (us) | all pairs / grid |\n|---:|---:|---:|---:|\n";
    for c in &r.crossover {
        s += &format!(
            "| {} | {:.2} | {:.2} | {:.2} |\n",
            c.n,
            c.all_pairs_s * 1e6,
            c.grid_s * 1e6,
            c.all_pairs_s / c.grid_s
        );
    }
    match r.crossover_n {
        Some(x) => {
            s += &format!("\n- all pairs stops being faster than the grid at N ≈ {x:.0}.\n");
        }
        None => {
            s += "\n- no crossover in N = 8 … 256: one detection is faster everywhere.\n";
        }
    }
    s += &format!(
        "- recommended RigidParams::grid_threshold = {} (current default {}).\n",
        r.recommended_threshold, r.current_threshold
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn packing_is_dense_and_deterministic() {
        let (a, planes) = packing(1000, 1);
        let (b, _) = packing(1000, 1);
        assert_eq!(a, b);
        let c = detect_grid(&a, &planes, 0.0);
        let pairs = c.iter().filter(|c| c.b.is_some()).count();
        let per_sphere = (pairs + c.len()) as f64 / a.len() as f64;
        assert!((4.0..=8.0).contains(&per_sphere), "{per_sphere}");
        assert_eq!(c, detect_all_pairs(&a, &planes, 0.0));
    }

    #[test]
    fn lattice_fills_the_box() {
        let sizes = SIZES.iter().chain(&CROSSOVER_SIZES);
        for &n in sizes {
            let [x, y, z] = lattice(n);
            assert_eq!(x * y * z, n, "{n}");
            assert!(x <= y && y <= z && z <= 4 * x, "{n}: {x} {y} {z}");
        }
        assert_eq!(lattice(1000), [10, 10, 10]);
        assert_eq!(lattice(101), [5, 5, 5]);
    }

    #[test]
    fn crossover_interpolates() {
        let row = |n, a, g| CrossoverRow {
            n,
            all_pairs_s: a,
            grid_s: g,
        };
        let rows = [row(8, 1.0, 2.0), row(16, 2.0, 2.0 * 2f64.sqrt()), row(32, 4.0, 2.0)];
        let x = crossover_n(&rows).unwrap();
        assert!(x > 16.0 && x < 32.0, "{x}");
        assert_eq!(recommend(&rows, Some(x)), 32);
        assert_eq!(crossover_n(&[row(8, 1.0, 2.0)]), None);
    }
}
