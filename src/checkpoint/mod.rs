//! Checkpoints and restart (`blockflow run --checkpoint-every N`, `--checkpoint-wall SECONDS`,
//! `--restart PATH`).
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
//! - `particles` (scenes with bodies): the run totals of [`crate::physics::particles::RigidCounters`]: sub-steps
//!   u64, contacts u64, largest penetration f64.
//! - `balance` (runs with a balancer): strategy and weights names (u8 length + ASCII each), balancing steps
//!   u64, blocks migrated u64, balancing seconds f64, corrector α f64 and clamp f64, u64 n and n ratios f64,
//!   u64 m and m predictions f64 (the interval under way), u64 k and k estimates f64 of the last
//!   balancing step (absent in files written before they were stored: a reader takes none). The owners
//!   are not stored: they never change a number, and a restart on another process count assigns the
//!   blocks afresh.
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
//!
//! Files: [`mod@format`] (the file's bytes: encoding and checked reading), [`restore`] (a checkpoint into a
//! time loop, and the configuration of a restarted run); this file writes, lists and finds them.

pub mod format;
pub mod restore;

pub use format::{encode, stream, BalanceState, Checkpoint, CheckpointInput, CHECKPOINT_MAGIC, CHECKPOINT_VERSION};
pub use restore::{restart_config, RESTART_MAY_CHANGE};

use crate::error::{io_err, Error, Result};
use crate::physics::simulation::Simulation;
use crate::ranks::World;
use crate::serialise::{encode_block, encoded_len};
use crate::util::fs::write_atomic_to;
use blockflow_kernels::Real;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// A checkpoint written by [`write()`].
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
    write_atomic_to(&path, &tmp, true, |w| w.write_all(&bytes)).map_err(|(p, e)| {
        if p == dir {
            Error::Io(format!("checkpoint folder {}: {e}", dir.display()))
        } else {
            Error::Io(format!("checkpoint {}: {e}", p.display()))
        }
    })?;
    prune(dir, keep.max(1))?;
    Ok(Written {
        path,
        bytes: bytes.len() as u64,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// [`write()`] on ranks: rank 0 writes the file as the blocks arrive from their owners, in block-id
/// order, so it has the bytes a single process writes for the same state; every rank calls this at once
/// (`owners`: block id → rank) and gets the same result.
pub fn write_on<T: Real>(
    dir: &Path,
    sim: &Simulation<T>,
    input: &CheckpointInput,
    keep: usize,
    world: &World,
    owners: &[u32],
) -> Result<Written> {
    if world.is_single() {
        return write(dir, sim, input, keep);
    }
    let t0 = Instant::now();
    let nb = sim.blocks.len();
    let held = (0..nb).filter(|&b| sim.blocks[b].is_held());
    let lens = world.all_block_values(nb, held.clone().map(|b| (b, encoded_len(sim, b) as f64)).collect())?;
    let lens: Vec<usize> = lens.iter().map(|&l| l as usize).collect();
    let tag = world.stream_tag();
    let t = world.transport();
    let mut outcome: Vec<u8> = Vec::new();
    if world.is_root() {
        let path = file_of(dir, sim.step);
        let tmp = dir.join(format!(".step-{}.tmp", sim.step));
        let mut got = vec![false; nb];
        let written = write_atomic_to(&path, &tmp, true, |w| {
            stream(w, sim, input, &lens, |b, v| {
                if owners[b] == 0 {
                    encode_block(sim, b, v);
                } else {
                    *v = t
                        .recv(owners[b] as usize, tag)
                        .map_err(|e| std::io::Error::other(e.to_string()))?;
                    got[b] = true;
                }
                Ok(())
            })
            .map(|_| ())
        });
        // Take what a failed write left unread, so the stream's messages do not outlive it.
        for b in (0..nb).filter(|&b| owners[b] != 0 && !got[b]) {
            t.recv(owners[b] as usize, tag).map_err(|e| world.error(e))?;
        }
        outcome = match written {
            Ok(()) => {
                prune(dir, keep.max(1))?;
                let size = std::fs::metadata(&path).map_err(|e| io_err(&path, e))?.len();
                format!("ok\n{size}").into_bytes()
            }
            Err((p, e)) if p == dir => format!("error\ncheckpoint folder {}: {e}", dir.display()).into_bytes(),
            Err((p, e)) => format!("error\ncheckpoint {}: {e}", p.display()).into_bytes(),
        };
    } else {
        for b in held {
            let mut v = Vec::with_capacity(lens[b]);
            encode_block(sim, b, &mut v);
            t.send(0, tag, v).map_err(|e| world.error(e))?;
        }
    }
    world.broadcast(0, &mut outcome)?;
    let text = String::from_utf8_lossy(&outcome);
    let (status, rest) = text.split_once('\n').unwrap_or(("error", "no answer from rank 0"));
    if status != "ok" {
        return Err(Error::Io(rest.to_string()));
    }
    Ok(Written {
        path: file_of(dir, sim.step),
        bytes: rest.parse().unwrap_or(0),
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
