//! The bookkeeping of the skip rules (DESIGN.md principle 2): which tasks a graph holds per kind and,
//! under `run.no_skip`, which rule each extra task is owed to.

use super::*;

/// The skip rules of DESIGN.md principle 2 that `run.no_skip` switches off (see the module docs):
/// outside blocks, blocks without boundary cells, blocks without particles, static geometry mapped once,
/// and the fused kernel.
pub const SKIP_RULES: [&str; 5] = ["outside", "no_boundary", "no_particles", "static_map", "fused_kernel"];
const RULE_OUTSIDE: usize = 0;
const RULE_NO_BOUNDARY: usize = 1;
const RULE_NO_PARTICLES: usize = 2;
const RULE_STATIC: usize = 3;
const RULE_FUSED: usize = 4;
pub(super) const NO_RULE: u8 = u8::MAX;

/// Task counts of one compiled graph.
#[derive(Clone, Debug, Default)]
pub(super) struct GraphCounts {
    pub(super) by_kind: [u64; 10],
    pub(super) by_rule: [u64; 5],
    /// The rule each task is owed to (index into [`SKIP_RULES`]; `NO_RULE`: it runs with the rules on).
    pub(super) rule_of: Vec<u8>,
}

/// Counts the tasks of a compiled graph per kind and, with `no_skip`, the work per skip rule that is
/// done only because the rule is off (classified from the same block state the graph was built from).
pub(super) fn count_tasks<T: Real>(
    sim: &Simulation<T>,
    graph: &TaskGraph,
    force_boundary: &[bool],
    no_skip: bool,
) -> GraphCounts {
    let mut c = GraphCounts {
        rule_of: vec![NO_RULE; graph.len()],
        ..Default::default()
    };
    let active = |b: usize| sim.particles.as_ref().is_some_and(|p| p.active[b]);
    for (i, spec) in graph.specs().iter().enumerate() {
        let kind = (spec.payload & 15) as usize;
        c.by_kind[kind] += 1;
        if !no_skip {
            continue;
        }
        let blk = &sim.blocks[spec.block as usize];
        let outside = blk.fluid_cells == 0;
        let rule = match kind as u32 {
            KIND_COMM | KIND_BOUNDARY | KIND_SWEEP if outside => Some(RULE_OUTSIDE),
            KIND_COMM if blk.recv.is_empty() => Some(RULE_OUTSIDE),
            KIND_BOUNDARY if blk.links.is_empty() && !force_boundary[blk.id] => Some(RULE_NO_BOUNDARY),
            KIND_SWEEP if sim.kernel == KernelChoice::Fused => Some(RULE_FUSED),
            KIND_MAP | KIND_RECON | KIND_FORCES | KIND_RB | KIND_RB_SYNC if !active(blk.id) => Some(RULE_NO_PARTICLES),
            KIND_MAP | KIND_RECON if outside => Some(RULE_OUTSIDE),
            KIND_STATIC => Some(RULE_STATIC),
            _ => None,
        };
        if let Some(r) = rule {
            c.by_rule[r] += 1;
            c.rule_of[i] = r as u8;
        }
    }
    c
}
