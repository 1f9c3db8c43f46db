//! `blockflow bench accuracy [--quick] [--out DIR]`: the built-in suite of
//! run time against error. Every scene runs through [`crate::app::scan`] over its resolution and both
//! precisions (for the drag array three solid fractions and both particle boundaries, for the settling
//! sphere the cases of ten Cate et al. 2002 against their measured peak speed); per scene the
//! Pareto front (the cheapest run for each error level), the fitted orders, and the f32 error and speedup
//! next to f64 are printed. `--quick` is the CI size.

use crate::app::scan::{self, ScanOptions, ScanReport};
use crate::error::Result;
use std::path::{Path, PathBuf};

/// One scene of the suite.
struct Case {
    name: &'static str,
    file: &'static str,
    vary: Vec<(&'static str, Vec<&'static str>)>,
    sets: Vec<&'static str>,
    error: &'static str,
    /// Repeats (the fastest counts); long runs need fewer.
    repeat: Option<usize>,
}

fn suite(quick: bool) -> Vec<Case> {
    let prec = ("fluid.precision", vec!["\"f64\"", "\"f32\""]);
    let pick = |q: Vec<&'static str>, full: Vec<&'static str>| if quick { q } else { full };
    vec![
        Case {
            name: "channel",
            file: "channel.toml",
            vary: vec![
                ("scene.resolution", pick(vec!["8", "16"], vec!["8", "16", "32"])),
                prec.clone(),
            ],
            sets: vec![],
            error: "l2_error",
            repeat: None,
        },
        Case {
            name: "couette",
            file: "couette.toml",
            vary: vec![
                ("scene.resolution", pick(vec!["8", "16"], vec!["8", "16", "32"])),
                prec.clone(),
            ],
            sets: vec![],
            error: "l2_error",
            repeat: None,
        },
        Case {
            name: "taylor_green",
            file: "taylor_green.toml",
            vary: vec![
                ("scene.resolution", pick(vec!["16", "24"], vec!["16", "24", "32", "48"])),
                prec.clone(),
            ],
            sets: vec![],
            error: "l2_error",
            repeat: None,
        },
        Case {
            name: "drag_array",
            file: "drag_array.toml",
            vary: vec![
                ("scene.resolution", pick(vec!["8", "12"], vec!["8", "12", "16", "24"])),
                (
                    "scene.solid_fraction",
                    pick(vec!["0.125"], vec!["0.064", "0.125", "0.216"]),
                ),
                ("particles.boundary", vec!["\"cli\"", "\"sbb\""]),
                prec,
            ],
            sets: vec![],
            error: "relative_error",
            repeat: None,
        },
        // The settling sphere against ten Cate et al. (2002), in SI units: the four cases E1-E4 (Re 1.5-32)
        // at 6, 9, 12 and 16 cells per diameter in the full suite (9 gives the exact 60 x 60 x 96 box), E4 at
        // 6 and 9 in the quick one. One run each: they take seconds to minutes.
        Case {
            name: "settling_sphere",
            file: "settling_sphere.toml",
            vary: vec![
                ("scene.resolution", pick(vec!["6", "9"], vec!["6", "9", "12", "16"])),
                (
                    "scene.case",
                    pick(vec!["\"E4\""], vec!["\"E1\"", "\"E2\"", "\"E3\"", "\"E4\""]),
                ),
                ("fluid.precision", vec!["\"f64\"", "\"f32\""]),
            ],
            sets: vec![],
            error: "relative_error",
            repeat: Some(1),
        },
    ]
}

/// One scene's result.
pub struct AccuracyCase {
    /// Scene name.
    pub name: String,
    /// The sweep.
    pub report: ScanReport,
}

/// Runs the suite into `out/<scene>/`.
pub fn run(quick: bool, out: &Path, configs: &Path) -> Result<Vec<AccuracyCase>> {
    let mut res = Vec::new();
    for c in suite(quick) {
        let opts = ScanOptions {
            scene: configs.join(c.file),
            vary: c
                .vary
                .iter()
                .map(|(k, v)| (k.to_string(), v.iter().map(|x| x.to_string()).collect()))
                .collect(),
            sets: c.sets.iter().map(|s| s.to_string()).collect(),
            // The fastest of a few repeats: the runs are short and the machine is noisy.
            repeat: c.repeat.unwrap_or(if quick { 2 } else { 3 }),
            steps: None,
            error: Some(c.error.to_string()),
            out: out.join(c.name),
            record_refused: false,
            // Runs over 5 s are not repeated: their timing noise is small next to their length.
            repeat_until_seconds: Some(5.0),
        };
        res.push(AccuracyCase {
            name: c.name.to_string(),
            report: scan::scan(&opts)?,
        });
    }
    Ok(res)
}

/// Per scene: the Pareto front, the orders, and f32 against f64 (error ratio and speedup) for every
/// combination run in both precisions.
pub fn to_markdown(cases: &[AccuracyCase]) -> String {
    let mut s = String::new();
    for c in cases {
        let r = &c.report;
        let e = r.error.clone().unwrap_or_default();
        s += &format!("### {}\n\nPareto front (cheapest run for each {e} level):\n\n", c.name);
        s += &format!("| {} | core s | wall s | {e} | {e} × core s |\n", r.keys.join(" | "));
        s += &format!("|{}---:|---:|---:|---:|\n", "---|".repeat(r.keys.len()));
        for &i in &r.pareto {
            let row = &r.rows[i];
            let err = row.observables.get(&e).copied().unwrap_or(f64::NAN);
            s += &format!(
                "| {} | {:.3} | {:.3} | {:.3e} | {:.3e} |\n",
                row.values.join(" | "),
                row.core_seconds,
                row.wall_seconds,
                err,
                err * row.core_seconds
            );
        }
        for (label, o) in &r.orders {
            s += &format!("\norder of convergence, {label}: {o:.2}");
        }
        if r.rows.iter().any(|x| x.observables.contains_key("velocity_noise")) {
            s += "\n\nEvery run: peak settling speed against the measured one, raw (largest per-step speed) and \
                  windowed (one cell of travel), and the noise of the raw speed (RMS about its one-cell mean, \
                  relative to the peak):\n\n";
            s += &format!(
                "| {} | raw error | windowed error | noise | wall s | core s |\n",
                r.keys.join(" | ")
            );
            s += &format!("|{}---:|---:|---:|---:|---:|\n", "---|".repeat(r.keys.len()));
            for row in &r.rows {
                let o = |k: &str| row.observables.get(k).copied().unwrap_or(f64::NAN);
                s += &format!(
                    "| {} | {:.2} % | {:.2} % | {:.2} % | {:.1} | {:.1} |\n",
                    row.values.join(" | "),
                    100.0 * o("relative_error_raw"),
                    100.0 * o("relative_error"),
                    100.0 * o("velocity_noise"),
                    row.wall_seconds,
                    row.core_seconds
                );
            }
        }
        if let Some(pi) = r.keys.iter().position(|k| k == "fluid.precision") {
            s += "\n\nf32 against f64 (same other values):\n\n| values | f64 error | f32 error | f32 speedup |\n|---|---:|---:|---:|\n";
            for a in r.rows.iter().filter(|x| x.values[pi].contains("f64")) {
                let twin = r.rows.iter().find(|b| {
                    b.values[pi].contains("f32")
                        && b.values.iter().enumerate().all(|(k, v)| k == pi || *v == a.values[k])
                });
                if let Some(b) = twin {
                    let mut vals = a.values.clone();
                    vals.remove(pi);
                    s += &format!(
                        "| {} | {:.3e} | {:.3e} | {:.2} |\n",
                        vals.join(" "),
                        a.observables.get(&e).copied().unwrap_or(f64::NAN),
                        b.observables.get(&e).copied().unwrap_or(f64::NAN),
                        a.wall_seconds / b.wall_seconds
                    );
                }
            }
        }
        s += "\n";
    }
    s
}

/// Default configs folder (the crate's `configs/`, else `./configs`).
pub fn configs_dir() -> PathBuf {
    let here = PathBuf::from("configs");
    if here.is_dir() {
        here
    } else {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("configs")
    }
}
