//! `summary.json` of a finished run, from the time loop's state, totals and intervals.

use crate::config::BalanceConfig;
use crate::error::Result;
use crate::io::summary::{
    BalanceSummary, Checksums, ParticleSummary, PartsSeconds, RankMessages, Summary, WorkSummary,
};
use crate::physics::parts::Part;
use crate::physics::simulation::Simulation;
use crate::pipeline::kinds::TaskKind;
use crate::pipeline::SkipRule;
use crate::pipeline::Totals;
use crate::ranks::views;
use crate::timeloop::TimeLoop;
use crate::util::stats::median;
use blockflow_kernels::Real;

/// Fills the fields of `s` that the run's end state, totals and intervals give: steps, parts, task
/// counts, particles, balance, work and checksums (the caller sets timing, status and observables).
/// Under ranks every rank calls it (the totals and checksums are added over the ranks).
pub fn fill<T: Real>(s: &mut Summary, tl: &TimeLoop<T>, cfg: &BalanceConfig, tasks_per_step: usize) -> Result<()> {
    let sim = tl.sim();
    let pipe = tl.pipeline();
    let world = tl.world();
    let totals = pipe.totals().summed(world)?;
    let t = &totals;
    s.steps = sim.step;
    s.no_skip = pipe.settings().no_skip;
    s.tasks_by_kind = TaskKind::ALL
        .iter()
        .filter(|k| t.tasks_by_kind[k.index()] > 0)
        .map(|k| (k.name().to_string(), t.tasks_by_kind[k.index()]))
        .collect();
    s.tasks_cpu_seconds_by_kind = TaskKind::ALL
        .iter()
        .filter(|k| t.tasks_by_kind[k.index()] > 0)
        .map(|k| (k.name().to_string(), t.cpu_by_kind[k.index()]))
        .collect();
    if !world.is_single() {
        s.rank_messages = Some(
            t.rank_messages
                .iter()
                .map(|(k, &(messages, bytes))| (k.clone(), RankMessages { messages, bytes }))
                .collect(),
        );
        s.rank_pair_bytes = Some(t.rank_bytes.clone());
    }
    let rules = || SkipRule::ALL.iter().map(|r| r.name().to_string());
    s.unskipped_by_rule = s.no_skip.then(|| rules().zip(t.unskipped).collect());
    s.unskipped_cpu_seconds_by_rule = s.no_skip.then(|| rules().zip(t.unskipped_cpu).collect());
    let coupled = sim.particles.is_some() && sim.fluid_cells() > 0;
    let p = &t.part_cpu;
    s.parts_seconds = PartsSeconds {
        lbm: p[Part::Lbm],
        boundary: p[Part::Boundary],
        exchange: p[Part::Exchange],
        rigid_body: sim.particles.as_ref().map(|_| p[Part::RigidBody]),
        map: coupled.then_some(p[Part::Map]),
        reconstruct: coupled.then_some(p[Part::Reconstruct]),
    };
    let bodies = views::bodies(world, sim)?.len();
    s.particles = sim.particles.as_ref().map(|p| ParticleSummary {
        bodies,
        subcycles: p.subcycles,
        solver: p.solver,
        rounds: p.rounds,
        substeps: p.counters.substeps,
        contacts_per_substep: p.counters.contacts as f64 / p.counters.substeps.max(1) as f64,
        max_penetration: p.counters.max_penetration,
        active_blocks: p.active.iter().filter(|&&a| a).count(),
    });
    s.balance = Some(balance(tl, t, cfg, tasks_per_step));
    s.work = work(sim);
    let (fluid, particles) = views::checksums(world, sim)?;
    s.checksum = Checksums {
        fluid: format!("{fluid:016x}"),
        particles: particles.map(|p| format!("{p:016x}")),
    };
    Ok(())
}

/// The `balance` record: strategy, per-interval imbalance, modeled times, migration, messages.
fn balance<T: Real>(
    tl: &TimeLoop<T>,
    t: &Totals,
    cfg_balance: &BalanceConfig,
    tasks_per_step: usize,
) -> BalanceSummary {
    let pipe = tl.pipeline();
    let owners = pipe.owners();
    let procs = pipe.processes();
    let iv = tl.intervals();
    let imbalance: Vec<f64> = iv.iter().map(|i| i.imbalance).collect();
    BalanceSummary {
        strategy: format!("{:?}", cfg_balance.strategy).to_lowercase(),
        interval: cfg_balance.interval,
        imbalance_median: if imbalance.is_empty() { 0.0 } else { median(&imbalance) },
        imbalance,
        predicted_imbalance: iv
            .iter()
            .map(|i| i.predicted_imbalance.is_finite().then_some(i.predicted_imbalance))
            .collect(),
        modeled_seconds: iv.iter().map(|i| i.modeled_seconds).sum(),
        bsp_seconds: iv.iter().map(|i| i.bsp_seconds).sum(),
        balance_seconds: iv.iter().map(|i| i.balance_seconds).sum(),
        migrated_bytes: iv.iter().map(|i| i.migrated_bytes).sum(),
        latency: cfg_balance.latency,
        bandwidth: cfg_balance.bandwidth,
        edge_cut_mean: crate::metrics::edge_cut::edge_cut_mean(&tl.sim().domain, owners, procs),
        migrated_blocks: tl.balancer().map_or(0, |b| b.migrated),
        blocks_per_process: (0..procs as u32)
            .map(|p| owners.iter().filter(|&&o| o == p).count())
            .collect(),
        message_bytes: t.message_bytes,
        remote_messages: t.remote_messages,
        local_copies: t.local_copies,
        tasks_per_step,
    }
}

/// The work the skip rules left per step.
fn work<T: Real>(sim: &Simulation<T>) -> WorkSummary {
    let (sweeps, bnd, msgs) = sim.blocks.iter().fold((0, 0, 0), |(s, b, m), blk| {
        if blk.fluid_cells == 0 {
            (s, b, m)
        } else {
            (s + 1, b + usize::from(!blk.links.is_empty()), m + blk.recv.len())
        }
    });
    WorkSummary {
        fluid_sweeps_per_step: sweeps,
        boundary_passes_per_step: bnd,
        messages_per_step: msgs,
        blocks_without_fluid: sim.blocks.iter().filter(|b| b.fluid_cells == 0).count(),
        blocks_without_boundary: sim
            .blocks
            .iter()
            .filter(|b| b.fluid_cells > 0 && b.links.is_empty())
            .count(),
    }
}
