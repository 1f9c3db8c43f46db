//! The coefficients of the workload functions (eqs. 10–14 or this engine's form, [`Model`]), their
//! evaluation (eq. 15) and the `coefficients.toml` format.
//!
//! Layout of the file (every key required except `model`, `provenance.threads` and
//! `provenance.fit_quality`; unknown keys are errors):
//!
//! ```toml
//! model = "blockflow"         # or "paper" (the default when the key is missing)
//! floor = 0.0                 # lower bound of every predicted part (seconds), ≥ 0
//!
//! [provenance]
//! machine = "..."             # where the timings were measured
//! date = "..."
//! commit = "..."              # blockflow commit that was timed
//! scenes = ["..."]            # calibration scenes / runs
//! samples = 0                 # number of samples fitted
//! threads = 1                 # workers of the timed runs, each on a core of its own (default 1)
//! note = "..."
//!
//! [provenance.fit_quality]    # optional: name = number, e.g. step_in_sample, interval_held_out
//!
//! [lbm]    # one key per term of the model: paper a1 … a3 (eq. 10), blockflow fluid_cells, runs, active
//! [bh]     # eq. (11) or its blockflow form
//! [coup1]  # eq. (12)
//! [coup2]  # eq. (13)
//! [rb]     # eq. (14)
//! ```
//!
//! The keys of each table are the model's terms ([`Model::terms`]); a missing or unknown key is an
//! error naming the table and the key. [`Coefficients::to_toml`] writes every number in the shortest
//! form that reads back to the same bits, so `parse(to_toml(c)) == c` bitwise.

use std::collections::BTreeMap;
use std::path::Path;

use serde::Deserialize;

use super::model::Model;
use super::{PartTimes, Quantities, PARTS};
use crate::error::{Error, Result};

/// `configs/coefficients.toml` as it was when this binary was built: the coefficients a run uses when
/// `balance.coefficients` is the default path and the working folder has no such file.
pub const BUILT_IN_COEFFICIENTS: &str = include_str!("../../configs/coefficients.toml");

/// Where a set of coefficients came from (section 3.5: coefficients are valid only for the machine,
/// implementation and algorithms they were measured with).
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Provenance {
    /// Machine the timings were measured on.
    pub machine: String,
    /// Date of the calibration.
    pub date: String,
    /// Commit of the timed code.
    pub commit: String,
    /// Calibration scenes or runs (section 3.3: block sizes and diameters).
    pub scenes: Vec<String>,
    /// Number of samples fitted.
    pub samples: usize,
    /// Worker threads of the timed runs, each pinned to a core of its own: the memory contention the
    /// costs include (1: each block timed alone on its core; a file without the key counts as 1).
    #[serde(default = "one_thread")]
    pub threads: usize,
    /// Fit quality measures (section 3.4), e.g. `step_in_sample`, `interval_held_out`.
    #[serde(default)]
    pub fit_quality: BTreeMap<String, f64>,
    /// Free text.
    pub note: String,
}

fn one_thread() -> usize {
    1
}

impl Default for Provenance {
    fn default() -> Self {
        Provenance {
            machine: String::new(),
            date: String::new(),
            commit: String::new(),
            scenes: Vec::new(),
            samples: 0,
            threads: one_thread(),
            fit_quality: BTreeMap::new(),
            note: String::new(),
        }
    }
}

/// Coefficients of the five workload functions of one [`Model`] plus provenance. `parts[p][j]`
/// multiplies term j of part p ([`PARTS`] order; for the paper's model, the paper's a_{j+1,X}).
#[derive(Clone, Debug, PartialEq)]
pub struct Coefficients {
    /// The form of the workload functions.
    pub model: Model,
    /// One coefficient per term of each part.
    pub parts: [Vec<f64>; 5],
    /// Lower bound (≥ 0) of every predicted part; see [`Coefficients::predict`].
    pub floor: f64,
    /// Where the coefficients came from.
    pub provenance: Provenance,
}

impl Coefficients {
    /// All-zero coefficients of `model` (what a fit without samples gives).
    pub fn zeros(model: Model, provenance: Provenance) -> Self {
        Coefficients {
            model,
            parts: std::array::from_fn(|p| vec![0.0; model.terms(p).len()]),
            floor: 0.0,
            provenance,
        }
    }

    /// The coefficients of part `name` (one of [`PARTS`]).
    pub fn part(&self, name: &str) -> &[f64] {
        let p = PARTS.iter().position(|x| *x == name).expect("a part name");
        &self.parts[p]
    }

    /// Predicted seconds of part `part` for quantities `q`, before the floor.
    pub fn raw(&self, part: usize, q: &Quantities) -> f64 {
        self.model.row(part, q).dot(&self.parts[part])
    }

    /// Eqs. (10)–(14) (or the model's form): predicted seconds per part for a block with quantities
    /// `q`, each part clamped below at [`floor`](Coefficients::floor).
    ///
    /// Why the floor: the paper's form needs negative intercepts (Table 2: a3,LBM, a3,BH, a5,Coup1,
    /// a5,Coup2 < 0), so blocks with few fluid cells, no boundary cells or no particles, above all empty
    /// blocks, get negative predictions. A negative weight is no workload and breaks the partitioners
    /// (prefix sums of weights must not decrease), so each part is at least `floor` ≥ 0. The
    /// `blockflow` form is fitted with non-negative coefficients and never needs it.
    pub fn predict(&self, q: &Quantities) -> PartTimes {
        let p: [f64; 5] = std::array::from_fn(|i| self.raw(i, q).max(self.floor));
        PartTimes {
            lbm: p[0],
            bh: p[1],
            coup1: p[2],
            coup2: p[3],
            rb: p[4],
        }
    }

    /// Eq. (15): WL_tot = WL_LBM + WL_BH + WL_Coup1 + WL_Coup2 + WL_RB (the clamped parts of
    /// [`predict`](Coefficients::predict)): the weight of a block.
    pub fn total(&self, q: &Quantities) -> f64 {
        self.predict(q).total()
    }

    /// Reads a coefficients file (layout in the module documentation). Errors are one line naming the
    /// file and the key.
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| Error::Config(format!("cannot read coefficients file {}: {e}", path.display())))?;
        Self::parse(&text, &path.display().to_string())
    }

    /// Parses coefficients text (named `origin` in messages) and checks it: the model's keys in every
    /// part table, every coefficient, the floor and every fit-quality number finite, the floor ≥ 0.
    pub fn parse(text: &str, origin: &str) -> Result<Self> {
        let fail = |m: String| Error::Config(format!("{origin}: {m}"));
        let mut table = crate::config::parse_table(text, origin)?;
        let model = match table.remove("model") {
            None => Model::Paper,
            Some(toml::Value::String(s)) => Model::parse(&s)
                .ok_or_else(|| fail(format!("model = {s:?}: unknown; use \"paper\" or \"blockflow\"")))?,
            Some(v) => return Err(fail(format!("model = {v}: must be \"paper\" or \"blockflow\""))),
        };
        let mut parts: [Vec<f64>; 5] = Default::default();
        for (p, name) in PARTS.iter().enumerate() {
            let t = match table.remove(*name) {
                Some(toml::Value::Table(t)) => t,
                Some(_) => return Err(fail(format!("{name}: must be a table"))),
                None => return Err(fail(format!("missing table [{name}]"))),
            };
            let terms = model.terms(p);
            for k in t.keys() {
                if !terms.iter().any(|(key, _)| key == k) {
                    let known: Vec<&str> = terms.iter().map(|t| t.0).collect();
                    return Err(fail(format!(
                        "{name}.{k}: unknown key for the {} model (known: {})",
                        model.name(),
                        known.join(", ")
                    )));
                }
            }
            for (key, _) in terms {
                let v = match t.get(*key) {
                    Some(toml::Value::Float(x)) => *x,
                    Some(toml::Value::Integer(i)) => *i as f64,
                    Some(v) => return Err(fail(format!("{name}.{key} = {v}: must be a number"))),
                    None => return Err(fail(format!("{name}: missing key `{key}`"))),
                };
                parts[p].push(v);
            }
        }
        #[derive(Deserialize)]
        #[serde(deny_unknown_fields)]
        struct Rest {
            floor: f64,
            provenance: Provenance,
        }
        let rest: Rest = serde_path_to_error::deserialize(toml::Value::Table(table)).map_err(|e| {
            let path = e.path().to_string();
            let key = if path == "." {
                String::new()
            } else {
                format!("{path}: ")
            };
            fail(format!("{key}{}", one_line(&e.inner().to_string())))
        })?;
        let c = Coefficients {
            model,
            parts,
            floor: rest.floor,
            provenance: rest.provenance,
        };
        c.check().map_err(fail)?;
        Ok(c)
    }

    /// Finite coefficients, finite non-negative floor, at least one thread, finite fit-quality numbers.
    fn check(&self) -> std::result::Result<(), String> {
        for (p, name) in PARTS.iter().enumerate() {
            for (v, (key, _)) in self.parts[p].iter().zip(self.model.terms(p)) {
                if !v.is_finite() {
                    return Err(format!("{name}.{key} = {v}: must be a finite number"));
                }
            }
        }
        if !self.floor.is_finite() || self.floor < 0.0 {
            return Err(format!("floor = {}: must be a finite number ≥ 0", self.floor));
        }
        if self.provenance.threads == 0 {
            return Err("provenance.threads = 0: the timed runs had at least one worker".into());
        }
        for (k, v) in &self.provenance.fit_quality {
            if !v.is_finite() {
                return Err(format!("provenance.fit_quality.{k} = {v}: must be a finite number"));
            }
        }
        Ok(())
    }

    /// Writes the coefficients file (layout in the module documentation), with a comment per
    /// coefficient naming the quantity it multiplies. Numbers are written in the shortest form that
    /// reads back to the same bits.
    pub fn to_toml(&self) -> String {
        let p = &self.provenance;
        let mut s = String::new();
        s.push_str(&format!(
            "# Workload estimator coefficients ({} model; eqs. (10)-(14) of Rettinger & Ruede (2019) or this\n",
            self.model.name()
        ));
        s.push_str("# engine's form of them); seconds per block and step. Valid only for the machine and code named\n");
        s.push_str("# in [provenance] (section 3.5).\n\n");
        s.push_str(&format!("model = {}\n", quote(self.model.name())));
        s.push_str("# Lower bound of every predicted part.\n");
        s.push_str(&format!("floor = {}\n\n", num(self.floor)));
        s.push_str("[provenance]\n");
        s.push_str(&format!("machine = {}\n", quote(&p.machine)));
        s.push_str(&format!("date = {}\n", quote(&p.date)));
        s.push_str(&format!("commit = {}\n", quote(&p.commit)));
        let scenes: Vec<String> = p.scenes.iter().map(|x| quote(x)).collect();
        s.push_str(&format!("scenes = [{}]\n", scenes.join(", ")));
        s.push_str(&format!("samples = {}\n", p.samples));
        s.push_str(&format!("threads = {}\n", p.threads));
        s.push_str(&format!("note = {}\n\n", quote(&p.note)));
        s.push_str("[provenance.fit_quality]\n");
        for (k, v) in &p.fit_quality {
            s.push_str(&format!("{} = {}\n", quote(k), num(*v)));
        }
        const EQ: [&str; 5] = [
            "eq. (10), LBM",
            "eq. (11), BH",
            "eq. (12), Coup1",
            "eq. (13), Coup2",
            "eq. (14), RB",
        ];
        for (i, name) in PARTS.iter().enumerate() {
            s.push_str(&format!("\n# {} ({} form)\n[{name}]\n", EQ[i], self.model.name()));
            for (v, (key, meaning)) in self.parts[i].iter().zip(self.model.terms(i)) {
                s.push_str(&format!("{key} = {} # {meaning}\n", num(*v)));
            }
        }
        s
    }
}

/// A float as TOML: Rust's `{:e}` is the shortest representation that reads back to the same bits, and
/// `1.5e-6`, `1e0`, `-0e0` are all TOML floats. Non-finite values (never written by a checked set) as
/// TOML's `nan`/`inf`.
fn num(v: f64) -> String {
    if v.is_nan() {
        "nan".into()
    } else if v.is_infinite() {
        if v > 0.0 { "inf" } else { "-inf" }.into()
    } else {
        format!("{v:e}")
    }
}

/// A TOML basic string (also used for keys: a quoted key is always valid).
fn quote(s: &str) -> String {
    let mut o = String::with_capacity(s.len() + 2);
    o.push('"');
    for ch in s.chars() {
        match ch {
            '"' => o.push_str("\\\""),
            '\\' => o.push_str("\\\\"),
            '\n' => o.push_str("\\n"),
            '\t' => o.push_str("\\t"),
            '\r' => o.push_str("\\r"),
            c if (c as u32) < 0x20 || c as u32 == 0x7f => o.push_str(&format!("\\u{:04X}", c as u32)),
            c => o.push(c),
        }
    }
    o.push('"');
    o
}

fn one_line(s: &str) -> String {
    s.split_whitespace().collect::<Vec<_>>().join(" ")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn example() -> Coefficients {
        let mut fq = BTreeMap::new();
        fq.insert("median_tot".to_string(), -1.234_567_890_123_456_7e-3);
        fq.insert("share within \"10%\"".to_string(), 0.871);
        Coefficients {
            model: Model::Paper,
            parts: [
                vec![9.99e-6, 1.57e-4, -8.23e-2],
                vec![6.65e-6, 7.06e-4, -0.1 - 0.2],
                vec![3.08e-6, 2.42e-7, 1.41e-2, 2.78e-2, -1.40e-1],
                vec![1.0 / 3.0, f64::MIN_POSITIVE, -0.0, 1e300, 5e-324],
                vec![1.16e-6, 9.62e-4, 2.75e-4, 1.48e-3, std::f64::consts::PI],
            ],
            floor: 1e-9,
            provenance: Provenance {
                machine: "test box\twith \\ tabs".into(),
                date: "2025-01-01".into(),
                commit: "abc123".into(),
                scenes: vec!["bs24-d10".into(), "ünïcode \"quoted\"\n".into()],
                samples: 1_300_000,
                threads: 3,
                fit_quality: fq,
                note: String::new(),
            },
        }
    }

    fn bits(c: &Coefficients) -> Vec<u64> {
        let mut v: Vec<f64> = c.parts.concat();
        v.push(c.floor);
        v.extend(c.provenance.fit_quality.values());
        v.iter().map(|x| x.to_bits()).collect()
    }

    #[test]
    fn parse_round_trips_to_toml_bitwise() {
        let c = example();
        let text = c.to_toml();
        let back = Coefficients::parse(&text, "mem").unwrap_or_else(|e| panic!("{e}\n{text}"));
        assert_eq!(bits(&back), bits(&c));
        assert_eq!(back.provenance, c.provenance);
        assert_eq!(back.to_toml(), text);
        // -0.0 keeps its sign.
        assert!(back.parts[3][2].is_sign_negative());
        // The blockflow form round-trips too, with its named keys.
        let mut b = Coefficients::zeros(Model::Blockflow, c.provenance.clone());
        for (p, v) in b.parts.iter_mut().enumerate() {
            for (j, x) in v.iter_mut().enumerate() {
                *x = (1 + p * 10 + j) as f64 * 1.1e-9;
            }
        }
        let text = b.to_toml();
        assert!(
            text.contains("model = \"blockflow\"") && text.contains("contacts_seen = "),
            "{text}"
        );
        let back = Coefficients::parse(&text, "mem").unwrap_or_else(|e| panic!("{e}\n{text}"));
        assert_eq!(bits(&back), bits(&b));
        assert_eq!(back.model, Model::Blockflow);
        // A paper file is not a blockflow file.
        let m = err(&text.replacen("model = \"blockflow\"", "model = \"paper\"", 1));
        assert!(m.contains("lbm.") && m.contains("paper model"), "{m}");
        let m = err(&text.replacen("model = \"blockflow\"", "model = \"fast\"", 1));
        assert!(m.contains("model") && m.contains("fast"), "{m}");
    }

    #[test]
    fn predict_applies_eqs_10_to_14_and_clamps_at_the_floor() {
        let mut c = example();
        c.parts[3] = vec![1e-6, 2e-6, 3e-3, 4e-3, 5e-3];
        c.parts[4] = vec![1e-6, 2e-4, 3e-4, 4e-4, 5e-3];
        c.floor = 0.0;
        let q = Quantities {
            c: 32768.0,
            f: 20000.0,
            nb: 3000.0,
            pl: 3.0,
            ps: 4.0,
            k: 5.0,
            s: 10.0,
            ..Default::default()
        };
        let p = c.predict(&q);
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-12 * b.abs().max(1e-300);
        assert!(close(p.lbm, 9.99e-6 * 32768.0 + 1.57e-4 * 20000.0 - 8.23e-2));
        assert!(close(
            p.coup1,
            3.08e-6 * 32768.0 + 2.42e-7 * 20000.0 + 1.41e-2 * 3.0 + 2.78e-2 * 4.0 - 1.40e-1
        ));
        assert!(close(
            p.coup2,
            1e-6 * 32768.0 + 2e-6 * 20000.0 + 3e-3 * 3.0 + 4e-3 * 4.0 + 5e-3
        ));
        assert!(close(
            p.rb,
            10.0 * (1e-6 * 49.0 + 2e-4 * 3.0 + 3e-4 * 4.0 + 4e-4 * 5.0 + 5e-3)
        ));
        assert!(close(c.total(&q), p.lbm + p.bh + p.coup1 + p.coup2 + p.rb));
        // S scales the rigid-body part linearly (eq. 14).
        let q20 = Quantities { s: 20.0, ..q };
        assert!(close(c.predict(&q20).rb, 2.0 * p.rb));

        // An empty block: the raw values of Table 2-like intercepts are negative; every part is clamped.
        let empty = Quantities {
            c: 13824.0,
            ..Default::default()
        };
        let raw_bh = 6.65e-6 * 13824.0 + (-0.1 - 0.2);
        assert!(raw_bh < 0.0);
        assert_eq!(c.predict(&empty).bh, 0.0);
        c.floor = 1e-7;
        let pe = c.predict(&empty);
        assert_eq!(pe.bh, 1e-7);
        assert_eq!(pe.coup1, 1e-7); // 3.08e-6·13824 − 0.14 < 0
        for v in pe.as_array() {
            assert!(v >= 1e-7);
        }
        // Parts above the floor are untouched.
        assert!(close(c.predict(&q).lbm, p.lbm));
    }

    fn err(text: &str) -> String {
        match Coefficients::parse(text, "coef.toml") {
            Err(Error::Config(m)) => {
                assert!(!m.contains('\n'), "not one line: {m}");
                assert!(m.starts_with("coef.toml: "), "does not name the file: {m}");
                m
            }
            Err(e) => panic!("not a config error: {e}"),
            Ok(_) => panic!("accepted:\n{text}"),
        }
    }

    #[test]
    fn malformed_incomplete_and_mismatched_files_give_one_line_errors_naming_the_key() {
        let good = example().to_toml();
        assert!(Coefficients::parse(&good, "coef.toml").is_ok());

        // Missing coefficient (a table one short).
        let m = err(&good.replacen("a3 = -8.23e-2 # 1\n", "", 1));
        assert!(m.contains("lbm") && m.contains("a3"), "{m}");
        // One coefficient too many.
        let m = err(&good.replacen("[bh]\n", "[bh]\na4 = 1.0\n", 1));
        assert!(m.contains("bh") && m.contains("a4"), "{m}");
        // Missing table.
        let start = good.find("\n# eq. (14)").unwrap();
        let m = err(&good[..start]);
        assert!(m.contains("rb"), "{m}");
        // Missing floor and missing provenance key.
        let m = err(&good.replacen("floor = 1e-9\n", "", 1));
        assert!(m.contains("floor"), "{m}");
        let m = err(&good.replacen("commit = \"abc123\"\n", "", 1));
        assert!(m.contains("provenance") && m.contains("commit"), "{m}");
        // Unknown top-level key.
        let m = err(&format!("speed = 1.0\n{good}"));
        assert!(m.contains("speed"), "{m}");
        // Wrong type.
        let m = err(&good.replacen("a2 = 1.57e-4", "a2 = \"fast\"", 1));
        assert!(m.contains("lbm.a2"), "{m}");
        // Non-finite values.
        let m = err(&good.replacen("a2 = 1.57e-4", "a2 = nan", 1));
        assert!(m.contains("lbm.a2"), "{m}");
        let m = err(&good.replacen("a5 = 3.141592653589793e0", "a5 = inf", 1));
        assert!(m.contains("rb.a5"), "{m}");
        let m = err(&good.replacen("\"median_tot\" = ", "\"median_tot\" = nan #", 1));
        assert!(m.contains("fit_quality.median_tot"), "{m}");
        // Files from before the key was written were timed on one worker; none is no thread count.
        let old = Coefficients::parse(&good.replacen("threads = 3\n", "", 1), "coef.toml").unwrap();
        assert_eq!(old.provenance.threads, 1);
        let m = err(&good.replacen("threads = 3", "threads = 0", 1));
        assert!(m.contains("provenance.threads"), "{m}");
        // Negative floor.
        let m = err(&good.replacen("floor = 1e-9", "floor = -1e-3", 1));
        assert!(m.contains("floor") && m.contains("≥ 0"), "{m}");
        // Syntax error.
        let m = err(&good.replacen("[lbm]", "[lbm", 1));
        assert!(m.contains("syntax") && m.contains("line"), "{m}");
        // Integers are accepted where floats are expected.
        let ok = Coefficients::parse(&good.replacen("floor = 1e-9", "floor = 0", 1), "coef.toml").unwrap();
        assert_eq!(ok.floor, 0.0);
    }

    #[test]
    fn load_names_the_file() {
        let dir = std::env::temp_dir().join(format!("blockflow-estimator-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("coefficients.toml");
        std::fs::write(&path, example().to_toml()).unwrap();
        assert_eq!(bits(&Coefficients::load(&path).unwrap()), bits(&example()));
        std::fs::write(&path, example().to_toml().replacen("floor = 1e-9", "floor = -1", 1)).unwrap();
        let m = Coefficients::load(&path).unwrap_err().to_string();
        assert!(m.contains(&path.display().to_string()) && m.contains("floor"), "{m}");
        let missing = dir.join("nope.toml");
        let m = Coefficients::load(&missing).unwrap_err().to_string();
        assert!(m.contains("nope.toml") && !m.contains('\n'), "{m}");
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn paper_table2_example_file_parses() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/coefficients-paper-table2.toml");
        let c = Coefficients::load(&path).unwrap();
        assert_eq!(c.model, Model::Paper);
        assert_eq!(c.part("lbm"), [9.99e-6, 1.57e-4, -8.23e-2]);
        assert_eq!(c.part("bh"), [6.65e-6, 7.06e-4, -1.09e-1]);
        assert_eq!(c.part("coup1"), [3.08e-6, 2.42e-7, 1.41e-2, 2.78e-2, -1.40e-1]);
        assert_eq!(c.part("coup2"), [5.99e-6, 3.90e-6, -8.80e-3, 2.51e-2, -1.30e-1]);
        assert_eq!(c.part("rb"), [1.16e-6, 9.62e-4, 2.75e-4, 1.48e-3, 1.88e-2]);
        assert!(c.provenance.machine.contains("SuperMUC"));
        assert!(c.provenance.note.contains("NOT"));
    }
}
