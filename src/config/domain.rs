//! `[domain]`: the block decomposition.

use crate::error::{config_err, Result};
use serde::{Deserialize, Serialize};

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

impl DomainConfig {
    /// Checks the keys' ranges; the message names the key.
    pub fn validate(&self) -> Result<()> {
        for (name, v) in [("domain.blocks", self.blocks), ("domain.block_size", self.block_size)] {
            if let Some(v) = v {
                if v.contains(&0) {
                    return config_err(format!("{name} = {v:?}: every entry must be at least 1"));
                }
            }
        }
        Ok(())
    }
}
