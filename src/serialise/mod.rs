//! One block as bytes: the serialisation behind block migration between virtual processes, per-block
//! checkpoints and (one day) an MPI backend. [`encode_block`] writes the state of one block after
//! `sim.step` steps, [`decode_block`] rebuilds it in place, [`encoded_len`] prices it.
//!
//! # Format (version [`BLOCK_FORMAT_VERSION`]), all integers and floats little-endian
//!
//! | bytes | field |
//! |---|---|
//! | 5 | magic `b"BFBLK"` |
//! | u32 | format version |
//! | u64 | total length of the encoding, checksum included (so a truncated copy is told from a corrupt one) |
//! | u8 | precision of the PDFs: 4 = f32, 8 = f64 |
//! | u64 | block id |
//! | 3 × u32 | block size (interior cells along x, y, z) |
//! | u64 | step: the state is the one after this many steps |
//! | u32 | number of sections |
//! | per section | name length u8, name (ASCII), payload length u64 (a reader skips names it does not know) |
//! | ... | the payloads, in table order |
//! | u64 | checksum of every byte before it (see [`checksum`]) |
//!
//! Cell indices below are *layout-free*: `c = x + (nx+2)·(y + (ny+2)·z)` over the ghost-inclusive grid
//! (`0` and `n+1` are the ghost layers), written as u32; the in-memory padding of rows never travels.
//! Vectors are 3 × f64 (x, y, z), quaternions 4 × f64 (x, y, z, w); every f64 is its exact bits.
//!
//! Sections:
//! - `pdf` (only for a block with fluid cells): the post-collision PDFs of the *interior* cells of the
//!   current state, f*_q(x) wherever the streaming pattern keeps it (so pull and AA runs write the same
//!   bytes and restart each other), zero-centred as stored (`f_q − w_q`), in the precision of the
//!   header: direction q = 0..19 slowest, then z, y, x fastest (x, y, z = 1..=n). Cells that are not fluid
//!   now (walls, cells covered by a particle) are written as 0: their values are dead (the next step's
//!   boundary passes and reconstruction rewrite every one that is read), and zeroing them makes the
//!   bytes a function of the live state only. No ghost layer: the next step's exchange fills it. Pull's
//!   other field is not carried either: the next step overwrites every cell of it that is ever read.
//! - `flags`: the flag byte of every cell *with* its ghost layer, x fastest. Flags are static geometry; the
//!   decoder does not write them but checks them against the block it decodes into (`Mismatch`).
//! - `overlay` (only if the block has a particle overlay): everything of [`ParticleCells`] except its
//!   scratch buffers. `owner` (read by the next mapping to find the cells that turn fluid, and by the
//!   reconstruction) run-length coded over the ghost-inclusive cells; `owned`; the fluid-cell counts;
//!   segments, mapped bodies, link cells (cell, directions), turned and covered cells, exchanged momentum
//!   and the last forces.
//!   Most of it is rebuilt by the next `map` task, but not all blocks get one (fixed bodies are mapped
//!   once; inactive blocks keep their overlay), the checksum and Table 1 read segments and counts
//!   between steps, and total forces read `forces`: carrying it all keeps every reader exact.
//! - `bodies` (with particles): the block's published list of the current parity — the bodies this block
//!   published after the last sub-step, each with every [`Body`] field (force/torque and the averaging
//!   history `force_prev`/`torque_prev` included) and its home block (u32). These are the block's local
//!   bodies (a body that just crossed a face is published by its old home, which is where the next
//!   sub-step looks for it). Each body lives in exactly one block's list, so the lists of all blocks
//!   together are all bodies. Then the list's contact impulses ([`OwnedImpulse`]: count, then a u64,
//!   b u64 and the impulse per entry; after a step they are the Jacobi solver's warm start of the next
//!   sub-step) and its contact counts (count, then u32 each; empty between sub-steps).
//!
//! [`OwnedImpulse`]: crate::physics::particles::OwnedImpulse
//! - `particle_state` (with particles): the block's last rigid-body result ([`Work`]): local and shadow
//!   bodies, velocity changes, and the contact and gather counters (K and the rigid-body regressors of the
//!   estimator, statistics for the summary).
//!
//! Not carried, on purpose: the ghost layers and the other PDF field (rewritten before they are read;
//! the continuation tests prove it bitwise), the static block structure (segments, wall links, receive lists,
//! neighbour lists and planes of the rigid-body bookkeeping: rebuilt from the geometry, which `flags`
//! checks), the other parity's published list (stale: overwritten by the next sub-step before anyone
//! reads it; the decoder clears it), and the global particle state in [`crate::physics::particles::Particles`]:
//! `active` (recomputed before every graph run), `counters` (run totals) and pending errors. A
//! checkpoint must store `counters` beside its blocks if it wants them continued.

use std::fmt;

pub mod halo;
mod read;
mod write;

use crate::util::bytes::Reader;
pub use read::decode_block;
pub use write::{encode_block, encoded_len};

/// Version of the block format written by [`encode_block`]; the decoder accepts only this one.
pub const BLOCK_FORMAT_VERSION: u32 = 4;
/// First bytes of every encoded block.
pub const MAGIC: [u8; 5] = *b"BFBLK";
/// Bytes of the fixed header (before the section table).
const HEADER_LEN: usize = 5 + 4 + 8 + 1 + 8 + 12 + 8 + 4;
/// Bytes of one body as the `bodies` and `particle_state` sections write it.
const BODY_BYTES: usize = 8 + 8 * (3 + 4 + 3 + 3 + 1 + 1) + 1 + 8 * 12;
/// Bytes of one body force (id, force, torque).
const BODY_FORCE_BYTES: usize = 8 + 48;
/// Section names.
const PDF: &str = "pdf";
const FLAGS: &str = "flags";
const OVERLAY: &str = "overlay";
const BODIES: &str = "bodies";
const PARTICLE_STATE: &str = "particle_state";

/// Why bytes could not be decoded into a block. Decoding checks everything before it changes the block,
/// so after an error the block is as it was.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FormatError {
    /// Fewer bytes than the header announces (or than a header needs).
    Truncated {
        /// Bytes needed.
        needed: usize,
        /// Bytes given.
        found: usize,
    },
    /// The bytes do not start with [`MAGIC`].
    BadMagic,
    /// Written by another format version.
    Version {
        /// Version in the bytes.
        found: u32,
        /// The version this build reads.
        expected: u32,
    },
    /// The checksum does not match the content (a flipped or lost byte).
    Checksum {
        /// Checksum stored in the bytes.
        stored: u64,
        /// Checksum of the content.
        computed: u64,
    },
    /// Valid bytes for another block, precision, block size, step, geometry or particle setting.
    Mismatch(String),
    /// A section is inconsistent although the checksum matches (a writer bug or crafted input).
    Malformed(String),
}

impl fmt::Display for FormatError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FormatError::Truncated { needed, found } => {
                write!(f, "encoded block truncated: {found} bytes, {needed} needed")
            }
            FormatError::BadMagic => write!(f, "not an encoded block (the magic bytes BFBLK are missing)"),
            FormatError::Version { found, expected } => {
                write!(
                    f,
                    "encoded block has format version {found}; this build reads version {expected}"
                )
            }
            FormatError::Checksum { stored, computed } => write!(
                f,
                "encoded block corrupt: checksum {stored:016x} stored, {computed:016x} computed"
            ),
            FormatError::Mismatch(m) => write!(f, "encoded block does not fit: {m}"),
            FormatError::Malformed(m) => write!(f, "encoded block malformed: {m}"),
        }
    }
}

impl std::error::Error for FormatError {}

/// The fixed header of an encoded block.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BlockHeader {
    /// Format version.
    pub version: u32,
    /// Total length of the encoding in bytes (checksum included).
    pub total_len: usize,
    /// Bytes per PDF value: 4 (f32) or 8 (f64).
    pub precision_bytes: u8,
    /// Block id.
    pub id: usize,
    /// Interior cells along x, y, z.
    pub block_size: [usize; 3],
    /// Steps taken when the block was encoded.
    pub step: u64,
}

/// The checksum of the format: FNV-1a 64 over little-endian 8-byte words (the tail zero-padded to a
/// word), then the byte length folded in the same way: `h = 0xcbf29ce484222325`, per word
/// `h = (h ^ w) · 0x100000001b3` (wrapping). Any change of a single word changes it.
pub fn checksum(bytes: &[u8]) -> u64 {
    const PRIME: u64 = 0x0000_0100_0000_01b3;
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut words = bytes.chunks_exact(8);
    for w in &mut words {
        h = (h ^ u64::from_le_bytes(w.try_into().expect("8 bytes"))).wrapping_mul(PRIME);
    }
    let rest = words.remainder();
    if !rest.is_empty() {
        let mut w = [0u8; 8];
        w[..rest.len()].copy_from_slice(rest);
        h = (h ^ u64::from_le_bytes(w)).wrapping_mul(PRIME);
    }
    (h ^ bytes.len() as u64).wrapping_mul(PRIME)
}

/// [`checksum`] computed over bytes given in pieces of any length (a file written as it is streamed).
#[derive(Clone, Debug)]
pub struct Checksummer {
    h: u64,
    len: u64,
    tail: [u8; 8],
    tail_len: usize,
}

impl Default for Checksummer {
    fn default() -> Self {
        Checksummer {
            h: 0xcbf2_9ce4_8422_2325,
            len: 0,
            tail: [0; 8],
            tail_len: 0,
        }
    }
}

impl Checksummer {
    const PRIME: u64 = 0x0000_0100_0000_01b3;

    /// Adds the next bytes.
    pub fn update(&mut self, mut bytes: &[u8]) {
        self.len += bytes.len() as u64;
        if self.tail_len > 0 {
            let take = (8 - self.tail_len).min(bytes.len());
            self.tail[self.tail_len..self.tail_len + take].copy_from_slice(&bytes[..take]);
            self.tail_len += take;
            bytes = &bytes[take..];
            if self.tail_len < 8 {
                return;
            }
            self.h = (self.h ^ u64::from_le_bytes(self.tail)).wrapping_mul(Self::PRIME);
            self.tail_len = 0;
        }
        let mut words = bytes.chunks_exact(8);
        for w in &mut words {
            self.h = (self.h ^ u64::from_le_bytes(w.try_into().expect("8 bytes"))).wrapping_mul(Self::PRIME);
        }
        let rest = words.remainder();
        self.tail[..rest.len()].copy_from_slice(rest);
        self.tail_len = rest.len();
    }

    /// The checksum of everything given ([`checksum`] of the concatenation).
    pub fn finish(&self) -> u64 {
        let mut h = self.h;
        if self.tail_len > 0 {
            let mut w = [0u8; 8];
            w[..self.tail_len].copy_from_slice(&self.tail[..self.tail_len]);
            h = (h ^ u64::from_le_bytes(w)).wrapping_mul(Self::PRIME);
        }
        (h ^ self.len).wrapping_mul(Self::PRIME)
    }
}

/// Reads the fixed header (magic, version, lengths, block id, size, step) without checking the rest.
pub fn peek_header(bytes: &[u8]) -> Result<BlockHeader, FormatError> {
    if bytes.len() < MAGIC.len() {
        return Err(FormatError::Truncated {
            needed: HEADER_LEN,
            found: bytes.len(),
        });
    }
    if bytes[..MAGIC.len()] != MAGIC {
        return Err(FormatError::BadMagic);
    }
    if bytes.len() < MAGIC.len() + 4 {
        return Err(FormatError::Truncated {
            needed: HEADER_LEN,
            found: bytes.len(),
        });
    }
    let version = u32::from_le_bytes(bytes[5..9].try_into().expect("4 bytes"));
    if version != BLOCK_FORMAT_VERSION {
        return Err(FormatError::Version {
            found: version,
            expected: BLOCK_FORMAT_VERSION,
        });
    }
    if bytes.len() < HEADER_LEN {
        return Err(FormatError::Truncated {
            needed: HEADER_LEN,
            found: bytes.len(),
        });
    }
    let mut r = Reader::new(&bytes[9..HEADER_LEN], "header");
    let total = r.u64()?;
    let precision_bytes = r.u8()?;
    let id = r.u64()?;
    let size = [r.u32()? as usize, r.u32()? as usize, r.u32()? as usize];
    let step = r.u64()?;
    let total_len = usize::try_from(total).map_err(|_| FormatError::Malformed(format!("total length {total}")))?;
    if total_len < HEADER_LEN + 8 {
        return Err(FormatError::Malformed(format!(
            "total length {total_len} is shorter than a header"
        )));
    }
    Ok(BlockHeader {
        version,
        total_len,
        precision_bytes,
        id: id as usize,
        block_size: size,
        step,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_streamed_checksum_is_the_checksum_of_the_whole() {
        let bytes: Vec<u8> = (0..1000u32).map(|i| (i * 37 % 251) as u8).collect();
        for cuts in [vec![], vec![3], vec![8, 16], vec![1, 2, 3, 4, 5, 999], vec![7, 7, 500]] {
            let mut c = Checksummer::default();
            let mut at = 0;
            for &k in &cuts {
                c.update(&bytes[at..k]);
                at = k;
            }
            c.update(&bytes[at..]);
            assert_eq!(c.finish(), checksum(&bytes), "cuts {cuts:?}");
        }
        assert_eq!(Checksummer::default().finish(), checksum(&[]));
        let mut c = Checksummer::default();
        c.update(&bytes[..5]);
        assert_eq!(c.finish(), checksum(&bytes[..5]));
    }
}
