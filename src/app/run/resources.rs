//! What a run needs from the machine, checked before anything is allocated: memory.

use crate::config::{Config, Precision};
use crate::error::{Error, Result};
use crate::scenes::{self, Scene};
use blockflow_kernels::Layout;

/// Bytes available to a new allocation: the smallest of `MemAvailable` (/proc/meminfo), the cgroup v2
/// `memory.max` and four fifths of the soft `RLIMIT_AS` (None where /proc/meminfo cannot be read).
pub fn available_memory() -> Option<u128> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: u128 = line.split_whitespace().nth(1)?.parse().ok()?;
    let mut avail = kb * 1024;
    // A container's or batch job's cgroup limit (v2) and the process's own address-space limit bound it
    // too (with a fifth left for the binary and the allocator; the threads' stacks are estimated apart).
    if let Some(max) = std::fs::read_to_string("/sys/fs/cgroup/memory.max")
        .ok()
        .and_then(|t| t.trim().parse::<u128>().ok())
    {
        avail = avail.min(max);
    }
    let mut lim = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit writes the struct it is given.
    if unsafe { libc::getrlimit(libc::RLIMIT_AS, &mut lim) } == 0 && lim.rlim_cur != libc::RLIM_INFINITY {
        avail = avail.min(lim.rlim_cur as u128 / 5 * 4);
    }
    Some(avail)
}

/// The memory a scene's state needs, estimated before anything is allocated.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MemoryEstimate {
    /// Everything, bytes.
    pub total: u128,
    /// PDFs: per block one field (AA streaming) or two (pull) of 19 padded arrays over the cells with
    /// the ghost layer, in the precision.
    pub pdf: u128,
    /// Flags: one byte per cell with the ghost layer.
    pub flags: u128,
    /// Particles: each body's copies (two published lists, the rigid-body result, shadows) and the
    /// per-block bookkeeping.
    pub particles: u128,
    /// The worker threads' stacks and signal stacks ([`THREAD_BYTES`] each): address space more than
    /// memory, but an address-space limit counts it.
    pub stacks: u128,
}

/// Address space one worker thread takes: the standard library's 2 MiB stack, its guard page and the
/// signal stack (a thread that cannot map its signal stack aborts the process).
pub const THREAD_BYTES: u128 = 2 * 1024 * 1024 + 64 * 1024;

/// Worker threads this OS process starts: P × T, or R × T with R ranks in the process (under MPI each
/// rank has only its own T, so this bounds it from above).
pub fn worker_threads(cfg: &Config) -> u128 {
    let p = &cfg.processes;
    let groups = if p.ranks > 1 { p.ranks } else { p.count };
    groups as u128 * p.threads_per_process as u128
}

/// The memory estimate of a scene under a configuration.
pub fn estimate_memory(cfg: &Config, scene: &Scene) -> Result<MemoryEstimate> {
    let d = scenes::domain_for(&cfg.domain, scene)?;
    let blocks: u128 = d.blocks.iter().map(|&x| x as u128).product();
    let full: u128 = d.block_size.iter().map(|&x| x as u128 + 2).product();
    // One field exactly as a block allocates it (rows padded, arrays page-rounded and skewed).
    let field: u128 = match cfg.fluid.precision {
        Precision::F64 => 8 * Layout::new::<f64>(d.block_size).len() as u128,
        Precision::F32 => 4 * Layout::new::<f32>(d.block_size).len() as u128,
    };
    let fluid = cfg.fluid.enabled && !scene.geometry.no_fluid;
    let fields = cfg.fluid.streaming.pattern().fields() as u128;
    let pdf = if fluid { fields * blocks * field } else { 0 };
    let flags = blocks * full;
    let particles = match scene.particles.as_ref().filter(|_| cfg.particles.enabled) {
        Some(ps) => {
            let body = std::mem::size_of::<blockflow_kernels::rigid::Body>() as u128;
            ps.bodies.len() as u128 * body * 8 + blocks * 1024
        }
        None => 0,
    };
    let stacks = worker_threads(cfg) * THREAD_BYTES;
    Ok(MemoryEstimate {
        total: pdf + flags + particles + stacks,
        pdf,
        flags,
        particles,
        stacks,
    })
}

/// Refuses a scene whose estimated memory ([`estimate_memory`]) exceeds what the machine has available.
pub fn check_memory(cfg: &Config, scene: &Scene) -> Result<()> {
    check_memory_of_copies(cfg, scene, 1)
}

/// [`check_memory`] for `copies` states built at once in this process: in-process ranks each build the
/// whole state before they release the blocks they do not hold, and they start together, so the state
/// counts once per rank (the threads' stacks once in all).
pub fn check_memory_of_copies(cfg: &Config, scene: &Scene, copies: usize) -> Result<()> {
    let MemoryEstimate {
        total,
        pdf,
        flags,
        particles,
        stacks,
    } = estimate_memory(cfg, scene)?;
    let state = (total - stacks) * copies as u128;
    let total = state + stacks;
    let Some(avail) = available_memory().filter(|&a| total > a) else {
        return Ok(());
    };
    // Name what to change: what takes most of it.
    let change = if copies > 1 && state * 2 > total {
        format!("use fewer ranks (processes.ranks = {copies}: each builds the whole state), or MPI")
    } else if stacks * 2 > total {
        format!(
            "use fewer processes or threads (processes.count = {}, processes.ranks = {}, \
             processes.threads_per_process = {})",
            cfg.processes.count, cfg.processes.ranks, cfg.processes.threads_per_process
        )
    } else {
        "use fewer or smaller blocks (domain.blocks, domain.block_size, scene.resolution)".to_string()
    };
    Err(Error::Config(format!(
        "scene {} needs an estimated {total} bytes ({:.1} GiB: {copies} × (PDFs {pdf}, flags {flags}, particles \
         {particles}), stacks of {} worker threads {stacks}) but the machine has {avail} bytes available \
         (MemAvailable, cgroup and address-space limits); {change}",
        scene.name,
        total as f64 / (1u64 << 30) as f64,
        worker_threads(cfg)
    )))
}
