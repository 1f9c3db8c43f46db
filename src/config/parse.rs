//! Reading scene files: TOML with positioned syntax errors, `--set key.path=value` overrides, the raw
//! `[scene]` table checked against its kind, unknown keys rejected by name.

use super::Config;
use crate::error::{config_err, Error, Result};
use std::path::Path;

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
        Some(sc) => super::scene::check_table(sc).map_err(|m| Error::Config(format!("{origin}: {m}")))?,
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
        // More than `v`: the value went on with further lines of TOML (`0.7\n[scene]...`).
        Ok(t) if t.len() > 1 => {
            return config_err(format!(
                "--set {key}: the value {raw:?} is more than one TOML value; give one value (a number, string, \
                 array or inline table)"
            ))
        }
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
