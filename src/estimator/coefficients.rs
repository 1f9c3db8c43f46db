//! The coefficients of eqs. (10)–(14), their evaluation (eq. 15) and the `coefficients.toml` format.
//!
//! Layout of the file (every key required except `provenance.fit_quality`; unknown keys are errors):
//!
//! ```toml
//! floor = 0.0                 # lower bound of every predicted part (seconds), ≥ 0
//!
//! [provenance]
//! machine = "..."             # where the timings were measured
//! date = "..."
//! commit = "..."              # blockflow commit that was timed
//! scenes = ["..."]            # calibration scenes / runs
//! samples = 0                 # number of samples fitted
//! note = "..."
//!
//! [provenance.fit_quality]    # optional: name = number, e.g. median_tot, mad_tot, share_within_10pct
//!
//! [lbm]    # eq. (10): WL_LBM   = a1·C + a2·F + a3
//! a1 = ...
//! a2 = ...
//! a3 = ...
//! [bh]     # eq. (11): WL_BH    = a1·C + a2·NB + a3
//! [coup1]  # eq. (12): WL_Coup1 = a1·C + a2·F + a3·P_L + a4·P_S + a5
//! [coup2]  # eq. (13): WL_Coup2 = a1·C + a2·F + a3·P_L + a4·P_S + a5
//! [rb]     # eq. (14): WL_RB    = S·(a1·(P_L+P_S)² + a2·P_L + a3·P_S + a4·K + a5)
//! ```
//!
//! A table with the wrong number of coefficients shows up as a missing key (`lbm: missing field `a3``)
//! or an unknown one (`lbm.a4`); both are errors. [`Coefficients::to_toml`] writes every number in the
//! shortest form that reads back to the same bits, so `parse(to_toml(c)) == c` bitwise.

use std::collections::BTreeMap;
use std::path::Path;

use serde::Deserialize;

use super::{row_bh, row_coup, row_lbm, row_rb, PartTimes, Quantities};
use crate::error::{Error, Result};

/// `configs/coefficients.toml` as it was when this binary was built: the coefficients a run uses when
/// `balance.coefficients` is the default path and the working folder has no such file.
pub const BUILT_IN_COEFFICIENTS: &str = include_str!("../../configs/coefficients.toml");

/// Where a set of coefficients came from (section 3.5: coefficients are valid only for the machine,
/// implementation and algorithms they were measured with).
#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
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
    /// Fit quality measures (section 3.4), e.g. `median_tot`, `mad_tot`, `share_within_10pct`.
    #[serde(default)]
    pub fit_quality: BTreeMap<String, f64>,
    /// Free text.
    pub note: String,
}

/// Coefficients of eqs. (10)–(14) plus provenance. Index `i` of each array is the paper's a_{i+1,X}.
#[derive(Clone, Debug, PartialEq)]
pub struct Coefficients {
    /// Eq. (10): WL_LBM = a1·C + a2·F + a3.
    pub lbm: [f64; 3],
    /// Eq. (11): WL_BH = a1·C + a2·NB + a3.
    pub bh: [f64; 3],
    /// Eq. (12): WL_Coup1 = a1·C + a2·F + a3·P_L + a4·P_S + a5.
    pub coup1: [f64; 5],
    /// Eq. (13): WL_Coup2 = a1·C + a2·F + a3·P_L + a4·P_S + a5.
    pub coup2: [f64; 5],
    /// Eq. (14): WL_RB = S·(a1·(P_L+P_S)² + a2·P_L + a3·P_S + a4·K + a5).
    pub rb: [f64; 5],
    /// Lower bound (≥ 0) of every predicted part; see [`Coefficients::predict`].
    pub floor: f64,
    /// Where the coefficients came from.
    pub provenance: Provenance,
}

fn dot<const N: usize>(a: &[f64; N], r: &[f64; N]) -> f64 {
    a.iter().zip(r).map(|(a, r)| a * r).sum()
}

impl Coefficients {
    /// Eqs. (10)–(14): predicted seconds per part for a block with quantities `q`, each part clamped
    /// below at [`floor`](Coefficients::floor).
    ///
    /// Why the floor: least squares puts no sign constraint on the coefficients and the intercepts come
    /// out negative (Table 2: a3,LBM, a3,BH, a5,Coup1, a5,Coup2 < 0), so blocks with few fluid cells, no
    /// boundary cells or no particles, above all empty blocks, get negative predictions. A negative weight
    /// is no workload and breaks the partitioners (prefix sums of weights must not decrease), so each part
    /// is at least `floor` ≥ 0.
    pub fn predict(&self, q: &Quantities) -> PartTimes {
        let fl = |x: f64| x.max(self.floor);
        PartTimes {
            lbm: fl(dot(&self.lbm, &row_lbm(q))),
            bh: fl(dot(&self.bh, &row_bh(q))),
            coup1: fl(dot(&self.coup1, &row_coup(q))),
            coup2: fl(dot(&self.coup2, &row_coup(q))),
            rb: fl(dot(&self.rb, &row_rb(q))),
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

    /// Parses coefficients text (named `origin` in messages) and checks it: every coefficient, the floor
    /// and every fit-quality number finite, the floor ≥ 0.
    pub fn parse(text: &str, origin: &str) -> Result<Self> {
        let table = crate::config::parse_table(text, origin)?;
        let file: File = serde_path_to_error::deserialize(toml::Value::Table(table)).map_err(|e| {
            let path = e.path().to_string();
            let key = if path == "." {
                String::new()
            } else {
                format!("{path}: ")
            };
            Error::Config(format!("{origin}: {key}{}", one_line(&e.inner().to_string())))
        })?;
        let c = Coefficients {
            lbm: [file.lbm.a1, file.lbm.a2, file.lbm.a3],
            bh: [file.bh.a1, file.bh.a2, file.bh.a3],
            coup1: file.coup1.array(),
            coup2: file.coup2.array(),
            rb: file.rb.array(),
            floor: file.floor,
            provenance: file.provenance,
        };
        c.check().map_err(|m| Error::Config(format!("{origin}: {m}")))?;
        Ok(c)
    }

    /// Finite coefficients, finite non-negative floor, finite fit-quality numbers.
    fn check(&self) -> std::result::Result<(), String> {
        let parts: [(&str, &[f64]); 5] = [
            ("lbm", &self.lbm),
            ("bh", &self.bh),
            ("coup1", &self.coup1),
            ("coup2", &self.coup2),
            ("rb", &self.rb),
        ];
        for (name, a) in parts {
            for (i, v) in a.iter().enumerate() {
                if !v.is_finite() {
                    return Err(format!("{name}.a{} = {v}: must be a finite number", i + 1));
                }
            }
        }
        if !self.floor.is_finite() || self.floor < 0.0 {
            return Err(format!("floor = {}: must be a finite number ≥ 0", self.floor));
        }
        for (k, v) in &self.provenance.fit_quality {
            if !v.is_finite() {
                return Err(format!("provenance.fit_quality.{k} = {v}: must be a finite number"));
            }
        }
        Ok(())
    }

    /// Writes the coefficients file (layout in the module documentation), with a comment per table
    /// naming the quantity each coefficient multiplies. Numbers are written in the shortest form that
    /// reads back to the same bits.
    pub fn to_toml(&self) -> String {
        let p = &self.provenance;
        let mut s = String::new();
        s.push_str(
            "# Workload estimator coefficients, eqs. (10)-(14) of Rettinger & Ruede (2019); seconds per block\n",
        );
        s.push_str("# and step. Valid only for the machine and code named in [provenance] (section 3.5).\n\n");
        s.push_str(
            "# Lower bound of every predicted part (least squares may predict negative times for empty blocks).\n",
        );
        s.push_str(&format!("floor = {}\n\n", num(self.floor)));
        s.push_str("[provenance]\n");
        s.push_str(&format!("machine = {}\n", quote(&p.machine)));
        s.push_str(&format!("date = {}\n", quote(&p.date)));
        s.push_str(&format!("commit = {}\n", quote(&p.commit)));
        let scenes: Vec<String> = p.scenes.iter().map(|x| quote(x)).collect();
        s.push_str(&format!("scenes = [{}]\n", scenes.join(", ")));
        s.push_str(&format!("samples = {}\n", p.samples));
        s.push_str(&format!("note = {}\n\n", quote(&p.note)));
        s.push_str("[provenance.fit_quality]\n");
        for (k, v) in &p.fit_quality {
            s.push_str(&format!("{} = {}\n", quote(k), num(*v)));
        }
        let tables: [(&str, &str, &[f64]); 5] = [
            ("lbm", "eq. (10): WL_LBM = a1*C + a2*F + a3", &self.lbm),
            ("bh", "eq. (11): WL_BH = a1*C + a2*NB + a3", &self.bh),
            (
                "coup1",
                "eq. (12): WL_Coup1 = a1*C + a2*F + a3*PL + a4*PS + a5",
                &self.coup1,
            ),
            (
                "coup2",
                "eq. (13): WL_Coup2 = a1*C + a2*F + a3*PL + a4*PS + a5",
                &self.coup2,
            ),
            (
                "rb",
                "eq. (14): WL_RB = S*(a1*(PL+PS)^2 + a2*PL + a3*PS + a4*K + a5)",
                &self.rb,
            ),
        ];
        for (name, comment, a) in tables {
            s.push_str(&format!("\n# {comment}\n[{name}]\n"));
            for (i, v) in a.iter().enumerate() {
                s.push_str(&format!("a{} = {}\n", i + 1, num(*v)));
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

/// The file as read: named coefficients per part.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    floor: f64,
    provenance: Provenance,
    lbm: Three,
    bh: Three,
    coup1: Five,
    coup2: Five,
    rb: Five,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Three {
    a1: f64,
    a2: f64,
    a3: f64,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Five {
    a1: f64,
    a2: f64,
    a3: f64,
    a4: f64,
    a5: f64,
}

impl Five {
    fn array(&self) -> [f64; 5] {
        [self.a1, self.a2, self.a3, self.a4, self.a5]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn example() -> Coefficients {
        let mut fq = BTreeMap::new();
        fq.insert("median_tot".to_string(), -1.234_567_890_123_456_7e-3);
        fq.insert("share within \"10%\"".to_string(), 0.871);
        Coefficients {
            lbm: [9.99e-6, 1.57e-4, -8.23e-2],
            bh: [6.65e-6, 7.06e-4, -0.1 - 0.2],
            coup1: [3.08e-6, 2.42e-7, 1.41e-2, 2.78e-2, -1.40e-1],
            coup2: [1.0 / 3.0, f64::MIN_POSITIVE, -0.0, 1e300, 5e-324],
            rb: [1.16e-6, 9.62e-4, 2.75e-4, 1.48e-3, std::f64::consts::PI],
            floor: 1e-9,
            provenance: Provenance {
                machine: "test box\twith \\ tabs".into(),
                date: "2025-01-01".into(),
                commit: "abc123".into(),
                scenes: vec!["bs24-d10".into(), "ünïcode \"quoted\"\n".into()],
                samples: 1_300_000,
                fit_quality: fq,
                note: String::new(),
            },
        }
    }

    fn bits(c: &Coefficients) -> Vec<u64> {
        let mut v: Vec<f64> = Vec::new();
        v.extend(c.lbm);
        v.extend(c.bh);
        v.extend(c.coup1);
        v.extend(c.coup2);
        v.extend(c.rb);
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
        assert!(back.coup2[2].is_sign_negative());
    }

    #[test]
    fn predict_applies_eqs_10_to_14_and_clamps_at_the_floor() {
        let mut c = example();
        c.coup2 = [1e-6, 2e-6, 3e-3, 4e-3, 5e-3];
        c.rb = [1e-6, 2e-4, 3e-4, 4e-4, 5e-3];
        c.floor = 0.0;
        let q = Quantities {
            c: 32768.0,
            f: 20000.0,
            nb: 3000.0,
            pl: 3.0,
            ps: 4.0,
            k: 5.0,
            s: 10.0,
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
        let m = err(&good.replacen("a3 = -8.23e-2\n", "", 1));
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
        assert_eq!(c.lbm, [9.99e-6, 1.57e-4, -8.23e-2]);
        assert_eq!(c.bh, [6.65e-6, 7.06e-4, -1.09e-1]);
        assert_eq!(c.coup1, [3.08e-6, 2.42e-7, 1.41e-2, 2.78e-2, -1.40e-1]);
        assert_eq!(c.coup2, [5.99e-6, 3.90e-6, -8.80e-3, 2.51e-2, -1.30e-1]);
        assert_eq!(c.rb, [1.16e-6, 9.62e-4, 2.75e-4, 1.48e-3, 1.88e-2]);
        assert!(c.provenance.machine.contains("SuperMUC"));
        assert!(c.provenance.note.contains("NOT"));
    }
}
