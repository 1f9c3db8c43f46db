//! A checkpoint into a time loop ([`Checkpoint::restore_into`]) and the configuration of a restarted run
//! ([`restart_config`]: the checkpoint's own, with the command line's overrides of the keys that never
//! change a number).

use super::format::Checkpoint;
use crate::config::{self, Config};
use crate::error::{Error, Result};
use crate::physics::simulation::Simulation;
use crate::serialise::decode_block;
use crate::timeloop::TimeLoop;
use blockflow_kernels::Real;
use blockflow_scheduler::executor::Executor;
use std::path::Path;
use std::sync::Mutex;

/// Top-level config tables a restart may change (they never change a number of the state).
pub const RESTART_MAY_CHANGE: [&str; 3] = ["run", "processes", "balance"];

/// Keys of the physics tables that choose only how the same arithmetic is carried out (the kernels give
/// the same bits under each value), so a restart may change them too.
pub const RESTART_MAY_CHANGE_KEYS: [(&str, &str); 2] = [("fluid", "streaming"), ("fluid", "kernel")];

impl Checkpoint {
    /// Puts the checkpoint's state into a fresh time loop of the same configuration: the simulation's
    /// blocks (decoded on their owners' threads), the particle counters, the balancer's state; the
    /// interval under way starts at the checkpoint's step.
    pub fn restore_into<T: Real>(&self, tl: &mut TimeLoop<T>) -> Result<()> {
        let (sim, pipe, balancer) = tl.parts_mut();
        let local: Vec<Option<u32>> = (0..sim.blocks.len()).map(|b| pipe.local_process(b)).collect();
        self.restore(sim, &local, pipe.executor())?;
        if let (Some(b), Some(st)) = (balancer, self.balance.as_ref()) {
            st.restore(b);
        }
        tl.resume();
        Ok(())
    }

    /// Puts the checkpoint's state into `sim`, a fresh simulation of the same configuration whose blocks
    /// this process holds are run by `local` (block id → process of `exec`; `None`: another rank's block,
    /// left alone): sets the step, decodes every held block on a thread of its process (first touch),
    /// restores the particle counters. On an error (a block that does not fit) the message names the
    /// file and the block.
    fn restore<T: Real>(&self, sim: &mut Simulation<T>, local: &[Option<u32>], exec: &Executor) -> Result<()> {
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
            for id in (0..local.len()).filter(|&id| local[id] == Some(p)) {
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
    for (table, key) in RESTART_MAY_CHANGE_KEYS {
        if let Some(toml::Value::Table(x)) = t.get_mut(table) {
            x.remove(key);
        }
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
        let same_bits = RESTART_MAY_CHANGE_KEYS.iter().any(|(t, k)| key == format!("{t}.{k}"));
        if !RESTART_MAY_CHANGE.contains(&top) && !same_bits {
            let (a, b) = (before.get(top), table.get(top));
            if first_difference(top, a, b).is_some() {
                return Err(Error::Config(format!(
                    "--set {o}: a restart continues the physics of checkpoint {}; only run.*, processes.*, \
                     balance.*, fluid.streaming and fluid.kernel keys may change",
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
