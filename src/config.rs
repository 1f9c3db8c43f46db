//! Scene configuration: TOML files with the stable keys of DESIGN.md, `--set key.path=value` overrides,
//! unknown keys rejected by name.

use crate::error::{config_err, Error, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// A whole scene file.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// Block decomposition (`[domain]`).
    #[serde(default)]
    pub domain: DomainConfig,
    /// Fluid model (`[fluid]`).
    #[serde(default)]
    pub fluid: FluidConfig,
    /// Run control (`[run]`).
    #[serde(default)]
    pub run: RunConfig,
    /// Virtual processes and threads (`[processes]`).
    #[serde(default)]
    pub processes: ProcessesConfig,
    /// Block assignment and balancing (`[balance]`).
    #[serde(default)]
    pub balance: BalanceConfig,
    /// Rigid bodies and their solver (`[particles]`).
    #[serde(default)]
    pub particles: ParticlesConfig,
    /// The scene and its physical parameters (`[scene]`, chosen by `kind`).
    pub scene: crate::scenes::SceneConfig,
}

/// `[particles]`: the hard-contact rigid-body solver (section 2.2, Algorithm 7) of scenes with bodies.
/// Units are the scene's: lattice units (Δx = Δt = 1) when the fluid is on. Keys left out take the
/// scene's default where it has one (gravity, restitution threshold), else the default below.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ParticlesConfig {
    /// Rigid-body sub-steps S per time step (Algorithm 1; the hydrodynamic force is held over them).
    #[serde(default = "d_subcycles")]
    pub subcycles: usize,
    /// Coefficient of restitution e of the normal contact (0: plastic, 1: elastic).
    #[serde(default = "d_restitution")]
    pub restitution: f64,
    /// Coulomb friction coefficient μ.
    #[serde(default = "d_friction")]
    pub friction: f64,
    /// Projected Gauss–Seidel sweeps over the contacts of a block per sub-step.
    #[serde(default = "d_iterations")]
    pub iterations: usize,
    /// Relaxation ω of the Gauss–Seidel update, in (0, 2).
    #[serde(default = "d_relaxation")]
    pub relaxation: f64,
    /// Body count (locals + shadows of a block) from which detection uses the hash grid, not all pairs.
    #[serde(default = "d_grid_threshold")]
    pub grid_threshold: usize,
    /// Gap below which a contact is generated (speculative contacts), ≥ 0.
    #[serde(default)]
    pub contact_margin: f64,
    /// Baumgarte factor β in [0, 1]: a penetration d is removed at speed β d / Δt_sub.
    #[serde(default = "d_position_correction")]
    pub position_correction: f64,
    /// Approach speed above which restitution applies; absent: the scene's default.
    pub restitution_threshold: Option<f64>,
    /// Gravitational acceleration; absent: the scene's default.
    pub gravity: Option<[f64; 3]>,
    /// Time per step for scenes without fluid (with fluid the step is the lattice time unit, 1); absent:
    /// the scene's default.
    pub dt: Option<f64>,
    /// Boundary condition at particle surfaces: `"cli"` (default; eq. 6 with the ray–sphere δ_q, simple
    /// bounce-back where the second fluid cell is missing) or `"sbb"` (simple bounce-back).
    #[serde(default)]
    pub boundary: crate::coupling::SurfaceBoundary,
    /// Average the hydrodynamic force and torque over the current and the previous step (default on:
    /// without it, spheres lighter than about twice the fluid's density oscillate and blow up).
    #[serde(default = "yes")]
    pub force_averaging: bool,
}

fn d_subcycles() -> usize {
    10
}
fn d_restitution() -> f64 {
    0.5
}
fn d_friction() -> f64 {
    0.3
}
fn d_iterations() -> usize {
    20
}
fn d_relaxation() -> f64 {
    1.0
}
fn d_grid_threshold() -> usize {
    32
}
fn d_position_correction() -> f64 {
    0.2
}

impl Default for ParticlesConfig {
    fn default() -> Self {
        ParticlesConfig {
            subcycles: d_subcycles(),
            restitution: d_restitution(),
            friction: d_friction(),
            iterations: d_iterations(),
            relaxation: d_relaxation(),
            grid_threshold: d_grid_threshold(),
            contact_margin: 0.0,
            position_correction: d_position_correction(),
            restitution_threshold: None,
            gravity: None,
            dt: None,
            boundary: Default::default(),
            force_averaging: true,
        }
    }
}

impl ParticlesConfig {
    /// Checks every key's range; the message names the key and the allowed range.
    pub fn validate(&self) -> Result<()> {
        let p = self;
        if p.subcycles == 0 || p.subcycles > 255 {
            return config_err(format!(
                "particles.subcycles = {}: must be between 1 and 255",
                p.subcycles
            ));
        }
        if p.iterations == 0 || p.iterations > 100_000 {
            return config_err(format!(
                "particles.iterations = {}: must be between 1 and 100000",
                p.iterations
            ));
        }
        let checks: [(&str, f64, bool, &str); 5] = [
            (
                "restitution",
                p.restitution,
                (0.0..=1.0).contains(&p.restitution),
                "between 0 and 1",
            ),
            ("friction", p.friction, p.friction >= 0.0, "≥ 0"),
            (
                "relaxation",
                p.relaxation,
                p.relaxation > 0.0 && p.relaxation < 2.0,
                "in (0, 2)",
            ),
            ("contact_margin", p.contact_margin, p.contact_margin >= 0.0, "≥ 0"),
            (
                "position_correction",
                p.position_correction,
                (0.0..=1.0).contains(&p.position_correction),
                "between 0 and 1",
            ),
        ];
        for (k, v, ok, what) in checks {
            if !ok || !v.is_finite() {
                return config_err(format!("particles.{k} = {v}: must be {what}"));
            }
        }
        if let Some(t) = p.restitution_threshold {
            if !(t >= 0.0 && t.is_finite()) {
                return config_err(format!("particles.restitution_threshold = {t}: must be ≥ 0"));
            }
        }
        if let Some(g) = p.gravity {
            if g.iter().any(|v| !v.is_finite()) {
                return config_err(format!("particles.gravity = {g:?}: must be finite"));
            }
        }
        if let Some(dt) = p.dt {
            if !(dt > 0.0 && dt.is_finite()) {
                return config_err(format!("particles.dt = {dt}: must be a finite number > 0"));
            }
        }
        Ok(())
    }
}

/// `[domain]`: how the scene's box of cells is cut into blocks.
#[derive(Clone, Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct DomainConfig {
    /// Blocks per axis. Scenes with a fixed extent derive `block_size` from it.
    pub blocks: Option<[usize; 3]>,
    /// Cells per block and axis (non-cubic allowed).
    pub block_size: Option<[usize; 3]>,
    /// Periodicity per axis; scenes that fix it reject a different value.
    pub periodic: Option<[bool; 3]>,
}

/// Storage and compute precision of the PDFs.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
    /// Double precision (default).
    #[default]
    F64,
    /// Single precision: about twice the MLUPS, errors floor near 1e-6.
    F32,
}

/// Which kernels a fluid block runs.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum KernelChoice {
    /// Fused pull-stream + collide (default; bitwise equal to `split`).
    #[default]
    Fused,
    /// Separate stream and collide sweeps.
    Split,
}

/// `[fluid]`: the lattice Boltzmann model.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct FluidConfig {
    /// Relaxation time τ+ (ν = (τ - 1/2)/3, eq. 5). Absent: the scene's default or derived value.
    pub tau: Option<f64>,
    /// Magic parameter Λ of eq. (5); 3/16 puts bounce-back walls exactly half-way.
    #[serde(default = "default_magic")]
    pub magic: f64,
    /// `"f64"` (default) or `"f32"`.
    #[serde(default)]
    pub precision: Precision,
    /// Largest |u| (lattice units) before the run is stopped as unstable.
    #[serde(default = "default_velocity_limit")]
    pub velocity_limit: f64,
    /// `"fused"` (default) or `"split"` kernels.
    #[serde(default)]
    pub kernel: KernelChoice,
    /// `false` switches the fluid off (rigid bodies only): no PDF is stored or computed, no fluid task.
    #[serde(default = "yes")]
    pub enabled: bool,
}

fn yes() -> bool {
    true
}

fn default_magic() -> f64 {
    3.0 / 16.0
}
fn default_velocity_limit() -> f64 {
    0.5
}

impl Default for FluidConfig {
    fn default() -> Self {
        FluidConfig {
            tau: None,
            magic: default_magic(),
            precision: Precision::F64,
            velocity_limit: default_velocity_limit(),
            kernel: KernelChoice::Fused,
            enabled: true,
        }
    }
}

/// `[run]`: run length, output and checkpoints.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RunConfig {
    /// Number of time steps; absent: the scene's own (e.g. to steady state).
    pub steps: Option<u64>,
    /// Output folder; absent: `out/<scene file name>`.
    pub out: Option<String>,
    /// Write a row of `series.csv` every this many steps (default: about 100 rows per run, at least every 10 steps).
    pub series_every: Option<u64>,
    /// Write VTK output every this many steps (default: never).
    pub vtk_every: Option<u64>,
    /// Write a checkpoint (`OUT/checkpoints/step-<step>`) whenever the step is a multiple of this
    /// (default: never; `--checkpoint-every`).
    pub checkpoint_every: Option<u64>,
    /// Write a checkpoint when this many wall-clock seconds have passed since the last one (default:
    /// never; `--checkpoint-wall`).
    pub checkpoint_wall: Option<f64>,
    /// Checkpoints kept: after each write all but the newest this many are deleted (default 2).
    #[serde(default = "d_checkpoints_kept")]
    pub checkpoints_kept: usize,
    /// Run every task on every block (`--no-skip`; default false): switches off the skip rules of
    /// DESIGN.md principle 2 (outside blocks, blocks without boundary cells, blocks without particles,
    /// static geometry mapped once, the fused kernel) to measure what they save. For measurement only:
    /// slower, and the results are bitwise the same. See [`crate::pipeline`].
    #[serde(default)]
    pub no_skip: bool,
}

fn d_checkpoints_kept() -> usize {
    crate::checkpoint::DEFAULT_KEPT
}

impl Default for RunConfig {
    fn default() -> Self {
        RunConfig {
            steps: None,
            out: None,
            series_every: None,
            vtk_every: None,
            checkpoint_every: None,
            checkpoint_wall: None,
            checkpoints_kept: d_checkpoints_kept(),
            no_skip: false,
        }
    }
}

/// `processes.pin`: a policy name or an explicit core list.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq, Eq)]
#[serde(untagged)]
pub enum PinConfig {
    /// `"compact"`, `"scatter"` or `"none"` (or a list written as a string, `"0,2,4-7"`).
    Name(String),
    /// Explicit cores, one per worker thread in process-major order.
    Cores(Vec<usize>),
}

impl Default for PinConfig {
    fn default() -> Self {
        PinConfig::Name("none".into())
    }
}

/// `processes.steal`: where idle threads may take ready tasks from.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum StealConfig {
    /// Only inside their own virtual process (MPI-faithful; default).
    #[default]
    Process,
    /// From any process: a shared-memory experiment MPI cannot run.
    Global,
}

/// `[processes]`: virtual processes (thread groups standing in for MPI ranks).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ProcessesConfig {
    /// Number of virtual processes P.
    #[serde(default = "one")]
    pub count: usize,
    /// Threads per process T.
    #[serde(default = "one")]
    pub threads_per_process: usize,
    /// Pinning policy.
    #[serde(default)]
    pub pin: PinConfig,
    /// Stealing policy.
    #[serde(default)]
    pub steal: StealConfig,
    /// Steps per task-graph run: consecutive steps overlap inside a run (no barrier between them); the
    /// instability detector and the time series look at the state between runs.
    #[serde(default = "d_graph_steps")]
    pub steps_per_graph: usize,
}

fn one() -> usize {
    1
}
fn d_graph_steps() -> usize {
    4
}

impl Default for ProcessesConfig {
    fn default() -> Self {
        ProcessesConfig {
            count: 1,
            threads_per_process: 1,
            pin: PinConfig::default(),
            steal: StealConfig::Process,
            steps_per_graph: d_graph_steps(),
        }
    }
}

/// `balance.strategy`: how blocks are assigned to processes.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Strategy {
    /// Static Hilbert split by fluid-cell count at the start (the paper's baseline).
    #[default]
    None,
    /// 3D Hilbert curve order, greedy prefix split.
    Hilbert,
    /// Morton curve order, greedy prefix split.
    Morton,
    /// Diffusive balancing between neighbouring processes (waLBerla's `DynamicDiffusionBalance`), starting
    /// from the Hilbert assignment; see `balance::diffusive`.
    Diffusive,
    /// METIS k-way graph partitioning of the block graph (eq. 17 edge weights), relabelled to keep blocks
    /// where they are, starting from the Hilbert assignment; see `balance::graph_partition`.
    Metis,
}

/// `balance.diffusive_mode`: who decides which blocks move in the diffusive strategy.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum DiffusiveMode {
    /// Processes with outflow send blocks to their neighbours (default).
    #[default]
    Push,
    /// Processes with inflow take blocks from their neighbours.
    Pull,
}

/// `[balance]`: assignment and balancing.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct BalanceConfig {
    /// Strategy.
    #[serde(default)]
    pub strategy: Strategy,
    /// Steps per balancing / measurement interval.
    #[serde(default = "d_interval")]
    pub interval: u64,
    /// Block weight: `"cells"` (fluid cells; default), `"estimator"` (eq. 15 with `balance.coefficients`),
    /// `"measured"` (the block's m_tot over the last interval) or `"corrected"` (the estimate times the
    /// smoothed measured/predicted ratio). With every strategy but `"none"` (which never moves a
    /// block) the blocks are redistributed with these weights at the end of every interval.
    #[serde(default)]
    pub weights: Weights,
    /// Coefficients file of the estimator (written by `blockflow calibrate`); used with
    /// `weights = "estimator"`.
    #[serde(default = "d_coefficients")]
    pub coefficients: String,
    /// How the curve order is cut into processes: `"greedy"` (the paper's prefix split; default) or
    /// `"optimal"` (the contiguous split minimising the heaviest process, by bisection on the bottleneck).
    #[serde(default)]
    pub split: SplitKind,
    /// Diffusive strategy: diffusion iterations over the process graph per main iteration (the flow
    /// estimate on every process-process edge; at least 1).
    #[serde(default = "d_flow_iterations")]
    pub flow_iterations: usize,
    /// Diffusive strategy: main iterations per balancing step (a block moves at most one process hop per
    /// main iteration; at least 1).
    #[serde(default = "d_diffusive_iterations")]
    pub diffusive_iterations: usize,
    /// Diffusive strategy: `"push"` (overloaded processes send; default) or `"pull"` (underloaded processes
    /// take).
    #[serde(default)]
    pub diffusive_mode: DiffusiveMode,
    /// METIS strategy: allowed load imbalance, max part weight / mean part weight (METIS' ufactor is
    /// `(metis_imbalance - 1) * 1000`; at least 1.0; default 1.05).
    #[serde(default = "d_metis_imbalance")]
    pub metis_imbalance: f64,
    /// Latency α of a message between processes in the modeled times (seconds; default 2e-6, an
    /// InfiniBand FDR cluster like the paper's SuperMUC).
    #[serde(default = "d_latency")]
    pub latency: f64,
    /// Bandwidth β of a message between processes in the modeled times (bytes per second; default 5e9).
    #[serde(default = "d_bandwidth")]
    pub bandwidth: f64,
}

/// `balance.split`.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum SplitKind {
    /// For each process in turn, take blocks while that brings it closer to remaining weight / remaining
    /// processes.
    #[default]
    Greedy,
    /// The contiguous split of the same order with the lightest heaviest part.
    Optimal,
}

/// `balance.weights`: what a block weighs.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Weights {
    /// Fluid cells (cells when the fluid is off).
    #[default]
    Cells,
    /// The workload estimate of eq. (15) from the block's Table 1 quantities.
    Estimator,
    /// The block's own measured m_tot over the last interval (cells for the initial assignment).
    Measured,
    /// The estimate scaled by the block's smoothed measured/predicted ratio (section 3.5; see
    /// `estimator::weights`; the plain estimate for the initial assignment).
    Corrected,
}

fn d_coefficients() -> String {
    "configs/coefficients.toml".to_string()
}

fn d_interval() -> u64 {
    100
}

fn d_flow_iterations() -> usize {
    15
}

fn d_diffusive_iterations() -> usize {
    20
}

fn d_metis_imbalance() -> f64 {
    1.05
}

fn d_latency() -> f64 {
    crate::study::model::DEFAULT_LATENCY
}

fn d_bandwidth() -> f64 {
    crate::study::model::DEFAULT_BANDWIDTH
}

impl Default for BalanceConfig {
    fn default() -> Self {
        BalanceConfig {
            strategy: Strategy::None,
            interval: d_interval(),
            weights: Weights::Cells,
            coefficients: d_coefficients(),
            split: SplitKind::Greedy,
            flow_iterations: d_flow_iterations(),
            diffusive_iterations: d_diffusive_iterations(),
            diffusive_mode: DiffusiveMode::Push,
            metis_imbalance: d_metis_imbalance(),
            latency: d_latency(),
            bandwidth: d_bandwidth(),
        }
    }
}

/// Reads a scene file, applies `--set` overrides and validates the generic keys.
pub fn load(path: &Path, overrides: &[String]) -> Result<Config> {
    let text =
        std::fs::read_to_string(path).map_err(|e| Error::Config(format!("cannot read {}: {e}", path.display())))?;
    parse(&text, &path.display().to_string(), overrides)
}

/// Parses scene text (named `origin` in messages), applies overrides and validates.
pub fn parse(text: &str, origin: &str, overrides: &[String]) -> Result<Config> {
    let mut table = parse_table(text, origin)?;
    for o in overrides {
        apply_override(&mut table, o)?;
    }
    match table.get("scene") {
        Some(sc) => crate::scenes::check_table(sc).map_err(|m| Error::Config(format!("{origin}: {m}")))?,
        None => {
            return config_err(format!(
                "{origin}: missing [scene] table (with kind = \"channel\", ...)"
            ))
        }
    }
    let cfg: Config = serde_path_to_error::deserialize(toml::Value::Table(table)).map_err(|e| {
        let path = e.path().to_string();
        let inner = one_line(&e.inner().to_string());
        let key = if path == "." {
            String::new()
        } else {
            format!("{path}: ")
        };
        Error::Config(format!("{origin}: {key}{inner}"))
    })?;
    cfg.validate().map_err(|e| Error::Config(format!("{origin}: {e}")))?;
    Ok(cfg)
}

/// Parses TOML text into a table; a syntax error is one line naming `origin`, line and column.
pub fn parse_table(text: &str, origin: &str) -> Result<toml::Table> {
    text.parse().map_err(|e: toml::de::Error| {
        let pos = e
            .span()
            .map(|s| {
                let line = text[..s.start].matches('\n').count() + 1;
                let col = s.start - text[..s.start].rfind('\n').map_or(0, |p| p + 1) + 1;
                format!(" at line {line}, column {col}")
            })
            .unwrap_or_default();
        Error::Config(format!("{origin}: TOML syntax error{pos}: {}", one_line(e.message())))
    })
}

fn one_line(s: &str) -> String {
    s.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// Applies one `key.path=value` override. The value is read as a TOML value (`0.6`, `[2, 2, 1]`, `true`,
/// `"f32"`); anything that does not parse as TOML is taken as a string (`fluid.precision=f32`).
pub fn apply_override(table: &mut toml::Table, spec: &str) -> Result<()> {
    let Some((key, raw)) = spec.split_once('=') else {
        return config_err(format!("--set {spec}: expected key.path=value"));
    };
    let key = key.trim();
    let raw = raw.trim();
    if key.is_empty() || key.split('.').any(|p| p.is_empty()) {
        return config_err(format!("--set {spec}: empty key"));
    }
    let value = match format!("v = {raw}").parse::<toml::Table>() {
        Ok(mut t) => t.remove("v").expect("parsed key"),
        Err(_) => toml::Value::String(raw.to_string()),
    };
    let parts: Vec<&str> = key.split('.').collect();
    let mut cur = table;
    for (i, p) in parts[..parts.len() - 1].iter().enumerate() {
        let entry = cur
            .entry(p.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        cur = match entry {
            toml::Value::Table(t) => t,
            _ => return config_err(format!("--set {spec}: {} is not a table", parts[..=i].join("."))),
        };
    }
    cur.insert(parts[parts.len() - 1].to_string(), value);
    Ok(())
}

impl Config {
    /// Checks the generic keys; scenes check their own.
    pub fn validate(&self) -> Result<()> {
        if let Some(t) = self.fluid.tau {
            if t.is_nan() || t <= 0.5 || !t.is_finite() {
                return config_err(format!(
                    "fluid.tau = {t}: must be a finite number > 0.5 (ν = (τ - 1/2)/3 must be positive)"
                ));
            }
        }
        if self.fluid.magic.is_nan() || self.fluid.magic <= 0.0 || !self.fluid.magic.is_finite() {
            return config_err(format!(
                "fluid.magic = {}: must be a finite number > 0 (default 0.1875)",
                self.fluid.magic
            ));
        }
        if self.fluid.velocity_limit.is_nan() || self.fluid.velocity_limit <= 0.0 {
            return config_err(format!(
                "fluid.velocity_limit = {}: must be > 0 (default 0.5)",
                self.fluid.velocity_limit
            ));
        }
        for (name, v) in [
            ("domain.blocks", self.domain.blocks),
            ("domain.block_size", self.domain.block_size),
        ] {
            if let Some(v) = v {
                if v.contains(&0) {
                    return config_err(format!("{name} = {v:?}: every entry must be at least 1"));
                }
            }
        }
        let pr = &self.processes;
        for (name, v) in [
            ("processes.count", pr.count),
            ("processes.threads_per_process", pr.threads_per_process),
            ("processes.steps_per_graph", pr.steps_per_graph),
        ] {
            if v == 0 || v > 4096 {
                return config_err(format!("{name} = {v}: must be between 1 and 4096"));
            }
        }
        self.particles.validate()?;
        if self.balance.interval == 0 {
            return config_err("balance.interval = 0: must be at least 1 step");
        }
        for (name, v) in [
            ("balance.flow_iterations", self.balance.flow_iterations),
            ("balance.diffusive_iterations", self.balance.diffusive_iterations),
        ] {
            if v == 0 || v > 100_000 {
                return config_err(format!("{name} = {v}: must be between 1 and 100000"));
            }
        }
        let mi = self.balance.metis_imbalance;
        if !(mi.is_finite() && (1.0..=3.0).contains(&mi)) {
            return config_err(format!(
                "balance.metis_imbalance = {mi}: must be a finite number between 1.0 and 3.0"
            ));
        }
        let (a, b) = (self.balance.latency, self.balance.bandwidth);
        if !(a.is_finite() && (0.0..=1.0).contains(&a)) {
            return config_err(format!("balance.latency = {a}: must be between 0 and 1 second"));
        }
        if !(b.is_finite() && b >= 1e3) {
            return config_err(format!(
                "balance.bandwidth = {b}: must be at least 1e3 bytes per second"
            ));
        }
        for (name, v) in [
            ("run.series_every", self.run.series_every),
            ("run.vtk_every", self.run.vtk_every),
        ] {
            if v == Some(0) {
                return config_err(format!("{name} = 0: must be at least 1 (leave it out to disable)"));
            }
        }
        if self.run.checkpoint_every == Some(0) {
            return config_err("run.checkpoint_every = 0: must be at least 1 step (leave it out to disable)");
        }
        if let Some(w) = self.run.checkpoint_wall {
            if !(w.is_finite() && w > 0.0) {
                return config_err(format!(
                    "run.checkpoint_wall = {w}: must be a finite number of seconds > 0 (leave it out to disable)"
                ));
            }
        }
        if self.run.checkpoints_kept == 0 || self.run.checkpoints_kept > 1_000_000 {
            return config_err(format!(
                "run.checkpoints_kept = {}: must be between 1 and 1000000",
                self.run.checkpoints_kept
            ));
        }
        Ok(())
    }

    /// The configuration as TOML (what `effective.toml` holds: every default and override resolved).
    pub fn to_toml(&self) -> String {
        toml::to_string(self).unwrap_or_default()
    }
}
