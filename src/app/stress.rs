//! `blockflow stress SCENE --vary KEY=RANGE [--vary KEY2=RANGE] [--steps N] [--max-error E] [--out DIR]`:
//! every combination runs a fixed number of steps with the instability detector on;
//! the map (stress.png, stress.csv) says stable, stable but inaccurate (the error observable above
//! `--max-error`), or unstable at which step. A RANGE is a list `V1,V2,...`, a linear range `A:B:N` or a
//! geometric one `A:B:N:log` (N values from A to B).

use crate::app::scan::{self, ScanOptions, ScanReport};
use crate::error::{Error, Result};
use crate::io::plots::scan::{stability_map, Outcome};
use std::path::PathBuf;

/// Stability map over one or two keys (`blockflow stress`).
#[derive(clap::Args, Debug)]
pub struct StressArgs {
    /// Scene file (TOML).
    pub scene: PathBuf,
    /// KEY=V1,V2,... or KEY=A:B:N or KEY=A:B:N:log (one or two).
    #[arg(long, value_name = "KEY=RANGE", required = true)]
    pub vary: Vec<String>,
    /// Fixed override (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Steps of every run (default: the scene's).
    #[arg(long)]
    pub steps: Option<u64>,
    /// Error observable for "inaccurate" (default: the first whose name contains "error").
    #[arg(long)]
    pub error: Option<String>,
    /// A stable run with the error observable above this is "inaccurate".
    #[arg(long)]
    pub max_error: Option<f64>,
    /// Output folder.
    #[arg(long, default_value = "out/stress")]
    pub out: PathBuf,
}

/// Runs `blockflow stress` and prints its table.
pub fn execute(a: StressArgs) -> Result<()> {
    let vary = a.vary.iter().map(|v| parse_range(v)).collect::<Result<Vec<_>>>()?;
    let opts = StressOptions {
        scene: a.scene,
        vary,
        sets: a.set,
        steps: a.steps,
        error: a.error,
        max_error: a.max_error,
        out: a.out.clone(),
    };
    let r = stress(&opts)?;
    super::print_out(&format!("{}results in {}\n", to_markdown(&r), a.out.display()));
    Ok(())
}

/// Options of `blockflow stress`.
#[derive(Clone, Debug, Default)]
pub struct StressOptions {
    /// Scene file.
    pub scene: PathBuf,
    /// One or two varied keys and their values.
    pub vary: Vec<(String, Vec<String>)>,
    /// Fixed overrides.
    pub sets: Vec<String>,
    /// Steps of every run (default: the scene's).
    pub steps: Option<u64>,
    /// Error observable and its bound for "inaccurate".
    pub error: Option<String>,
    /// Bound on the error observable.
    pub max_error: Option<f64>,
    /// Output folder.
    pub out: PathBuf,
}

/// Parses `KEY=RANGE` (see the module docs).
pub fn parse_range(s: &str) -> Result<(String, Vec<String>)> {
    let (k, v) = s
        .split_once('=')
        .ok_or_else(|| Error::Config(format!("--vary {s}: expected KEY=V1,V2,... or KEY=A:B:N[:log]")))?;
    let parts: Vec<&str> = v.split(':').collect();
    if parts.len() < 3 || parts.len() > 4 || v.contains(',') {
        return scan::parse_vary(s);
    }
    let bad = || {
        Error::Config(format!(
            "--vary {s}: expected A:B:N[:log] with finite numbers A and B (both > 0 with log) and N from 2 to 1000"
        ))
    };
    let a: f64 = parts[0].trim().parse().map_err(|_| bad())?;
    let b: f64 = parts[1].trim().parse().map_err(|_| bad())?;
    let n: usize = parts[2].trim().parse().map_err(|_| bad())?;
    let log = match parts.get(3).map(|x| x.trim()) {
        None => false,
        Some("log") => true,
        Some(_) => return Err(bad()),
    };
    if !(2..=1000).contains(&n) || !a.is_finite() || !b.is_finite() || (log && (a <= 0.0 || b <= 0.0)) {
        return Err(bad());
    }
    let vals = (0..n)
        .map(|i| {
            let t = i as f64 / (n - 1) as f64;
            let x = if log { a * (b / a).powf(t) } else { a + (b - a) * t };
            // Six significant digits (log ranges give long decimals otherwise).
            format!(
                "{}",
                format!("{x:.5e}").parse::<f64>().expect("a formatted float parses")
            )
        })
        .collect();
    Ok((k.trim().to_string(), vals))
}

/// The map: the sweep and every run's outcome.
pub struct StressReport {
    /// The runs.
    pub scan: ScanReport,
    /// Outcome per row of the sweep.
    pub outcomes: Vec<Outcome>,
}

/// Runs the map and writes stress.csv (the sweep's CSV) and stress.png.
pub fn stress(opts: &StressOptions) -> Result<StressReport> {
    if opts.vary.is_empty() || opts.vary.len() > 2 {
        return Err(Error::Config("stress: give one or two --vary KEY=RANGE".into()));
    }
    let so = ScanOptions {
        scene: opts.scene.clone(),
        vary: opts.vary.clone(),
        sets: opts.sets.clone(),
        repeat: 1,
        steps: opts.steps,
        error: opts.error.clone(),
        out: opts.out.clone(),
        record_refused: true,
        repeat_until_seconds: None,
    };
    let r = scan::scan(&so)?;
    // A map the scene refuses everywhere is a mistake in the ranges: say why.
    if let Some(msg) = r
        .rows
        .iter()
        .all(|x| x.status == "refused")
        .then(|| r.rows[0].message.clone())
        .flatten()
    {
        return Err(Error::Config(format!(
            "stress: the scene refuses every combination, e.g.: {msg}"
        )));
    }
    let _ = std::fs::rename(opts.out.join("sweep.csv"), opts.out.join("stress.csv"));
    let _ = std::fs::remove_file(opts.out.join("sweep.png"));
    let outcomes: Vec<Outcome> = r
        .rows
        .iter()
        .map(|row| {
            if row.status == "refused" {
                return Outcome::Refused;
            }
            if row.status != "ok" {
                return Outcome::Unstable(row.failed_step);
            }
            let e = r.error.as_ref().and_then(|k| row.observables.get(k)).copied();
            match (e, opts.max_error) {
                (Some(e), Some(m)) if e.partial_cmp(&m) != Some(std::cmp::Ordering::Less) && e != m => {
                    Outcome::Inaccurate
                }
                _ => Outcome::Stable,
            }
        })
        .collect();
    let xs = &opts.vary[0].1;
    let (ykey, ys) = match opts.vary.get(1) {
        Some((k, v)) => (k.as_str(), v.clone()),
        None => ("", vec![String::new()]),
    };
    // Sweep rows run the first key slowest: row index = i * ny + j.
    let cells: Vec<Vec<Outcome>> = (0..ys.len())
        .map(|j| (0..xs.len()).map(|i| outcomes[i * ys.len() + j].clone()).collect())
        .collect();
    let title = format!("{}: stability after {}", opts.scene.display(), steps_label(opts.steps));
    stability_map(
        &opts.out.join("stress.png"),
        &title,
        (&opts.vary[0].0, xs),
        (ykey, &ys),
        &cells,
    )?;
    Ok(StressReport { scan: r, outcomes })
}

fn steps_label(s: Option<u64>) -> String {
    s.map_or("the scene's own step count".into(), |n| format!("{n} steps"))
}

/// The map in words: per value of the second key, where the stable region ends along the first.
pub fn to_markdown(r: &StressReport) -> String {
    let keys = &r.scan.keys;
    let mut s = format!(
        "| {} | outcome | message |\n|{}---|---|\n",
        keys.join(" | "),
        "---|".repeat(keys.len())
    );
    for (row, o) in r.scan.rows.iter().zip(&r.outcomes) {
        let out = match o {
            Outcome::Stable => "stable".to_string(),
            Outcome::Inaccurate => "inaccurate".to_string(),
            Outcome::Unstable(Some(st)) => format!("unstable at step {st}"),
            Outcome::Unstable(None) => "unstable".to_string(),
            Outcome::Refused => "refused".to_string(),
        };
        s += &format!(
            "| {} | {out} | {} |\n",
            row.values.join(" | "),
            row.message.clone().unwrap_or_default().replace('|', "/")
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges() {
        assert_eq!(
            parse_range("fluid.tau=0.5:0.6:3").unwrap().1,
            vec!["0.5", "0.55", "0.6"]
        );
        assert_eq!(parse_range("k=1:100:3:log").unwrap().1, vec!["1", "10", "100"]);
        assert_eq!(parse_range("k=1,2").unwrap().1, vec!["1", "2"]);
        assert!(parse_range("k=1:2:1").is_err());
        assert!(parse_range("k=0:2:3:log").is_err());
        assert!(parse_range("k=a:2:3").is_err());
    }
}
