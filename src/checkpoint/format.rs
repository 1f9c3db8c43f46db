//! The checkpoint file's bytes (format in the module docs of [`super`]): [`encode`] writes them,
//! [`Checkpoint::parse`] checks and splits them.

use crate::balance::Balancer;
use crate::config::Config;
use crate::error::{Error, Result};
use crate::physics::simulation::Simulation;
use crate::serialise::{checksum, encode_block, encoded_len, Checksummer, BLOCK_FORMAT_VERSION};
use crate::util::bytes::{put_f64, put_f64s, put_str8, put_u64, ReadError, Reader};
use blockflow_kernels::Real;
use std::path::{Path, PathBuf};

/// Version of the checkpoint format written by [`encode`]; [`Checkpoint::read`] accepts only this one.
pub const CHECKPOINT_VERSION: u32 = 1;
/// First bytes of every checkpoint file.
pub const CHECKPOINT_MAGIC: [u8; 8] = *b"BFCHKPT\n";
/// Bytes before the section table: magic, version, total length, section count.
const HEADER_LEN: usize = 8 + 4 + 8 + 4;

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
    /// Every block's estimate at the last balancing step (`estimator` weights' forecast; empty in files
    /// written before it was stored).
    pub previous_estimate: Vec<f64>,
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
            previous_estimate: b.previous_estimate().to_vec(),
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
            if self.previous_estimate.len() == self.ratio.len() {
                b.set_previous_estimate(self.previous_estimate.clone());
            }
        }
    }

    fn decode(r: &mut Reader) -> std::result::Result<Self, ReadError> {
        Ok(BalanceState {
            strategy: r.str8()?,
            weights: r.str8()?,
            steps: r.u64()?,
            migrated: r.u64()?,
            seconds: r.f64()?,
            alpha: r.f64()?,
            clamp: r.f64()?,
            ratio: r.f64s()?,
            predicted: r.f64s()?,
            previous_estimate: if r.at_end() { Vec::new() } else { r.f64s()? },
        })
    }

    fn encode(&self, v: &mut Vec<u8>) {
        put_str8(v, &self.strategy);
        put_str8(v, &self.weights);
        put_u64(v, self.steps);
        put_u64(v, self.migrated);
        put_f64(v, self.seconds);
        put_f64(v, self.alpha);
        put_f64(v, self.clamp);
        put_f64s(v, &self.ratio);
        put_f64s(v, &self.predicted);
        put_f64s(v, &self.previous_estimate);
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
    let lens: Vec<usize> = (0..sim.blocks.len()).map(|b| encoded_len(sim, b)).collect();
    let mut out = Vec::new();
    stream(&mut out, sim, input, &lens, |b, v| {
        encode_block(sim, b, v);
        Ok(())
    })
    .expect("writing to memory does not fail");
    out
}

/// Writes the checkpoint file of `sim` to `w` as it goes: the sections before the blocks, then every
/// block's encoding in id order as `block(id, buffer)` appends it (of `lens[id]` bytes, announced in the
/// header), the sections after them, the checksum computed along the way. Returns the bytes written.
/// The blocks may come from other ranks: the file is the same bytes as [`encode`]'s.
pub fn stream<T: Real>(
    w: &mut impl std::io::Write,
    sim: &Simulation<T>,
    input: &CheckpointInput,
    lens: &[usize],
    mut block: impl FnMut(usize, &mut Vec<u8>) -> std::io::Result<()>,
) -> std::io::Result<u64> {
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
    let mut before: Vec<(&str, Vec<u8>)> = vec![
        ("meta", meta.to_string().into_bytes()),
        ("config", input.config.as_bytes().to_vec()),
    ];
    let blocks_len = 8 + lens.iter().map(|l| 8 + l).sum::<usize>();
    let mut after: Vec<(&str, Vec<u8>)> = Vec::new();
    if let Some(p) = &sim.particles {
        let mut v = Vec::new();
        put_u64(&mut v, p.counters.substeps);
        put_u64(&mut v, p.counters.contacts);
        put_f64(&mut v, p.counters.max_penetration);
        after.push(("particles", v));
    }
    if let Some(b) = &input.balance {
        let mut v = Vec::new();
        b.encode(&mut v);
        after.push(("balance", v));
    }
    let names: Vec<(&str, usize)> = before
        .iter()
        .map(|(n, p)| (*n, p.len()))
        .chain([("blocks", blocks_len)])
        .chain(after.iter().map(|(n, p)| (*n, p.len())))
        .collect();
    let table: usize = names.iter().map(|(n, _)| 1 + n.len() + 8).sum();
    let payload: usize = names.iter().map(|(_, l)| l).sum();
    let total = HEADER_LEN + table + payload + 8;
    let mut sum = Checksummer::default();
    let mut put = |w: &mut dyn std::io::Write, bytes: &[u8]| {
        sum.update(bytes);
        w.write_all(bytes)
    };
    let mut head = Vec::with_capacity(HEADER_LEN + table);
    head.extend_from_slice(&CHECKPOINT_MAGIC);
    head.extend_from_slice(&CHECKPOINT_VERSION.to_le_bytes());
    put_u64(&mut head, total as u64);
    head.extend_from_slice(&(names.len() as u32).to_le_bytes());
    for (name, len) in &names {
        put_str8(&mut head, name);
        put_u64(&mut head, *len as u64);
    }
    put(w, &head)?;
    for (_, p) in before.drain(..) {
        put(w, &p)?;
    }
    put(w, &(lens.len() as u64).to_le_bytes())?;
    let mut one = Vec::new();
    for (id, &len) in lens.iter().enumerate() {
        one.clear();
        block(id, &mut one)?;
        if one.len() != len {
            return Err(std::io::Error::other(format!(
                "block {id} encoded to {} bytes, {len} announced",
                one.len()
            )));
        }
        put(w, &(len as u64).to_le_bytes())?;
        put(w, &one)?;
    }
    for (_, p) in &after {
        put(w, p)?;
    }
    let s = sum.finish();
    w.write_all(&s.to_le_bytes())?;
    Ok(total as u64)
}

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
        let mut r = Reader::new(need("blocks")?, "blocks");
        let nb = r.count64(8).map_err(malformed)?;
        let mut blocks = Vec::with_capacity(nb);
        for _ in 0..nb {
            let len = r.count64(1).map_err(malformed)?;
            blocks.push(r.take(len).map_err(malformed)?.to_vec());
        }
        r.finish().map_err(malformed)?;
        let particles = match get("particles") {
            Some(s) => {
                let mut r = Reader::new(s, "particles");
                let v = (|| Ok((r.u64()?, r.u64()?, r.f64()?)))().map_err(malformed)?;
                r.finish().map_err(malformed)?;
                Some(v)
            }
            None => None,
        };
        let balance = match get("balance") {
            Some(s) => {
                let mut r = Reader::new(s, "balance");
                let v = BalanceState::decode(&mut r).map_err(malformed)?;
                r.finish().map_err(malformed)?;
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

    pub(super) fn err(&self, m: impl std::fmt::Display) -> Error {
        Error::Checkpoint(format!("checkpoint {}: {m}", self.path.display()))
    }
}

/// A reading error as the checkpoint reports it.
fn malformed(e: ReadError) -> String {
    format!("malformed: {e}")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The balancing state reads back as written, and a section written before the last balancing
    /// step's estimates were stored reads with none (the forecast then starts afresh).
    #[test]
    fn balance_state_round_trips_and_reads_the_older_section() {
        let st = BalanceState {
            strategy: "hilbert".into(),
            weights: "estimator".into(),
            steps: 3,
            migrated: 7,
            seconds: 0.25,
            alpha: 0.5,
            clamp: 10.0,
            ratio: vec![1.0, 1.5],
            predicted: vec![2.0, 3.0],
            previous_estimate: vec![4.0, 5.0],
        };
        let mut v = Vec::new();
        st.encode(&mut v);
        let mut r = Reader::new(&v, "balance");
        assert_eq!(BalanceState::decode(&mut r).unwrap(), st);
        assert!(r.at_end());
        // The older section: everything up to the predictions.
        let old = &v[..v.len() - (8 + 2 * 8)];
        let mut r = Reader::new(old, "balance");
        let back = BalanceState::decode(&mut r).unwrap();
        assert!(r.at_end());
        assert_eq!(
            back,
            BalanceState {
                previous_estimate: Vec::new(),
                ..st
            }
        );
    }
}
