//! The mapping's shortcuts (rows taken from the previous mapping, the fast path of a block with no
//! body near) against the full rebuild of every row, at every step of hopper-small's real body motion.

mod common;
use blockflow::physics::coupling::map_with;
use blockflow::physics::coupling::tasks::bodies_near;
use blockflow::physics::particle_cells::ParticleCells;
use common::timeloop;

/// Everything a mapping produces, for comparison.
fn mapped(pc: &ParticleCells) -> impl PartialEq + std::fmt::Debug + '_ {
    (
        (&pc.owner, pc.owned(), &pc.segments, &pc.link_cells),
        (
            &pc.turned,
            &pc.covered,
            pc.fluid_cells,
            pc.near_particle_cells,
            pc.near_boundary_cells,
        ),
        pc.bodies.iter().map(|m| m.id).collect::<Vec<_>>(),
    )
}

#[test]
fn incremental_mapping_equals_the_full_rebuild_at_every_step_of_hopper_small() {
    let mut tl = timeloop("hopper-small.toml", &[]);
    let sim = tl.sim();
    // Two overlays per block, mapped with and without shortcuts from the same start.
    let mut pairs: Vec<Option<(ParticleCells, ParticleCells)>> = sim
        .blocks
        .iter()
        .map(|b| b.particle_cells().map(|pc| (pc.clone(), pc.clone())))
        .collect();
    assert!(
        pairs.iter().flatten().count() > 50,
        "hopper-small has overlays on most blocks"
    );
    let (mut mappings, mut reused, mut changed) = (0usize, 0usize, 0usize);
    for _ in 0..300 {
        tl.advance(1).expect("step");
        let sim = tl.sim();
        let parts = sim.particles.as_ref().expect("particles");
        for (blk, pair) in sim.blocks.iter().zip(pairs.iter_mut()) {
            let Some((short, full)) = pair else { continue };
            let bodies = bodies_near(parts, blk, sim.step);
            let before = short.link_cells.clone();
            map_with(&sim.domain, blk, short, bodies.clone(), true);
            map_with(&sim.domain, blk, full, bodies, false);
            assert_eq!(mapped(short), mapped(full), "block {} after step {}", blk.id, sim.step);
            mappings += 1;
            if short.link_cells == before && !before.is_empty() {
                reused += 1;
            }
            if !short.turned.is_empty() || !short.covered.is_empty() {
                changed += 1;
            }
        }
    }
    // The comparison saw bodies move: cells turned and were covered, and link lists stayed the same too.
    assert!(
        changed > 1000 && reused > 100,
        "mappings {mappings}, changed {changed}, unchanged links {reused}"
    );
}
