//! `summary.json`: the stable result record of a run (DESIGN.md, "Command line and output contract").
//! Names are never renamed; fields that do not apply to a run are absent.

use crate::physics::parts::Part;
use serde::Serialize;
use std::collections::BTreeMap;

/// Seconds per part of Algorithm 1 (parts a run does not have are absent).
#[derive(Clone, Debug, Default, Serialize)]
pub struct PartsSeconds {
    /// Collide and stream (or the fused kernel).
    pub lbm: f64,
    /// Boundary handling.
    pub boundary: f64,
    /// Ghost exchange (not one of the paper's parts; reported beside them).
    pub exchange: f64,
    /// Particle mapping.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub map: Option<f64>,
    /// PDF reconstruction.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reconstruct: Option<f64>,
    /// Rigid-body sub-steps.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rigid_body: Option<f64>,
}

impl PartsSeconds {
    /// Every part with its label ([`Part::label`]) and its seconds (None: the run has no such part), in
    /// the order of the step's tables: LBM, boundary, exchange, map, reconstruct, rigid body.
    pub fn labelled(&self) -> [(&'static str, Option<f64>); 6] {
        [
            (Part::Lbm.label(), Some(self.lbm)),
            (Part::Boundary.label(), Some(self.boundary)),
            (Part::Exchange.label(), Some(self.exchange)),
            (Part::Map.label(), self.map),
            (Part::Reconstruct.label(), self.reconstruct),
            (Part::RigidBody.label(), self.rigid_body),
        ]
    }
}

/// Hashes over the exact bits of the final state (hex).
#[derive(Clone, Debug, Default, Serialize)]
pub struct Checksums {
    /// Every fluid cell's PDFs; independent of block layout and processes.
    pub fluid: String,
    /// Every body's state (absent without particles).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub particles: Option<String>,
}

/// Work per step that the skip rule left (DESIGN.md principle 2).
#[derive(Clone, Debug, Default, Serialize)]
pub struct WorkSummary {
    /// Blocks that ran the fluid sweep each step.
    pub fluid_sweeps_per_step: usize,
    /// Blocks that ran a boundary pass each step.
    pub boundary_passes_per_step: usize,
    /// Ghost regions exchanged each step.
    pub messages_per_step: usize,
    /// Blocks without any fluid cell (no fluid work at all).
    pub blocks_without_fluid: usize,
    /// Blocks whose fluid cells have no wall neighbour (no boundary pass).
    pub blocks_without_boundary: usize,
}

/// Assignment and imbalance (`balance.*`), per DESIGN.md.
#[derive(Clone, Debug, Default, Serialize)]
pub struct BalanceSummary {
    /// Strategy name.
    pub strategy: String,
    /// Steps per interval.
    pub interval: u64,
    /// Load imbalance eq. (18) per interval (workload m_tot eq. 16: CPU time of every task but the ghost
    /// exchange, per owner process).
    pub imbalance: Vec<f64>,
    /// Median of `imbalance`.
    pub imbalance_median: f64,
    /// The load imbalance the block weights predicted for each interval's assignment (null where the
    /// assignment was not made from weights).
    pub predicted_imbalance: Vec<Option<f64>>,
    /// Modeled time to solution (`graph` model): every step graph replayed with its measured task
    /// durations on P×T dedicated cores, messages between processes at α + bytes/β (meaningful even when
    /// P×T exceeds this machine's cores).
    pub modeled_seconds: f64,
    /// Modeled time to solution (`bsp` model): per step the slowest process, messages included.
    pub bsp_seconds: f64,
    /// Measured seconds of the balancing steps (weights, partition, migration, the graph recompiled).
    pub balance_seconds: f64,
    /// Bytes of the serialised blocks migrated.
    pub migrated_bytes: u64,
    /// Mean edge cut eq. (17) of the assignment (face b², edge b, corner 1 between blocks of different
    /// processes; non-cubic blocks use the shared face area and edge length).
    pub edge_cut_mean: f64,
    /// Blocks migrated by rebalancing.
    pub migrated_blocks: u64,
    /// Message latency α (s) and bandwidth β (B/s) of the modeled times.
    pub latency: f64,
    /// β.
    pub bandwidth: f64,
    /// Blocks per process.
    pub blocks_per_process: Vec<usize>,
    /// Bytes sent in cross-process messages.
    pub message_bytes: u64,
    /// Cross-process messages.
    pub remote_messages: u64,
    /// Ghost regions copied directly inside a process.
    pub local_copies: u64,
    /// Tasks per step of the one-step graph compiled at the start of the run (its rigid-body groups cut
    /// from the loads of the state it starts from: none yet in a fresh run, so one group per process).
    pub tasks_per_step: usize,
}

/// Messages of one kind between ranks.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct RankMessages {
    /// Messages sent.
    pub messages: u64,
    /// Their bytes, headers included.
    pub bytes: u64,
}

/// The whole summary.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Summary {
    /// `"ok"`, `"unstable"`, `"interrupted"` (SIGINT / SIGTERM: `steps` is the step reached, `checkpoint`
    /// the state to continue from) or `"error"`: only `"ok"` is a result.
    pub status: String,
    /// The error message when status is not ok.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// The last checkpoint this run wrote (absent: none).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub checkpoint: Option<String>,
    /// Checkpoints this run wrote.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub checkpoints_written: Option<u64>,
    /// Seconds spent writing them (encoding, write, fsync, rename).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub checkpoint_seconds: Option<f64>,
    /// Bytes of the last checkpoint written.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub checkpoint_bytes: Option<u64>,
    /// The checkpoint this run was restarted from (absent: a fresh start).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub restarted_from: Option<String>,
    /// Step of that checkpoint: this run computed steps `restart_step + 1 ..= steps` (timings and the
    /// balance record cover those; particle counters and migrated blocks are run totals).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub restart_step: Option<u64>,
    /// Scene kind.
    pub scene: String,
    /// Lattice spacing (m), time step (s) and fluid density (kg/m³) of a scene given in SI units.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub units: Option<crate::scenes::Units>,
    /// One line on the physical set-up.
    pub description: String,
    /// Steps completed.
    pub steps: u64,
    /// Steps requested.
    pub steps_requested: u64,
    /// Cells of the domain.
    pub cells: usize,
    /// Fluid cells.
    pub fluid_cells: usize,
    /// Blocks.
    pub blocks: usize,
    /// Blocks per axis.
    pub block_grid: [usize; 3],
    /// Cells per block and axis.
    pub block_size: [usize; 3],
    /// Virtual processes (under ranks: the ranks, each one process).
    pub processes: usize,
    /// Ranks that share no memory (1: every block in one OS process's shared memory).
    pub ranks: usize,
    /// Threads per process.
    pub threads_per_process: usize,
    /// `"f64"` or `"f32"`.
    pub precision: String,
    /// Streaming pattern: `"aa"` (one PDF field per block, in place) or `"pull"` (two).
    pub streaming: String,
    /// Bytes of PDF storage allocated over all blocks (padding and ghost layers included).
    pub pdf_bytes: u64,
    /// The memory estimate the run was checked against before anything was allocated, bytes.
    pub memory_estimate_bytes: u64,
    /// Relaxation time τ+.
    pub tau: f64,
    /// Magic parameter Λ.
    pub magic: f64,
    /// Wall-clock seconds of the time loop (set-up and output excluded).
    pub wall_seconds: f64,
    /// Fluid cell updates per second / 1e6 over the whole step.
    pub mlups: f64,
    /// Seconds per part.
    pub parts_seconds: PartsSeconds,
    /// Final-state hashes.
    pub checksum: Checksums,
    /// Scene observables.
    pub observables: BTreeMap<String, f64>,
    /// Skip-rule bookkeeping.
    pub work: WorkSummary,
    /// Whether the run ran every task on every block (`run.no_skip`, measurement only).
    pub no_skip: bool,
    /// Under ranks: the messages between ranks over the run by what they carry (`send`: ghost regions,
    /// `rb_sync` and `forces`: published bodies, `rb`: velocity changes, `boundary` and `map`: body
    /// forces, `halo`: the neighbours' particle state before each graph run, `migrate`: moved blocks).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rank_messages: Option<BTreeMap<String, RankMessages>>,
    /// Under ranks: bytes of those messages from each rank (row) to each rank (column).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rank_pair_bytes: Option<Vec<Vec<u64>>>,
    /// Block stages executed over the run, per kind (`send`, `comm`, `boundary`, `sweep`, `map`, ...): a
    /// task that runs the rigid-body phase of a group of blocks counts once per member.
    pub tasks_by_kind: BTreeMap<String, u64>,
    /// With `run.no_skip`: the work done only because the skip rules were off, per rule (`outside`,
    /// `no_boundary`, `no_particles`, `static_map`: tasks; `fused_kernel`: sweeps on the general path).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub unskipped_by_rule: Option<BTreeMap<String, u64>>,
    /// CPU seconds of the tasks per kind over the run.
    pub tasks_cpu_seconds_by_kind: BTreeMap<String, f64>,
    /// With `run.no_skip`: CPU seconds of the work in `unskipped_by_rule`, per rule (`fused_kernel`: the
    /// general-path sweeps of the fluid blocks, whole).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub unskipped_cpu_seconds_by_rule: Option<BTreeMap<String, f64>>,
    /// Pinned core of each worker thread (absent: not pinned).
    pub cores: Vec<Option<usize>>,
    /// Assignment and imbalance.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub balance: Option<BalanceSummary>,
    /// Rigid bodies (absent without particles).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub particles: Option<ParticleSummary>,
}

/// The rigid-body part of a run.
#[derive(Clone, Debug, Default, Serialize)]
pub struct ParticleSummary {
    /// Number of bodies.
    pub bodies: usize,
    /// Sub-steps per step.
    pub subcycles: usize,
    /// How the contacts are solved (`particles.solver`).
    pub solver: crate::config::ContactSolver,
    /// Rounds of the contact solve per sub-step (with the Jacobi solver: one per sweep plus the set-up).
    pub rounds: usize,
    /// Sub-steps taken.
    pub substeps: u64,
    /// Owned contacts per sub-step, averaged over the run.
    pub contacts_per_substep: f64,
    /// Largest penetration seen in any contact during the run (before resolution).
    pub max_penetration: f64,
    /// Blocks with rigid-body tasks at the end.
    pub active_blocks: usize,
}
