//! Checkpoints and restart (`blockflow run --checkpoint-every N`, `--checkpoint-wall SECONDS`,
//! `--restart PATH`), and the clean interruption of a run by SIGINT / SIGTERM.
//!
//! A checkpoint is one file, `OUT/checkpoints/step-<step>`, holding the whole state after `<step>` steps:
//! every block's bytes as [`crate::serialise::encode_block`] writes them (PDFs, flags, particle overlay, the
//! block's bodies with their force-averaging history, its rigid-body state), the global particle state that
//! no block carries (the run's counters), the balancing state (the predictor–corrector of
//! `balance.weights = "corrected"` and the prediction of the interval under way, so a continued run takes
//! the same decisions from the same measurements) and the effective configuration. The blocks are stored
//! per block, never per process: the file does not depend on the process count, and a restart may use any
//! P, T, pinning, stealing and balancing strategy. The final state is then bitwise identical to the
//! uninterrupted run's (`tests/restart.rs`, `scripts/kill_resume`).
//!
//! # Format (version [`CHECKPOINT_VERSION`]), integers and floats little-endian
//!
//! | bytes | field |
//! |---|---|
//! | 8 | magic `b"BFCHKPT\n"` |
//! | u32 | format version |
//! | u64 | total length of the file, checksum included (a truncated copy is told from a corrupt one) |
//! | u32 | number of sections |
//! | per section | name length u8, name (ASCII), payload length u64 (a reader skips names it does not know) |
//! | ... | the payloads, in table order |
//! | u64 | FNV-1a checksum of every byte before it ([`crate::serialise::checksum`]) |
//!
//! Sections:
//! - `meta`: JSON, for people and tools: `format`, `version`, `step`, `scene`, `precision`, `blocks`,
//!   `block_grid`, `block_size`, `block_format` (version of the per-block encoding), `writer`.
//! - `config`: the effective configuration as TOML (every default and `--set` resolved, `run.steps` and
//!   `run.out` filled in): a scene file that reproduces the run.
//! - `blocks`: u64 block count, then per block in id order u64 length and the block's encoding.
//! - `particles` (scenes with bodies): the run totals of [`crate::particles::RigidCounters`]: sub-steps
//!   u64, contacts u64, largest penetration f64.
//! - `balance` (runs with a balancer): strategy and weights names (u8 length + ASCII each), balancing steps
//!   u64, blocks migrated u64, balancing seconds f64, corrector α f64 and clamp f64, u64 n and n ratios f64,
//!   u64 m and m predictions f64 (the interval under way). The owners are not stored: they never change
//!   a number, and a restart on another process count assigns the blocks afresh.
//!
//! Not stored: the ghost layers and the other PDF field (see [`crate::serialise`]), `Particles::active`
//! (recomputed before every graph run), the time series and interval measurements of the first part
//! (the restarted run writes its own from the checkpoint's step on).
//!
//! Writing is atomic: the bytes go to `checkpoints/.step-<step>.tmp`, which is fsynced, renamed to
//! `step-<step>` and the folder fsynced. A crash mid-write leaves at most a `.tmp` file that no reader
//! looks at; a file named `step-<step>` is always complete (and its checksum says so). After each write
//! only the newest `run.checkpoints_kept` (default 2) checkpoints are kept.
//!
//! # The configuration of a restarted run
//!
//! `blockflow run --restart PATH [SCENE] [--set ...] [--processes P ...]` starts from the checkpoint's
//! effective configuration and applies the command line's overrides on top. Keys under `run`,
//! `processes` and `balance` may change (steps, output, checkpointing, P, T, pinning, stealing,
//! steps per graph, strategy, interval, weights); any other key (domain, fluid, particles, scene) would
//! change the physics and is refused with a message naming it. A SCENE file, if given, is only checked:
//! its physics must be the checkpoint's, else the checkpoint is "from another scene". The output folder is
//! `--out`, else the checkpoint's `run.out` (the original run's folder). `run.steps` is the total step
//! count, so a restart continues to the original end unless `--steps` says otherwise.
//!
//! # Interruption
//!
//! [`install_signal_handlers`] (called by `blockflow run`) makes SIGINT and SIGTERM set a flag that the
//! run loop reads after every graph run (`processes.steps_per_graph` steps, default 4: a run stops at the
//! end of the graph run under way, not in the middle of it). The run then writes a checkpoint and
//! summary.json with `"status": "interrupted"` and the step reached, and exits with 128 + the signal
//! number (130 for SIGINT, 143 for SIGTERM). A second signal ends the process at once (`_exit`, same
//! code), leaving at most a `.tmp` checkpoint behind.

use crate::balance::dynamic::Balancer;
use crate::config::{self, Config};
use crate::error::{io_err, Error, Result};
use crate::serialise::{checksum, decode_block, encode_block, BLOCK_FORMAT_VERSION};
use crate::sim::Simulation;
use blockflow_kernels::Real;
use blockflow_scheduler::executor::Executor;
use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicI32, AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::Instant;

/// Version of the checkpoint format written by [`write`]; [`Checkpoint::read`] accepts only this one.
pub const CHECKPOINT_VERSION: u32 = 1;
/// First bytes of every checkpoint file.
pub const CHECKPOINT_MAGIC: [u8; 8] = *b"BFCHKPT\n";
/// Bytes before the section table: magic, version, total length, section count.
const HEADER_LEN: usize = 8 + 4 + 8 + 4;
/// Default of `run.checkpoints_kept`.
pub const DEFAULT_KEPT: usize = 2;
/// Top-level config tables a restart may change (they never change a number of the state).
pub const RESTART_MAY_CHANGE: [&str; 3] = ["run", "processes", "balance"];

// ---------------------------------------------------------------------------------------------------
// Signals

static SIGNALS: AtomicUsize = AtomicUsize::new(0);
static LAST_SIGNAL: AtomicI32 = AtomicI32::new(0);

extern "C" fn on_signal(sig: libc::c_int) {
    // Only async-signal-safe work here: atomics and `_exit`.
    if SIGNALS.fetch_add(1, Ordering::SeqCst) >= 1 {
        // SAFETY: `_exit` is async-signal-safe.
        unsafe { libc::_exit(128 + sig) };
    }
    LAST_SIGNAL.store(sig, Ordering::SeqCst);
}

/// Installs the SIGINT / SIGTERM handlers of `blockflow run`: the first signal asks the run to stop at the
/// end of the current graph run ([`interrupted`]), a second one ends the process at once.
pub fn install_signal_handlers() -> Result<()> {
    for sig in [libc::SIGINT, libc::SIGTERM] {
        // SAFETY: a zeroed sigaction is valid; the handler only touches atomics and calls `_exit`.
        let r = unsafe {
            let mut sa: libc::sigaction = std::mem::zeroed();
            sa.sa_sigaction = on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
            sa.sa_flags = libc::SA_RESTART;
            libc::sigemptyset(&mut sa.sa_mask);
            libc::sigaction(sig, &sa, std::ptr::null_mut())
        };
        if r != 0 {
            return Err(Error::Io(format!(
                "cannot install the handler of signal {sig}: {}",
                std::io::Error::last_os_error()
            )));
        }
    }
    Ok(())
}

/// The signal that asked the run to stop, if one did (SIGINT = 2, SIGTERM = 15).
pub fn interrupted() -> Option<i32> {
    if SIGNALS.load(Ordering::SeqCst) > 0 {
        Some(LAST_SIGNAL.load(Ordering::SeqCst))
            .filter(|&s| s > 0)
            .or(Some(libc::SIGTERM))
    } else {
        None
    }
}

/// Name of a signal number for messages.
pub fn signal_name(sig: i32) -> String {
    match sig {
        libc::SIGINT => "SIGINT".into(),
        libc::SIGTERM => "SIGTERM".into(),
        s => format!("signal {s}"),
    }
}

// ---------------------------------------------------------------------------------------------------
// Writing

fn put_u64(v: &mut Vec<u8>, x: u64) {
    v.extend_from_slice(&x.to_le_bytes());
}
fn put_f64(v: &mut Vec<u8>, x: f64) {
    v.extend_from_slice(&x.to_bits().to_le_bytes());
}
fn put_str(v: &mut Vec<u8>, s: &str) {
    let b = &s.as_bytes()[..s.len().min(255)];
    v.push(b.len() as u8);
    v.extend_from_slice(b);
}
fn put_f64s(v: &mut Vec<u8>, xs: &[f64]) {
    put_u64(v, xs.len() as u64);
    for &x in xs {
        put_f64(v, x);
    }
}

/// The balancing state a checkpoint carries.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BalanceState {
    /// `balance.strategy` of the writer.
    pub strategy: String,
    /// `balance.weights` of the writer.
    pub weights: String,
    /// Balancing steps taken.
    pub steps: u64,
    /// Blocks migrated so far.
    pub migrated: u64,
    /// Seconds spent balancing so far.
    pub seconds: f64,
    /// Corrector smoothing factor α.
    pub alpha: f64,
    /// Corrector clamp.
    pub clamp: f64,
    /// Corrector ratio per block.
    pub ratio: Vec<f64>,
    /// Prediction of eq. (15) summed over the interval under way, per block.
    pub predicted: Vec<f64>,
}

fn lower(s: impl std::fmt::Debug) -> String {
    format!("{s:?}").to_lowercase()
}

impl BalanceState {
    /// The state of a balancer.
    pub fn of(cfg: &Config, b: &Balancer) -> Self {
        BalanceState {
            strategy: lower(cfg.balance.strategy),
            weights: lower(b.weights),
            steps: b.steps,
            migrated: b.migrated,
            seconds: b.seconds,
            alpha: b.corrector.alpha,
            clamp: b.corrector.clamp,
            ratio: b.corrector.ratio.clone(),
            predicted: b.predicted().to_vec(),
        }
    }

    /// Puts the state into a balancer of the restarted run. The corrector and the interval's prediction
    /// are restored only when the weights are the same kind (they mean nothing to other weights); the
    /// counters always (they are run totals).
    pub fn restore(&self, b: &mut Balancer) {
        b.steps = self.steps;
        b.migrated = self.migrated;
        b.seconds = self.seconds;
        if lower(b.weights) == self.weights && self.ratio.len() == b.corrector.ratio.len() {
            b.corrector.ratio = self.ratio.clone();
            b.corrector.alpha = self.alpha;
            b.corrector.clamp = self.clamp;
            if self.predicted.len() == self.ratio.len() {
                b.set_predicted(self.predicted.clone());
            }
        }
    }

    fn encode(&self, v: &mut Vec<u8>) {
        put_str(v, &self.strategy);
        put_str(v, &self.weights);
        put_u64(v, self.steps);
        put_u64(v, self.migrated);
        put_f64(v, self.seconds);
        put_f64(v, self.alpha);
        put_f64(v, self.clamp);
        put_f64s(v, &self.ratio);
        put_f64s(v, &self.predicted);
    }
}

/// What a checkpoint holds besides the blocks.
pub struct CheckpointInput<'a> {
    /// The effective configuration text (TOML).
    pub config: &'a str,
    /// Scene name.
    pub scene: &'a str,
    /// Balancing state, for runs with a balancer.
    pub balance: Option<BalanceState>,
}

/// Encodes the whole state of `sim` as a checkpoint file's bytes.
pub fn encode<T: Real>(sim: &Simulation<T>, input: &CheckpointInput) -> Vec<u8> {
    let mut sections: Vec<(&str, Vec<u8>)> = Vec::new();
    let meta = serde_json::json!({
        "format": "blockflow checkpoint",
        "version": CHECKPOINT_VERSION,
        "step": sim.step,
        "scene": input.scene,
        "precision": T::NAME,
        "blocks": sim.blocks.len(),
        "block_grid": sim.domain.blocks,
        "block_size": sim.domain.block_size,
        "block_format": BLOCK_FORMAT_VERSION,
        "writer": concat!("blockflow ", env!("CARGO_PKG_VERSION")),
    });
    sections.push(("meta", meta.to_string().into_bytes()));
    sections.push(("config", input.config.as_bytes().to_vec()));
    let mut blocks = Vec::new();
    put_u64(&mut blocks, sim.blocks.len() as u64);
    let mut one = Vec::new();
    for id in 0..sim.blocks.len() {
        one.clear();
        encode_block(sim, id, &mut one);
        put_u64(&mut blocks, one.len() as u64);
        blocks.extend_from_slice(&one);
    }
    sections.push(("blocks", blocks));
    if let Some(p) = &sim.particles {
        let mut v = Vec::new();
        put_u64(&mut v, p.counters.substeps);
        put_u64(&mut v, p.counters.contacts);
        put_f64(&mut v, p.counters.max_penetration);
        sections.push(("particles", v));
    }
    if let Some(b) = &input.balance {
        let mut v = Vec::new();
        b.encode(&mut v);
        sections.push(("balance", v));
    }
    let table: usize = sections.iter().map(|(n, _)| 1 + n.len() + 8).sum();
    let payload: usize = sections.iter().map(|(_, p)| p.len()).sum();
    let total = HEADER_LEN + table + payload + 8;
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(&CHECKPOINT_MAGIC);
    out.extend_from_slice(&CHECKPOINT_VERSION.to_le_bytes());
    put_u64(&mut out, total as u64);
    out.extend_from_slice(&(sections.len() as u32).to_le_bytes());
    for (name, p) in &sections {
        put_str(&mut out, name);
        put_u64(&mut out, p.len() as u64);
    }
    for (_, p) in &sections {
        out.extend_from_slice(p);
    }
    let sum = checksum(&out);
    put_u64(&mut out, sum);
    debug_assert_eq!(out.len(), total);
    out
}

/// A checkpoint written by [`write`].
#[derive(Clone, Debug)]
pub struct Written {
    /// The file.
    pub path: PathBuf,
    /// Its size in bytes.
    pub bytes: u64,
    /// Seconds to encode and write it (fsync included).
    pub seconds: f64,
}

/// The checkpoint file of `step` in `dir` (`dir/step-<step>`).
pub fn file_of(dir: &Path, step: u64) -> PathBuf {
    dir.join(format!("step-{step}"))
}

/// Writes the checkpoint of `sim`'s current step into the folder `dir` atomically — temporary file, fsync,
/// rename, fsync of the folder — then deletes all but the newest `keep` checkpoints. `dir` must exist (a
/// folder removed during a run is an error, not silently recreated).
pub fn write<T: Real>(dir: &Path, sim: &Simulation<T>, input: &CheckpointInput, keep: usize) -> Result<Written> {
    let t0 = Instant::now();
    let bytes = encode(sim, input);
    let path = file_of(dir, sim.step);
    let tmp = dir.join(format!(".step-{}.tmp", sim.step));
    let res = (|| -> std::io::Result<()> {
        let mut f = File::create(&tmp)?;
        f.write_all(&bytes)?;
        f.sync_all()?;
        Ok(())
    })();
    if let Err(e) = res {
        let _ = std::fs::remove_file(&tmp);
        return Err(Error::Io(format!("checkpoint {}: {e}", tmp.display())));
    }
    if let Err(e) = std::fs::rename(&tmp, &path) {
        let _ = std::fs::remove_file(&tmp);
        return Err(Error::Io(format!("checkpoint {}: {e}", path.display())));
    }
    File::open(dir)
        .and_then(|d| d.sync_all())
        .map_err(|e| Error::Io(format!("checkpoint folder {}: {e}", dir.display())))?;
    prune(dir, keep.max(1))?;
    Ok(Written {
        path,
        bytes: bytes.len() as u64,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// The checkpoints in `dir` (files named `step-<step>`), by step ascending.
pub fn list(dir: &Path) -> Vec<(u64, PathBuf)> {
    let mut v: Vec<(u64, PathBuf)> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|e| {
            let name = e.file_name();
            let step = name.to_str()?.strip_prefix("step-")?.parse::<u64>().ok()?;
            e.file_type().ok()?.is_file().then(|| (step, e.path()))
        })
        .collect();
    v.sort();
    v
}

fn prune(dir: &Path, keep: usize) -> Result<()> {
    let all = list(dir);
    for (_, p) in all.iter().take(all.len().saturating_sub(keep)) {
        std::fs::remove_file(p).map_err(|e| io_err(p, e))?;
    }
    Ok(())
}

/// The checkpoint file `--restart PATH` names: PATH itself if it is a file; for a folder, the newest
/// checkpoint in it or in its `checkpoints` subfolder.
pub fn resolve(path: &Path) -> Result<PathBuf> {
    if path.is_dir() {
        for d in [path.to_path_buf(), path.join("checkpoints")] {
            if let Some((_, p)) = list(&d).pop() {
                return Ok(p);
            }
        }
        return Err(Error::Checkpoint(format!(
            "checkpoint {}: a folder without any checkpoint (step-<step> files) in it or in its checkpoints/ \
             subfolder",
            path.display()
        )));
    }
    Ok(path.to_path_buf())
}

// ---------------------------------------------------------------------------------------------------
// Reading

/// A checkpoint read and checked (magic, version, length, checksum, sections) by [`Checkpoint::read`].
pub struct Checkpoint {
    /// The file it was read from.
    pub path: PathBuf,
    /// Step of the state.
    pub step: u64,
    /// Scene name.
    pub scene: String,
    /// `"f64"` or `"f32"`.
    pub precision: String,
    /// The effective configuration text.
    pub config: String,
    /// Each block's encoding, by id.
    pub blocks: Vec<Vec<u8>>,
    /// Particle run totals (sub-steps, contacts, largest penetration).
    pub particles: Option<(u64, u64, f64)>,
    /// Balancing state.
    pub balance: Option<BalanceState>,
}

impl std::fmt::Debug for Checkpoint {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Checkpoint")
            .field("path", &self.path)
            .field("step", &self.step)
            .field("scene", &self.scene)
            .field("blocks", &self.blocks.len())
            .finish()
    }
}

struct Reader<'a> {
    b: &'a [u8],
    at: usize,
    what: &'static str,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> std::result::Result<&'a [u8], String> {
        if self.b.len() - self.at < n {
            return Err(format!("malformed: section {} ends early", self.what));
        }
        let s = &self.b[self.at..self.at + n];
        self.at += n;
        Ok(s)
    }
    fn u64(&mut self) -> std::result::Result<u64, String> {
        Ok(u64::from_le_bytes(self.take(8)?.try_into().expect("8 bytes")))
    }
    fn f64(&mut self) -> std::result::Result<f64, String> {
        Ok(f64::from_bits(self.u64()?))
    }
    fn str(&mut self) -> std::result::Result<String, String> {
        let n = self.take(1)?[0] as usize;
        String::from_utf8(self.take(n)?.to_vec()).map_err(|_| format!("malformed: section {}: not text", self.what))
    }
    fn len(&mut self, each: usize) -> std::result::Result<usize, String> {
        let n = self.u64()?;
        if n > ((self.b.len() - self.at) / each.max(1)) as u64 {
            return Err(format!("malformed: section {}: count {n} exceeds its bytes", self.what));
        }
        Ok(n as usize)
    }
    fn f64s(&mut self) -> std::result::Result<Vec<f64>, String> {
        let n = self.len(8)?;
        (0..n).map(|_| self.f64()).collect()
    }
    fn done(&self) -> std::result::Result<(), String> {
        if self.at == self.b.len() {
            Ok(())
        } else {
            Err(format!(
                "malformed: {} bytes after section {}",
                self.b.len() - self.at,
                self.what
            ))
        }
    }
}

impl Checkpoint {
    /// Reads and checks a checkpoint file. Every failure is an [`Error::Checkpoint`] of one line naming the
    /// file and the reason (unreadable, not a checkpoint, another format version, truncated, corrupt,
    /// malformed).
    pub fn read(path: &Path) -> Result<Checkpoint> {
        let bytes =
            std::fs::read(path).map_err(|e| Error::Checkpoint(format!("checkpoint {}: {e}", path.display())))?;
        Self::parse(&bytes, path).map_err(|m| Error::Checkpoint(format!("checkpoint {}: {m}", path.display())))
    }

    /// Checks and splits the bytes of a checkpoint (`path` only names it).
    pub fn parse(b: &[u8], path: &Path) -> std::result::Result<Checkpoint, String> {
        if b.len() < CHECKPOINT_MAGIC.len() || b[..CHECKPOINT_MAGIC.len()] != CHECKPOINT_MAGIC {
            return Err(if b.is_empty() {
                "empty file, not a blockflow checkpoint".into()
            } else {
                "not a blockflow checkpoint (the magic bytes BFCHKPT are missing)".into()
            });
        }
        if b.len() < HEADER_LEN {
            return Err(format!("truncated: {} bytes, shorter than the header", b.len()));
        }
        let version = u32::from_le_bytes(b[8..12].try_into().expect("4 bytes"));
        if version != CHECKPOINT_VERSION {
            return Err(format!(
                "format version {version}; this build reads version {CHECKPOINT_VERSION} (written by another \
                 blockflow version)"
            ));
        }
        let total = u64::from_le_bytes(b[12..20].try_into().expect("8 bytes"));
        if (b.len() as u64) < total {
            return Err(format!("truncated: {} bytes, the header announces {total}", b.len()));
        }
        if (b.len() as u64) > total {
            return Err(format!(
                "corrupt: {} bytes, the header announces {total} (trailing bytes or a damaged length)",
                b.len()
            ));
        }
        if total < (HEADER_LEN + 8) as u64 {
            return Err(format!("corrupt: announced length {total} is shorter than a header"));
        }
        let n = b.len();
        let stored = u64::from_le_bytes(b[n - 8..].try_into().expect("8 bytes"));
        let computed = checksum(&b[..n - 8]);
        if stored != computed {
            return Err(format!(
                "corrupt: checksum {stored:016x} stored, {computed:016x} computed (a damaged or partly written file)"
            ));
        }
        // Section table.
        let body = &b[..n - 8];
        let count = u32::from_le_bytes(b[20..24].try_into().expect("4 bytes")) as usize;
        let mut at = HEADER_LEN;
        let mut table = Vec::new();
        for _ in 0..count {
            let nl = *body.get(at).ok_or("malformed: section table ends early")? as usize;
            let name = body
                .get(at + 1..at + 1 + nl)
                .ok_or("malformed: section table ends early")?;
            let name = std::str::from_utf8(name).map_err(|_| "malformed: a section name is not text")?;
            let len = body
                .get(at + 1 + nl..at + 9 + nl)
                .ok_or("malformed: section table ends early")?;
            table.push((name, u64::from_le_bytes(len.try_into().expect("8 bytes"))));
            at += 9 + nl;
        }
        let mut sections = Vec::new();
        for (name, len) in table {
            if len > (body.len() - at) as u64 {
                return Err(format!("malformed: section {name} runs past the end"));
            }
            sections.push((name, &body[at..at + len as usize]));
            at += len as usize;
        }
        if at != body.len() {
            return Err(format!("malformed: {} bytes after the last section", body.len() - at));
        }
        let get = |name: &str| sections.iter().find(|s| s.0 == name).map(|s| s.1);
        let need = |name: &str| get(name).ok_or_else(|| format!("malformed: no {name} section"));
        let meta: serde_json::Value =
            serde_json::from_slice(need("meta")?).map_err(|e| format!("malformed: meta section: {e}"))?;
        let step = meta["step"].as_u64().ok_or("malformed: meta section has no step")?;
        let scene = meta["scene"].as_str().unwrap_or("").to_string();
        let precision = meta["precision"].as_str().unwrap_or("").to_string();
        let config =
            String::from_utf8(need("config")?.to_vec()).map_err(|_| "malformed: config section is not text")?;
        let mut r = Reader {
            b: need("blocks")?,
            at: 0,
            what: "blocks",
        };
        let nb = r.len(8)?;
        let mut blocks = Vec::with_capacity(nb);
        for _ in 0..nb {
            let len = r.len(1)?;
            blocks.push(r.take(len)?.to_vec());
        }
        r.done()?;
        let particles = match get("particles") {
            Some(s) => {
                let mut r = Reader {
                    b: s,
                    at: 0,
                    what: "particles",
                };
                let v = (r.u64()?, r.u64()?, r.f64()?);
                r.done()?;
                Some(v)
            }
            None => None,
        };
        let balance = match get("balance") {
            Some(s) => {
                let mut r = Reader {
                    b: s,
                    at: 0,
                    what: "balance",
                };
                let v = BalanceState {
                    strategy: r.str()?,
                    weights: r.str()?,
                    steps: r.u64()?,
                    migrated: r.u64()?,
                    seconds: r.f64()?,
                    alpha: r.f64()?,
                    clamp: r.f64()?,
                    ratio: r.f64s()?,
                    predicted: r.f64s()?,
                };
                r.done()?;
                Some(v)
            }
            None => None,
        };
        Ok(Checkpoint {
            path: path.to_path_buf(),
            step,
            scene,
            precision,
            config,
            blocks,
            particles,
            balance,
        })
    }

    fn err(&self, m: impl std::fmt::Display) -> Error {
        Error::Checkpoint(format!("checkpoint {}: {m}", self.path.display()))
    }

    /// Puts the checkpoint's state into `sim`, a fresh simulation of the same configuration whose blocks
    /// belong to `owners` (block id → process of `exec`): sets the step, decodes every block on a thread
    /// of its owner (first touch), restores the particle counters. On an error (a block that does not fit) the message names the file and the block.
    pub fn restore<T: Real>(&self, sim: &mut Simulation<T>, owners: &[u32], exec: &Executor) -> Result<()> {
        if self.blocks.len() != sim.blocks.len() {
            return Err(self.err(format!(
                "{} blocks, the configuration has {} (from another scene or domain)",
                self.blocks.len(),
                sim.blocks.len()
            )));
        }
        if self.precision != T::NAME {
            return Err(self.err(format!(
                "precision {}, the configuration has {}",
                self.precision,
                T::NAME
            )));
        }
        if self.particles.is_some() != sim.particles.is_some() {
            return Err(self.err("particle state does not match the scene's (from another scene)"));
        }
        sim.step = self.step;
        let errors: Mutex<Vec<(usize, String)>> = Mutex::new(Vec::new());
        let sim_ref: &Simulation<T> = sim;
        exec.on_each_process(|p: u32| {
            for id in (0..owners.len()).filter(|&id| owners[id] == p) {
                // SAFETY: no task runs; each block is decoded by exactly one thread (its owner's).
                if let Err(e) = unsafe { decode_block(sim_ref, id, &self.blocks[id]) } {
                    errors.lock().expect("decode errors").push((id, e.to_string()));
                }
            }
        });
        let mut errors = errors.into_inner().expect("decode errors");
        errors.sort();
        if let Some((id, e)) = errors.first() {
            return Err(self.err(format!("block {id}: {e}")));
        }
        if let (Some(p), Some((substeps, contacts, pen))) = (sim.particles.as_mut(), self.particles) {
            p.counters.substeps = substeps;
            p.counters.contacts = contacts;
            p.counters.max_penetration = pen;
        }
        Ok(())
    }
}

// ---------------------------------------------------------------------------------------------------
// The configuration of a restart

/// The first dotted key path where two TOML values differ, with both values.
fn first_difference(path: &str, a: Option<&toml::Value>, b: Option<&toml::Value>) -> Option<(String, String, String)> {
    let show = |v: Option<&toml::Value>| v.map_or_else(|| "(absent)".to_string(), |v| v.to_string());
    match (a, b) {
        (Some(toml::Value::Table(x)), Some(toml::Value::Table(y))) => {
            let mut keys: Vec<&String> = x.keys().chain(y.keys()).collect();
            keys.sort();
            keys.dedup();
            keys.into_iter().find_map(|k| {
                let p = if path.is_empty() {
                    k.clone()
                } else {
                    format!("{path}.{k}")
                };
                first_difference(&p, x.get(k), y.get(k))
            })
        }
        (x, y) if x == y => None,
        (x, y) => Some((path.to_string(), show(x), show(y))),
    }
}

/// The physics part of a configuration (every top-level table but `run`, `processes`, `balance`) as a
/// TOML table with every default resolved.
fn physics(cfg: &Config) -> toml::Table {
    let mut t: toml::Table = toml::from_str(&cfg.to_toml()).unwrap_or_default();
    for k in RESTART_MAY_CHANGE {
        t.remove(k);
    }
    t
}

/// The configuration of `blockflow run --restart`: the checkpoint's effective configuration with the
/// command line's overrides applied (module docs). Overrides of physics keys are refused naming the key; a
/// `scene` file, if given, must have the checkpoint's physics.
pub fn restart_config(ck: &Checkpoint, scene: Option<&Path>, overrides: &[String]) -> Result<Config> {
    let origin = format!("checkpoint {} (its effective configuration)", ck.path.display());
    let original = config::parse(&ck.config, &origin, &[]).map_err(|e| ck.err(format!("config section: {e}")))?;
    let mut table = config::parse_table(&ck.config, &origin)?;
    for o in overrides {
        let before = table.clone();
        config::apply_override(&mut table, o)?;
        let key = o.split_once('=').map_or(o.as_str(), |(k, _)| k.trim());
        let top = key.split('.').next().unwrap_or("");
        if !RESTART_MAY_CHANGE.contains(&top) {
            let (a, b) = (before.get(top), table.get(top));
            if first_difference(top, a, b).is_some() {
                return Err(Error::Config(format!(
                    "--set {o}: a restart continues the physics of checkpoint {}; only run.*, processes.* and \
                     balance.* keys may change",
                    ck.path.display()
                )));
            }
        }
    }
    let text = toml::to_string(&table).map_err(|e| Error::Config(format!("{origin}: {e}")))?;
    let cfg = config::parse(&text, &origin, &[])?;
    // Catches what a key-by-key check cannot (e.g. a table replaced as a whole).
    if let Some((k, a, b)) = first_difference(
        "",
        Some(&toml::Value::Table(physics(&original))),
        Some(&toml::Value::Table(physics(&cfg))),
    ) {
        return Err(Error::Config(format!(
            "{k}: a restart continues the physics of checkpoint {} ({k} = {a} there, {b} asked); only run.*, \
             processes.* and balance.* keys may change",
            ck.path.display()
        )));
    }
    if let Some(scene) = scene {
        let sc = config::load(scene, overrides)?;
        let (mine, theirs) = (physics(&cfg), physics(&sc));
        // The scene kind first: the most telling difference.
        let kind = |t: &toml::Table| t.get("scene").and_then(|s| s.get("kind")).cloned();
        let by_kind = first_difference("scene.kind", kind(&mine).as_ref(), kind(&theirs).as_ref());
        if let Some((k, a, b)) = by_kind.or_else(|| {
            first_difference(
                "",
                Some(&toml::Value::Table(mine.clone())),
                Some(&toml::Value::Table(theirs.clone())),
            )
        }) {
            return Err(ck.err(format!(
                "written for another scene than {}: {k} is {a} in the checkpoint, {b} in the scene file",
                scene.display()
            )));
        }
    }
    Ok(cfg)
}
