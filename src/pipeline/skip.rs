//! The bookkeeping of the skip rules (DESIGN.md principle 2): which tasks a graph holds per kind and,
//! under `run.no_skip`, which rule each extra task is owed to.

use super::graph::RbGroups;
use super::kinds::{ByKind, Payload, TaskKind};
use crate::config::KernelChoice;
use crate::physics::simulation::Simulation;
use blockflow_kernels::Real;
use blockflow_scheduler::TaskGraph;

/// A skip rule of DESIGN.md principle 2 that `run.no_skip` switches off (see the module docs of
/// [`super`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum SkipRule {
    /// A block without fluid gets no task, a block without a ghost region to receive no `comm`.
    Outside = 0,
    /// A block without links gets no `boundary` task.
    NoBoundary = 1,
    /// Only blocks a body can reach get particle tasks.
    NoParticles = 2,
    /// Walls and planes are mapped into flags and links once, at set-up.
    StaticMap = 3,
    /// The sweep runs the configured kernel over the fluid runs mapped once.
    FusedKernel = 4,
}

impl SkipRule {
    /// Every rule, in index order.
    pub const ALL: [SkipRule; 5] = [
        SkipRule::Outside,
        SkipRule::NoBoundary,
        SkipRule::NoParticles,
        SkipRule::StaticMap,
        SkipRule::FusedKernel,
    ];

    /// Name in outputs (`summary.json`'s `unskipped_by_rule`, `blockflow bench skip`).
    pub fn name(self) -> &'static str {
        match self {
            SkipRule::Outside => "outside",
            SkipRule::NoBoundary => "no_boundary",
            SkipRule::NoParticles => "no_particles",
            SkipRule::StaticMap => "static_map",
            SkipRule::FusedKernel => "fused_kernel",
        }
    }
}

/// One value per [`SkipRule`].
pub type ByRule<V> = [V; 5];

/// Task counts of one compiled graph.
#[derive(Clone, Debug, Default)]
pub(super) struct GraphCounts {
    /// Block stages per kind: a task that runs the rigid-body phase of a group of blocks counts once per
    /// member, so the counts do not depend on the grouping.
    pub(super) by_kind: ByKind<u64>,
    pub(super) by_rule: ByRule<u64>,
    /// The rule each task is owed to (`None`: it runs with the rules on).
    pub(super) rule_of: Vec<Option<SkipRule>>,
}

/// Counts the block stages of a compiled graph per kind (the members of `groups` each once) and, with
/// `no_skip`, the work per skip rule that is done only because the rule is off (classified from the
/// same block state the graph was built from; `run.no_skip` groups nothing).
pub(super) fn count_tasks<T: Real>(
    sim: &Simulation<T>,
    graph: &TaskGraph,
    groups: &RbGroups,
    force_boundary: &[bool],
    no_skip: bool,
) -> GraphCounts {
    let mut c = GraphCounts {
        rule_of: vec![None; graph.len()],
        ..Default::default()
    };
    let active = |b: usize| sim.particles.as_ref().is_some_and(|p| p.active[b]);
    for (i, spec) in graph.specs().iter().enumerate() {
        let payload = Payload::of(spec);
        let kind = payload.kind;
        let rounds = sim.particles.as_ref().map_or(1, |p| p.rounds);
        c.by_kind[kind.index()] += match kind {
            TaskKind::Rb | TaskKind::RbSync => groups
                .members(spec.block as usize, payload.sub % rounds)
                .map_or(1, |m| m.len() as u64),
            _ => 1,
        };
        if !no_skip {
            continue;
        }
        let blk = &sim.blocks[spec.block as usize];
        let outside = blk.fluid_cells == 0;
        use TaskKind::*;
        let rule = match kind {
            Comm | Boundary | Sweep if outside => Some(SkipRule::Outside),
            Comm if blk.recv.is_empty() => Some(SkipRule::Outside),
            Boundary if blk.links.is_empty() && !force_boundary[blk.id] => Some(SkipRule::NoBoundary),
            Sweep if sim.kernel == KernelChoice::Fused => Some(SkipRule::FusedKernel),
            Map | Reconstruct | Forces | Rb | RbSync if !active(blk.id) => Some(SkipRule::NoParticles),
            Map | Reconstruct if outside => Some(SkipRule::Outside),
            StaticMap => Some(SkipRule::StaticMap),
            _ => None,
        };
        if let Some(r) = rule {
            c.by_rule[r as usize] += 1;
            c.rule_of[i] = Some(r);
        }
    }
    c
}
