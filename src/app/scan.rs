//! `blockflow sweep SCENE --vary KEY=V1,V2,... [--vary ...] [--set ...] [--repeat N] [--steps N]
//! [--error OBSERVABLE] [--out DIR]`: runs a scene over every combination of the varied
//! keys and writes `sweep.csv` (the varied values, status, steps, wall and core seconds, MLUPS, median
//! load imbalance, the core of each thread and every observable) and `sweep.png`: error against run
//! time (log–log, one line per variant with the fitted order of convergence in the legend), or, for a
//! scene without an error observable (a pinning or placement experiment), MLUPS, wall time and load
//! imbalance as one bar per configuration.
//!
//! The first `--vary` key drives convergence (resolution above all): a variant is one combination of the
//! other keys, and its order is the least-squares slope of −log(error) against log(first key). With
//! `--repeat N` every run is repeated and the fastest wall time is kept (the results are bitwise the same).
//! An unstable run is a row with status `unstable`, not the end of the sweep; a bad key or value stops it.

use crate::app::run::{self, RunOptions};
use crate::config;
use crate::error::{io_err, Error, Result};
use crate::io::plots::scan::ConfigurationBar;
use std::collections::BTreeMap;
use std::path::PathBuf;

/// Run a scene over every combination of the varied keys (`blockflow sweep`).
#[derive(clap::Args, Debug)]
pub struct SweepArgs {
    /// Scene file (TOML).
    pub scene: PathBuf,
    /// KEY=V1,V2,... (repeatable; the first key drives convergence, e.g. scene.resolution=16,32,64).
    #[arg(long, value_name = "KEY=V1,V2,...", required = true)]
    pub vary: Vec<String>,
    /// Fixed override (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Runs per combination; the fastest wall time is kept.
    #[arg(long, default_value_t = 1)]
    pub repeat: usize,
    /// Number of time steps (default: the scene's).
    #[arg(long)]
    pub steps: Option<u64>,
    /// Observable plotted as the error (default: the first whose name contains "error").
    #[arg(long)]
    pub error: Option<String>,
    /// Output folder.
    #[arg(long, default_value = "out/sweep")]
    pub out: PathBuf,
}

/// Runs `blockflow sweep` and prints its table.
pub fn execute(a: SweepArgs) -> Result<()> {
    if a.repeat == 0 {
        return Err(Error::Config("--repeat 0: must be at least 1".into()));
    }
    let vary = a.vary.iter().map(|v| parse_vary(v)).collect::<Result<Vec<_>>>()?;
    let opts = ScanOptions {
        scene: a.scene,
        vary,
        sets: a.set,
        repeat: a.repeat,
        steps: a.steps,
        error: a.error,
        out: a.out.clone(),
        record_refused: false,
        repeat_until_seconds: None,
    };
    let r = scan(&opts)?;
    super::print_out(&format!("{}results in {}\n", to_markdown(&r), a.out.display()));
    Ok(())
}

/// Options of `blockflow sweep`.
#[derive(Clone, Debug, Default)]
pub struct ScanOptions {
    /// Scene file.
    pub scene: PathBuf,
    /// Varied keys and their values (TOML literals), the first one driving convergence.
    pub vary: Vec<(String, Vec<String>)>,
    /// Fixed overrides.
    pub sets: Vec<String>,
    /// Runs per combination (the fastest is kept).
    pub repeat: usize,
    /// Steps (default: the scene's).
    pub steps: Option<u64>,
    /// Observable plotted as the error (default: the first whose name contains "error").
    pub error: Option<String>,
    /// Output folder.
    pub out: PathBuf,
    /// Record a combination the scene refuses (a value out of its range: a configuration error raised
    /// when the run is set up) as a `refused` row instead of stopping the sweep (stability maps).
    pub record_refused: bool,
    /// Stop repeating a combination once a run took longer than this many seconds (long runs carry little
    /// timing noise); absent: always `repeat` runs.
    pub repeat_until_seconds: Option<f64>,
}

/// One combination.
#[derive(Clone, Debug)]
pub struct ScanRow {
    /// The varied values, in `--vary` order.
    pub values: Vec<String>,
    /// `ok`, `unstable` or `refused` (the scene refused the values; only with
    /// [`ScanOptions::record_refused`]).
    pub status: String,
    /// Steps run.
    pub steps: u64,
    /// Fastest wall seconds of the repeats.
    pub wall_seconds: f64,
    /// CPU seconds of every task of that run (all threads).
    pub core_seconds: f64,
    /// Million fluid-cell updates per second.
    pub mlups: f64,
    /// Median load imbalance eq. (18) over the run's intervals (0 on one process; NaN for a failed run).
    pub imbalance: f64,
    /// The core each worker thread was pinned to, `;`-separated in thread order (`-` for an unpinned
    /// thread; empty for a failed run).
    pub cores: String,
    /// The scene's observables.
    pub observables: BTreeMap<String, f64>,
    /// The step at which an unstable run was stopped.
    pub failed_step: Option<u64>,
    /// The instability message (step, block, cell).
    pub message: Option<String>,
}

/// The result of a sweep.
#[derive(Clone, Debug)]
pub struct ScanReport {
    /// Varied keys.
    pub keys: Vec<String>,
    /// One row per combination.
    pub rows: Vec<ScanRow>,
    /// The error observable.
    pub error: Option<String>,
    /// Fitted order of convergence per variant label.
    pub orders: Vec<(String, f64)>,
    /// Indices of the rows on the Pareto front (cheapest run for each error level).
    pub pareto: Vec<usize>,
}

/// Parses `KEY=V1,V2,...`; commas inside brackets or quotes belong to a value (`domain.blocks=[2,2,1],[4,4,2]`).
pub fn parse_vary(s: &str) -> Result<(String, Vec<String>)> {
    let (k, v) = s
        .split_once('=')
        .ok_or_else(|| Error::Config(format!("--vary {s}: expected KEY=V1,V2,...")))?;
    let mut values = Vec::new();
    let (mut depth, mut quoted, mut cur) = (0i32, false, String::new());
    for ch in v.chars() {
        match ch {
            '"' => quoted = !quoted,
            '[' if !quoted => depth += 1,
            ']' if !quoted => depth -= 1,
            ',' if depth == 0 && !quoted => {
                values.push(std::mem::take(&mut cur));
                continue;
            }
            _ => {}
        }
        cur.push(ch);
    }
    values.push(cur);
    let values: Vec<String> = values.into_iter().map(|x| x.trim().to_string()).collect();
    if k.trim().is_empty() || values.iter().any(|x| x.is_empty()) {
        return Err(Error::Config(format!(
            "--vary {s}: expected KEY=V1,V2,... with no empty value"
        )));
    }
    Ok((k.trim().to_string(), values))
}

/// Least-squares slope of log y against log x over the positive finite points (None below two points or
/// for a degenerate x).
pub fn log_slope(points: &[(f64, f64)]) -> Option<f64> {
    let p: Vec<(f64, f64)> = points
        .iter()
        .filter(|(x, y)| x.is_finite() && y.is_finite() && *x > 0.0 && *y > 0.0)
        .map(|(x, y)| (x.ln(), y.ln()))
        .collect();
    if p.len() < 2 {
        return None;
    }
    let n = p.len() as f64;
    let (mx, my) = (
        p.iter().map(|q| q.0).sum::<f64>() / n,
        p.iter().map(|q| q.1).sum::<f64>() / n,
    );
    let sxx: f64 = p.iter().map(|q| (q.0 - mx).powi(2)).sum();
    let sxy: f64 = p.iter().map(|q| (q.0 - mx) * (q.1 - my)).sum();
    (sxx > 0.0).then(|| sxy / sxx)
}

/// Rows on the Pareto front of (wall seconds, error): sorted by time, each strictly more accurate than
/// every faster one.
pub fn pareto_front(points: &[(f64, f64)]) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..points.len())
        .filter(|&i| points[i].0.is_finite() && points[i].1.is_finite())
        .collect();
    idx.sort_by(|&a, &b| {
        points[a]
            .0
            .total_cmp(&points[b].0)
            .then(points[a].1.total_cmp(&points[b].1))
    });
    let mut best = f64::INFINITY;
    idx.into_iter()
        .filter(|&i| {
            let keep = points[i].1 < best;
            if keep {
                best = points[i].1;
            }
            keep
        })
        .collect()
}

/// Runs the sweep and writes its CSV and figure.
pub fn scan(opts: &ScanOptions) -> Result<ScanReport> {
    if opts.vary.is_empty() {
        return Err(Error::Config("sweep: give at least one --vary KEY=V1,V2,...".into()));
    }
    std::fs::create_dir_all(&opts.out).map_err(|e| io_err(&opts.out, e))?;
    let keys: Vec<String> = opts.vary.iter().map(|(k, _)| k.clone()).collect();
    let combos = combinations(&opts.vary);
    // Every combination's configuration is checked before the first run: a bad value late in the sweep
    // would otherwise stop it after the runs before it.
    for combo in &combos {
        config::load(&opts.scene, &sets_of(opts, &keys, combo))?;
    }
    let mut rows = Vec::new();
    for (n, combo) in combos.iter().enumerate() {
        let row = best_of_repeats(opts, &keys, n, combo)?;
        let took = match (row.failed_step, row.wall_seconds.is_finite()) {
            (Some(st), _) => format!(" at step {st}"),
            (None, true) => format!(" in {:.2} s", row.wall_seconds),
            (None, false) => String::new(),
        };
        eprintln!(
            "sweep: {} -> {}{took}",
            keys.iter()
                .zip(&row.values)
                .map(|(k, v)| format!("{k}={v}"))
                .collect::<Vec<_>>()
                .join(" "),
            row.status,
        );
        rows.push(row);
    }
    let error = opts.error.clone().or_else(|| {
        rows.iter()
            .flat_map(|r| r.observables.keys())
            .find(|k| k.contains("error"))
            .cloned()
    });
    let err_of = |r: &ScanRow| {
        error
            .as_ref()
            .and_then(|e| r.observables.get(e).copied())
            .unwrap_or(f64::NAN)
    };
    let (orders, lines) = variant_lines(&keys, &rows, &err_of);
    let pareto = pareto_front(&rows.iter().map(|r| (r.wall_seconds, err_of(r))).collect::<Vec<_>>());
    write_csv(opts, &keys, &rows)?;
    let figure = opts.out.join("sweep.png");
    let drawn = match &error {
        Some(e) => {
            let title = format!("{}: {e} against run time", opts.scene.display());
            crate::io::plots::scan::error_vs_time(&figure, &title, e, &lines)
        }
        // No error observable (a pinning or placement experiment): speed, time and balance per run.
        None => {
            let title = format!("{}: one bar per configuration", opts.scene.display());
            let bars: Vec<ConfigurationBar> = rows
                .iter()
                .map(|r| ConfigurationBar {
                    label: keys
                        .iter()
                        .zip(&r.values)
                        .map(|(k, v)| format!("{}={}", k.rsplit('.').next().unwrap_or(k), v.trim_matches('"')))
                        .collect::<Vec<_>>()
                        .join(" "),
                    mlups: r.mlups,
                    wall_seconds: r.wall_seconds,
                    imbalance: r.imbalance,
                })
                .collect();
            crate::io::plots::scan::configurations(&figure, &title, &bars)
        }
    };
    if let Err(err) = drawn {
        eprintln!("sweep: no figure: {err}");
    }
    Ok(ScanReport {
        keys,
        rows,
        error,
        orders,
        pareto,
    })
}

/// The `--set` overrides of one combination: the sweep's own, then each varied key's value.
fn sets_of(opts: &ScanOptions, keys: &[String], combo: &[String]) -> Vec<String> {
    let mut sets = opts.sets.clone();
    sets.extend(keys.iter().zip(combo).map(|(k, v)| format!("{k}={v}")));
    sets
}

/// Every combination of the varied values, the first key slowest.
fn combinations(vary: &[(String, Vec<String>)]) -> Vec<Vec<String>> {
    let mut combos: Vec<Vec<String>> = vec![Vec::new()];
    for (_, values) in vary {
        combos = combos
            .into_iter()
            .flat_map(|c| {
                values.iter().map(move |v| {
                    let mut c = c.clone();
                    c.push(v.clone());
                    c
                })
            })
            .collect();
    }
    combos
}

/// Runs combination `n` (`--repeat` times, stopping early past `repeat_until_seconds`) and keeps the
/// fastest row.
fn best_of_repeats(opts: &ScanOptions, keys: &[String], n: usize, combo: &[String]) -> Result<ScanRow> {
    let cfg = config::load(&opts.scene, &sets_of(opts, keys, combo))?;
    let mut best: Option<ScanRow> = None;
    for _ in 0..opts.repeat.max(1) {
        let row = one_row(opts, &cfg, n, combo)?;
        let long = opts
            .repeat_until_seconds
            .is_some_and(|t| row.wall_seconds.is_nan() || row.wall_seconds > t);
        if best.as_ref().is_none_or(|b| row.wall_seconds < b.wall_seconds) {
            best = Some(row);
        }
        if long {
            break;
        }
    }
    Ok(best.expect("at least one repeat"))
}

/// One run of a combination as a row: its figures, or `unstable` (with the step), or `refused` (with
/// `record_refused`); any other error stops the scan.
fn one_row(opts: &ScanOptions, cfg: &config::Config, n: usize, combo: &[String]) -> Result<ScanRow> {
    let run_opts = RunOptions {
        steps: opts.steps,
        out: Some(opts.out.join(format!("run-{n:03}"))),
        scene_path: Some(opts.scene.clone()),
        ..Default::default()
    };
    let failed = |status: &str, failed_step: Option<u64>, message: String| ScanRow {
        failed_step,
        message: Some(message),
        values: combo.to_vec(),
        status: status.into(),
        steps: 0,
        wall_seconds: f64::NAN,
        core_seconds: f64::NAN,
        mlups: f64::NAN,
        imbalance: f64::NAN,
        cores: String::new(),
        observables: BTreeMap::new(),
    };
    Ok(match run::run(cfg, &run_opts) {
        Ok(s) => {
            let p = &s.parts_seconds;
            ScanRow {
                values: combo.to_vec(),
                status: s.status.clone(),
                steps: s.steps,
                wall_seconds: s.wall_seconds,
                core_seconds: p.lbm
                    + p.boundary
                    + p.exchange
                    + p.rigid_body.unwrap_or(0.0)
                    + p.map.unwrap_or(0.0)
                    + p.reconstruct.unwrap_or(0.0),
                mlups: s.mlups,
                imbalance: s.balance.as_ref().map_or(0.0, |b| b.imbalance_median),
                cores: s
                    .cores
                    .iter()
                    .map(|c| c.map_or("-".to_string(), |c| c.to_string()))
                    .collect::<Vec<_>>()
                    .join(";"),
                observables: s.observables.clone(),
                failed_step: None,
                message: None,
            }
        }
        Err(e @ (Error::Unstable(_) | Error::ParticlesUnstable(_))) => {
            eprintln!("sweep: {}: {e}", combo.join(" "));
            let step = match &e {
                Error::Unstable(i) => Some(i.step),
                _ => None,
            };
            failed("unstable", step, e.to_string())
        }
        Err(Error::Config(msg)) if opts.record_refused => {
            eprintln!("sweep: {}: refused: {msg}", combo.join(" "));
            failed("refused", None, msg)
        }
        Err(e) => return Err(e),
    })
}

/// The variants (combinations of every key but the first) with their fitted orders, and one figure line
/// per variant: (run time, error) over the first key.
#[allow(clippy::type_complexity)]
fn variant_lines(
    keys: &[String],
    rows: &[ScanRow],
    err_of: &dyn Fn(&ScanRow) -> f64,
) -> (Vec<(String, f64)>, Vec<(String, Vec<(f64, f64)>)>) {
    let mut variants: BTreeMap<Vec<String>, Vec<usize>> = BTreeMap::new();
    for (i, r) in rows.iter().enumerate() {
        variants.entry(r.values[1..].to_vec()).or_default().push(i);
    }
    let mut orders = Vec::new();
    let mut lines = Vec::new();
    for (v, idx) in &variants {
        let label = if v.is_empty() {
            "all".to_string()
        } else {
            keys[1..]
                .iter()
                .zip(v)
                .map(|(k, x)| format!("{k}={x}"))
                .collect::<Vec<_>>()
                .join(" ")
        };
        let conv: Vec<(f64, f64)> = idx
            .iter()
            .filter_map(|&i| rows[i].values[0].parse::<f64>().ok().map(|x| (x, err_of(&rows[i]))))
            .collect();
        let order = log_slope(&conv).map(|s| -s);
        if let Some(o) = order {
            orders.push((label.clone(), o));
        }
        // The legend names each key by its last part and drops TOML quotes, so that labels fit.
        let short = keys[1..]
            .iter()
            .zip(v)
            .map(|(k, x)| format!("{}={}", k.rsplit('.').next().unwrap_or(k), x.trim_matches('"')))
            .collect::<Vec<_>>()
            .join(" ");
        let short = if short.is_empty() { label } else { short };
        let label = match order {
            Some(o) => format!("{short} (order {o:.2})"),
            None => short,
        };
        lines.push((
            label,
            idx.iter().map(|&i| (rows[i].wall_seconds, err_of(&rows[i]))).collect(),
        ));
    }
    (orders, lines)
}

fn write_csv(opts: &ScanOptions, keys: &[String], rows: &[ScanRow]) -> Result<()> {
    let obs: std::collections::BTreeSet<&String> = rows.iter().flat_map(|r| r.observables.keys()).collect();
    let mut text = keys.join(",");
    text += ",status,steps,wall_seconds,core_seconds,mlups,imbalance,cores";
    for o in &obs {
        text += &format!(",{o}");
    }
    text.push('\n');
    for r in rows {
        let quoted: Vec<String> = r
            .values
            .iter()
            .map(|v| {
                if v.contains(',') || v.contains('"') {
                    format!("\"{}\"", v.replace('"', "\"\""))
                } else {
                    v.clone()
                }
            })
            .collect();
        text += &quoted.join(",");
        text += &format!(
            ",{},{},{:.6e},{:.6e},{:.4},{:.6e},{}",
            r.status, r.steps, r.wall_seconds, r.core_seconds, r.mlups, r.imbalance, r.cores
        );
        for o in &obs {
            match r.observables.get(*o) {
                Some(v) => text += &format!(",{v:.9e}"),
                None => text += ",",
            }
        }
        text.push('\n');
    }
    let p = opts.out.join("sweep.csv");
    std::fs::write(&p, text).map_err(|e| io_err(&p, e))
}

/// The sweep as a markdown table: with an error observable its value and the Pareto rows marked;
/// without one (a pinning or scaling experiment) the median load imbalance and the cores the threads
/// ran on instead.
pub fn to_markdown(r: &ScanReport) -> String {
    let keys = r.keys.join(" | ");
    let rule = "---|".repeat(r.keys.len());
    let mut s = match &r.error {
        Some(e) => format!(
            "| {keys} | status | wall s | core s | MLUPS | {e} | Pareto |\n|{rule}---|---:|---:|---:|---:|---|\n"
        ),
        None => {
            format!("| {keys} | status | wall s | core s | MLUPS | LI | cores |\n|{rule}---|---:|---:|---:|---:|---|\n")
        }
    };
    for (i, row) in r.rows.iter().enumerate() {
        let last = match &r.error {
            Some(k) => format!(
                "{:.3e} | {}",
                row.observables.get(k).copied().unwrap_or(f64::NAN),
                if r.pareto.contains(&i) { "yes" } else { "" }
            ),
            None => format!("{:.1} % | {}", 100.0 * row.imbalance, row.cores.replace(';', " ")),
        };
        s += &format!(
            "| {} | {} | {:.3} | {:.3} | {:.1} | {last} |\n",
            row.values.join(" | "),
            row.status,
            row.wall_seconds,
            row.core_seconds,
            row.mlups,
        );
    }
    for (label, o) in &r.orders {
        s += &format!("\norder of convergence, {label}: {o:.2}");
    }
    s.push('\n');
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vary_values_keep_brackets_and_quotes() {
        let (k, v) = parse_vary("domain.blocks=[2,2,1],[4,4,2]").unwrap();
        assert_eq!(k, "domain.blocks");
        assert_eq!(v, vec!["[2,2,1]", "[4,4,2]"]);
        let (_, v) = parse_vary("fluid.precision=\"f32\",\"f64\"").unwrap();
        assert_eq!(v, vec!["\"f32\"", "\"f64\""]);
        assert!(parse_vary("novalue").is_err());
        assert!(parse_vary("a=1,,2").is_err());
    }

    #[test]
    fn slope_and_pareto() {
        // e = 3 N^-2 exactly: slope -2.
        let pts: Vec<(f64, f64)> = [8.0, 16.0, 32.0].iter().map(|&n: &f64| (n, 3.0 * n.powi(-2))).collect();
        assert!((log_slope(&pts).unwrap() + 2.0).abs() < 1e-12);
        assert!(log_slope(&pts[..1]).is_none());
        // (time, error): 0 is fastest; 2 is slower and better; 1 is slower than 0 and worse; 3 slowest, best.
        let front = pareto_front(&[(1.0, 0.1), (2.0, 0.2), (3.0, 0.05), (4.0, 0.01), (f64::NAN, 0.0)]);
        assert_eq!(front, vec![0, 2, 3]);
    }

    fn row(values: &[&str], imbalance: f64, cores: &str, error: Option<f64>) -> ScanRow {
        ScanRow {
            values: values.iter().map(|v| v.to_string()).collect(),
            status: "ok".into(),
            steps: 100,
            wall_seconds: 1.0,
            core_seconds: 2.0,
            mlups: 20.0,
            imbalance,
            cores: cores.into(),
            observables: error.map(|e| ("l2_error".to_string(), e)).into_iter().collect(),
            failed_step: None,
            message: None,
        }
    }

    #[test]
    fn table_shows_imbalance_and_cores_without_an_error_observable() {
        let pinning = ScanReport {
            keys: vec!["processes.pin".into()],
            rows: vec![
                row(&["compact"], 0.195, "0;1", None),
                row(&["none"], 0.105, "-;-", None),
            ],
            error: None,
            orders: vec![],
            pareto: vec![],
        };
        let t = to_markdown(&pinning);
        assert!(
            t.starts_with("| processes.pin | status | wall s | core s | MLUPS | LI | cores |"),
            "{t}"
        );
        assert!(
            t.contains("| compact | ok | 1.000 | 2.000 | 20.0 | 19.5 % | 0 1 |"),
            "{t}"
        );
        assert!(t.contains("| none | ok | 1.000 | 2.000 | 20.0 | 10.5 % | - - |"), "{t}");
        assert!(!t.contains("Pareto") && !t.contains("NaN"), "{t}");
        let accuracy = ScanReport {
            keys: vec!["scene.resolution".into()],
            rows: vec![row(&["8"], 0.0, "-", Some(1.5e-3))],
            error: Some("l2_error".into()),
            orders: vec![],
            pareto: vec![0],
        };
        let t = to_markdown(&accuracy);
        assert!(
            t.contains("| l2_error | Pareto |") && t.contains("| 8 | ok | 1.000 | 2.000 | 20.0 | 1.500e-3 | yes |"),
            "{t}"
        );
    }
}
