//! Rigid bodies on the block grid: analytic facts through the distributed solver (bodies
//! crossing block faces, contacts owned by one block), and bitwise determinism for any assignment.

mod common;
use blockflow::physics::domain::DomainSpec;
use blockflow::physics::particles::Particles;
use blockflow_kernels::rigid::{Body, RigidParams};
use common::{cfg, run, sim64, timeloop};
use glam::DVec3;

fn observable(s: &blockflow::io::summary::Summary, k: &str) -> f64 {
    *s.observables.get(k).unwrap_or_else(|| panic!("observable {k}"))
}

/// Free fall through four blocks: semi-implicit Euler gives v_n = −g n h and
/// z_n = z_0 − g h² n (n + 1) / 2 after n sub-steps of length h; rounding only (1e-12 relative).
#[test]
fn free_fall_across_blocks_matches_the_discrete_solution() {
    let d = DomainSpec {
        blocks: [1, 1, 4],
        block_size: [8, 8, 8],
        periodic: [false; 3],
    };
    let g = 1.5e-2;
    let params = RigidParams {
        gravity: DVec3::new(0.0, 0.0, -g),
        ..RigidParams::default()
    };
    let z0 = 30.0;
    let body = Body::sphere(7, DVec3::new(4.0, 4.0, z0), 1.0, 1.0);
    let mut p = Particles::new(d, vec![body], Vec::new(), params, 10, 1.0).unwrap();
    let steps = 60;
    p.advance_serial(0, steps).unwrap();
    let b = p.bodies(steps)[0];
    let n = (steps * 10) as f64;
    let h = 0.1;
    let z = z0 - g * h * h * n * (n + 1.0) / 2.0;
    assert!(z < 8.0, "the body crossed three block faces");
    assert!((b.position.z - z).abs() <= 1e-12 * z0, "{} vs {z}", b.position.z);
    assert!((b.velocity.z + g * h * n).abs() <= 1e-12 * g * h * n);
    assert_eq!(p.home(b.position), 0);
}

/// A sphere on an incline (crossing block faces): rolls with a = 5/7 g sin θ when tan θ ≤ 7/2 μ,
/// slides with a = g (sin θ − μ cos θ) otherwise; within 1 %.
#[test]
fn incline_rolls_and_slides_with_the_analytic_acceleration() {
    for (mu, rolls) in [(0.3, true), (0.05, false)] {
        let mu_set = format!("particles.friction={mu}");
        let s = run("incline.toml", &[&mu_set]);
        assert_eq!(observable(&s, "rolling") == 1.0, rolls);
        let err = observable(&s, "relative_error");
        assert!(err < 0.01, "mu = {mu}: relative error {err}");
        assert!(observable(&s, "distance") > 5.0, "the sphere moved across blocks");
        if rolls {
            assert!(observable(&s, "slip_speed") < 1e-9, "no slip while rolling");
        } else {
            assert!(observable(&s, "slip_speed") > 1e-4, "slipping");
        }
    }
}

/// Pair collisions on a block face: the head-on rebound ratio equals the restitution coefficient
/// within 1 %; linear and angular momentum are conserved to 1e-12 relative (impulses act on both bodies
/// once, whichever block owns the contact). Block Gauss–Seidel solves a contact on its owner, and with
/// three rounds per sub-step later rounds keep the first round's restitution target instead of applying
/// it again; the Jacobi solver computes it on both of its blocks from the same published velocities.
#[test]
fn collisions_conserve_momentum_and_rebound_with_restitution() {
    let jacobi = "particles.solver=\"jacobi\"";
    for (e, solver) in [
        (0.2, &[][..]),
        (0.5, &[][..]),
        (0.9, &[][..]),
        (0.5, &["particles.rounds=3"][..]),
        (0.5, &[jacobi][..]),
    ] {
        let set = format!("particles.restitution={e}");
        let sets: Vec<&str> = std::iter::once(set.as_str()).chain(solver.iter().copied()).collect();
        let s = run("collision.toml", &sets);
        let r = observable(&s, "restitution_head_on");
        assert!((r - e).abs() <= 0.01 * e, "e = {e}: measured {r}");
        assert!(observable(&s, "momentum_error") <= 1e-12);
        assert!(observable(&s, "angular_momentum_error") <= 1e-12);
        assert!(observable(&s, "energy_ratio") < 1.0);
        assert!(s.particles.as_ref().unwrap().contacts_per_substep > 0.0);
    }
}

/// The default granular box (Jacobi, as its file sets) settles (1000 steps): max overlap below 1 % of D and kinetic energy down by four orders
/// of magnitude from the start (it only gains energy from the fall before the pile forms).
#[test]
fn granular_box_settles_with_small_overlap() {
    let s = run("granular_box.toml", &["run.steps=1000"]);
    assert_eq!(observable(&s, "bodies"), 500.0);
    let ov = observable(&s, "max_overlap");
    assert!(ov < 0.01, "max overlap {ov} D");
    let c = cfg("granular_box.toml", &[]);
    let scene = blockflow::scenes::build(&c).unwrap();
    let e0: f64 = scene.particles.unwrap().bodies.iter().map(|b| b.kinetic_energy()).sum();
    let peak = 500.0 * 0.5 * (4.0 / 3.0 * std::f64::consts::PI * 1.75f64.powi(3)) * 2.0 * 2e-3 * 12.0;
    let ke = observable(&s, "kinetic_energy");
    assert!(ke < 1e-4 * peak.max(e0), "kinetic energy {ke} (scale {peak})");
    assert!(observable(&s, "mean_height") < 14.0, "the pile sits at the bottom");
}

fn granular_checksum_serial(sets: &[&str], steps: u64) -> u64 {
    let mut sim = sim64("granular_box.toml", sets);
    let p = sim.particles.as_mut().unwrap();
    p.advance_serial(0, steps).unwrap();
    p.checksum(steps)
}

/// granular_box (mid-fall and piling up, with contacts across block faces) is bitwise identical through
/// the task graph for P ∈ {1, 2, 5} with both curve assignments, and equal to the serial block loop.
#[test]
fn granular_box_bitwise_identical_for_any_assignment() {
    let base = ["scene.count=250", "processes.steps_per_graph=3"];
    let steps = 250;
    let want = granular_checksum_serial(&base, steps);
    for p in [1, 2, 5] {
        for curve in ["hilbert", "morton"] {
            let mut sets: Vec<String> = base.iter().map(|s| s.to_string()).collect();
            sets.push(format!("processes.count={p}"));
            sets.push(format!("balance.strategy=\"{curve}\""));
            sets.push("balance.interval=50".into());
            let refs: Vec<&str> = sets.iter().map(|s| s.as_str()).collect();
            let mut tl = timeloop("granular_box.toml", &refs);
            assert_eq!(
                *tl.pipeline().owners().iter().max().unwrap() as usize,
                p - 1,
                "every process owns blocks"
            );
            tl.advance(steps).expect("stable");
            let parts = tl.sim().particles.as_ref().unwrap();
            assert!(parts.counters.contacts > 0);
            assert_eq!(parts.checksum(steps), want, "P = {p}, {curve}");
        }
    }
}

/// With two rounds of the contact solve per sub-step, granular_box is bitwise identical through the task
/// graph for P ∈ {1, 3} and equal to the serial block loop, and the rounds change the result (the later
/// round does work).
#[test]
fn granular_box_with_rounds_bitwise_identical_for_any_assignment() {
    let gs = "particles.solver=\"block_gauss_seidel\"";
    let base = [
        "scene.count=250",
        "processes.steps_per_graph=3",
        gs,
        "particles.rounds=2",
        "particles.iterations=5",
    ];
    let steps = 250;
    let want = granular_checksum_serial(&base, steps);
    let one_round = granular_checksum_serial(&["scene.count=250", gs, "particles.iterations=5"], steps);
    assert_ne!(want, one_round, "a second round changes the solve");
    for p in [1, 3] {
        let mut sets: Vec<String> = base.iter().map(|s| s.to_string()).collect();
        sets.push(format!("processes.count={p}"));
        sets.push("balance.strategy=\"hilbert\"".into());
        sets.push("balance.interval=50".into());
        let refs: Vec<&str> = sets.iter().map(|s| s.as_str()).collect();
        let mut tl = timeloop("granular_box.toml", &refs);
        tl.advance(steps).expect("stable");
        let parts = tl.sim().particles.as_ref().unwrap();
        assert!(parts.counters.contacts > 0);
        assert_eq!(parts.checksum(steps), want, "P = {p}");
    }
}

/// The Jacobi solver's result does not depend on the block layout: granular_box (mid-fall and piling
/// up, 250 spheres) ends with the same bits on one block, on its 16 default blocks and on 4 and 8 blocks
/// of other shapes (serial block loop), and through the task graph for P ∈ {1, 3} with blocks migrating
/// (each migration carries the contacts' impulses, the next sub-step's warm start, in the block format).
/// The block Gauss–Seidel solver gives another result on 1 and on 16 blocks.
#[test]
fn jacobi_granular_box_is_bitwise_identical_for_any_block_layout() {
    let base = [
        "scene.count=250",
        "processes.steps_per_graph=3",
        "particles.solver=\"jacobi\"",
    ];
    let steps = 250;
    let with = |extra: &[&str]| -> Vec<String> { base.iter().chain(extra).map(|s| s.to_string()).collect() };
    let serial = |sets: Vec<String>| {
        let refs: Vec<&str> = sets.iter().map(|s| s.as_str()).collect();
        granular_checksum_serial(&refs, steps)
    };
    let one = ["domain.blocks=[1,1,1]", "domain.block_size=[32,32,64]"];
    let want = serial(with(&one));
    assert_eq!(serial(with(&[])), want, "16 blocks of 16³");
    assert_eq!(
        serial(with(&["domain.blocks=[2,2,1]", "domain.block_size=[16,16,64]"])),
        want,
        "4 columns"
    );
    assert_eq!(
        serial(with(&["domain.blocks=[1,2,4]", "domain.block_size=[32,16,16]"])),
        want,
        "8 slabs"
    );
    let gs = "particles.solver=\"block_gauss_seidel\"";
    let gs_one = granular_checksum_serial(&["scene.count=250", gs, one[0], one[1]], steps);
    let gs_16 = granular_checksum_serial(&["scene.count=250", gs], steps);
    assert_ne!(gs_one, gs_16, "block Gauss–Seidel depends on the layout");
    assert_ne!(gs_one, want, "the solvers differ");
    for p in [1, 3] {
        let mut sets = with(&["balance.strategy=\"hilbert\"", "balance.interval=50"]);
        sets.push(format!("processes.count={p}"));
        let refs: Vec<&str> = sets.iter().map(|s| s.as_str()).collect();
        let mut tl = timeloop("granular_box.toml", &refs);
        tl.advance(steps).expect("stable");
        let parts = tl.sim().particles.as_ref().unwrap();
        assert!(parts.counters.contacts > 0);
        if p == 3 {
            assert!(tl.balancer().is_some_and(|b| b.migrated > 0), "blocks migrated");
        }
        assert_eq!(parts.checksum(steps), want, "P = {p}");
    }
}

/// Block Gauss–Seidel (20 sub-steps of 10 sweeps) settles the granular box (1000 steps) as the test
/// above asks of the default Jacobi solver: max overlap below 1 % of D, kinetic energy four orders below
/// the fall's.
#[test]
fn block_gauss_seidel_granular_box_settles_with_small_overlap() {
    let s = run(
        "granular_box.toml",
        &[
            "run.steps=1000",
            "particles.solver=\"block_gauss_seidel\"",
            "particles.iterations=10",
        ],
    );
    let ov = observable(&s, "max_overlap");
    assert!(ov < 0.01, "max overlap {ov} D");
    let peak = 500.0 * 0.5 * (4.0 / 3.0 * std::f64::consts::PI * 1.75f64.powi(3)) * 2.0 * 2e-3 * 12.0;
    let ke = observable(&s, "kinetic_energy");
    assert!(ke < 1e-4 * peak, "kinetic energy {ke} (scale {peak})");
    assert!(observable(&s, "mean_height") < 14.0, "the pile sits at the bottom");
}

/// Collisions across a periodic face, with two blocks and with one block (the block is its own
/// periodic neighbour), by either solver: the head-on rebound ratio equals e within 1 %, momentum is
/// conserved to 1e-12, and the bodies come back into [0, L) after crossing.
#[test]
fn periodic_collisions_across_the_wrap() {
    for (blocks, jacobi) in [
        ([2, 1, 1], false),
        ([1, 1, 1], false),
        ([2, 1, 1], true),
        ([1, 1, 1], true),
    ] {
        let d = DomainSpec {
            blocks,
            block_size: [32 / blocks[0], 16, 16],
            periodic: [true, true, true],
        };
        let e = 0.6;
        let params = RigidParams {
            gravity: DVec3::ZERO,
            restitution: e,
            restitution_threshold: 1e-4,
            ..RigidParams::default()
        };
        let (r, u) = (2.0, 0.05);
        let mut a = Body::sphere(0, DVec3::new(32.0 - r - 0.2, 8.0, 8.0), r, 1.0);
        let mut b = Body::sphere(1, DVec3::new(r + 0.2, 8.0, 8.0), r, 3.0);
        a.velocity = DVec3::new(u, 0.0, 0.0);
        b.velocity = DVec3::new(-u, 0.0, 0.0);
        let p0 = a.mass() * a.velocity + b.mass() * b.velocity;
        let scale = a.mass() * u + b.mass() * u;
        let mut p = Particles::new(d, vec![a, b], Vec::new(), params, 10, 1.0).unwrap();
        if jacobi {
            // The block that is its own periodic neighbour holds both bodies and both their images.
            p = p.with_jacobi(0.8);
        }
        p.advance_serial(0, 100).unwrap();
        let bs = p.bodies(100);
        let p1 = bs[0].mass() * bs[0].velocity + bs[1].mass() * bs[1].velocity;
        assert!(
            (p1 - p0).length() <= 1e-12 * scale,
            "{blocks:?}, jacobi {jacobi}: momentum {p0} -> {p1}"
        );
        let ratio = (bs[1].velocity.x - bs[0].velocity.x) / (2.0 * u);
        assert!(
            (ratio - e).abs() <= 0.01 * e,
            "{blocks:?}, jacobi {jacobi}: rebound ratio {ratio}"
        );
        for x in &bs {
            assert!(
                (0.0..32.0).contains(&x.position.x),
                "{blocks:?}, jacobi {jacobi}: wrapped position {}",
                x.position.x
            );
        }
        assert!(p.counters.contacts > 0);
    }
}
