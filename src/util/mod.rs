//! Small shared vocabulary of the engine: deterministic hashing and pseudo-random numbers, atomic file
//! writes, a little-endian byte reader, and robust statistics. Nothing here knows about fluids, blocks or
//! processes.

pub mod bytes;
pub mod fs;
pub mod hash;
pub mod stats;
