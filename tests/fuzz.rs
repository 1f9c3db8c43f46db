//! Config fuzzing: proptest strategies generate scene files and `--set` strings, valid
//! and invalid, and run the real binary on each. Every case must either run its few steps and exit 0 with
//! `"status": "ok"` in summary.json, or exit non-zero with one line on stderr (no panic, no backtrace, no
//! summary.json that says ok), within a time limit and without being killed by a signal (an abort on a
//! failed allocation under the memory cap counts as a failure: a huge domain must be refused with a
//! message).
//!
//! Run with `cargo test --release --test fuzz`. The CI test runs `FUZZ_CI_CASES` cases from a fixed seed;
//! the ignored `fuzz_many` runs `BLOCKFLOW_FUZZ_CASES` (default 10 000), optionally from
//! `BLOCKFLOW_FUZZ_SEED`. Cases run on `BLOCKFLOW_FUZZ_THREADS` threads (default 2). Proptest generates
//! the inputs deterministically; there is no shrinking (each case is a process with a 30 s limit,
//! `BLOCKFLOW_FUZZ_SECONDS` to change it): every failing case is printed with the command line that
//! reproduces it. `BLOCKFLOW_FUZZ_BIN` points the cases at another binary (a debug build, whose overflow
//! checks find more; give it `BLOCKFLOW_FUZZ_SECONDS=300`).

use proptest::prelude::*;
use proptest::strategy::{Strategy, ValueTree};
use proptest::test_runner::{Config as ProptestConfig, RngAlgorithm, TestRng, TestRunner};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// Cases of the CI test.
const FUZZ_CI_CASES: usize = 500;
/// Seed of the CI test (any fixed 32 bytes).
const FUZZ_SEED: [u8; 32] = *b"blockflow config fuzzing, seed 1";
/// A case still running after this long is a hang (`BLOCKFLOW_FUZZ_SECONDS` overrides): the largest
/// domains the memory cap admits take a few seconds in a release build and about ten times as long in
/// a debug build, which therefore needs a longer limit.
const TIME_LIMIT: Duration = Duration::from_secs(30);

fn time_limit() -> Duration {
    std::env::var("BLOCKFLOW_FUZZ_SECONDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .map(Duration::from_secs)
        .unwrap_or(TIME_LIMIT)
}
/// Address-space cap of each run (KiB; `BLOCKFLOW_FUZZ_MEMORY_KIB` overrides): an allocation past it
/// aborts the run, which the check reports, instead of exhausting the machine.
const MEMORY_CAP_KIB: u64 = 6 * 1024 * 1024;

fn memory_cap_kib() -> u64 {
    std::env::var("BLOCKFLOW_FUZZ_MEMORY_KIB")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(MEMORY_CAP_KIB)
}

// ---------------------------------------------------------------------------------------------------------
// What a case is

/// The scene argument of a case.
#[derive(Clone, Debug)]
enum Source {
    /// A file of `configs/`.
    Config(&'static str),
    /// Text written to `scene.toml` in the case's folder (mutated or truncated configs).
    Text(String),
    /// Bytes written to `scene.toml` (empty files, binary garbage).
    Bytes(Vec<u8>),
    /// A path that does not exist.
    Missing,
}

/// One run: the scene and the arguments after it (`--out` is added by the runner).
#[derive(Clone, Debug)]
struct Case {
    source: Source,
    args: Vec<String>,
}

/// The scene files and their kinds (`None`: not a scene file).
const CONFIGS: [(&str, Option<&str>); 17] = [
    ("box.toml", Some("box")),
    ("calibration.toml", Some("calibration")),
    ("cavity.toml", Some("cavity")),
    ("channel.toml", Some("channel")),
    ("collision.toml", Some("collision")),
    ("couette.toml", Some("couette")),
    ("drag_array.toml", Some("drag_array")),
    ("granular_box.toml", Some("granular_box")),
    ("hopper-small.toml", Some("hopper")),
    ("hopper.toml", Some("hopper")),
    ("incline.toml", Some("incline")),
    ("settling_sphere.toml", Some("settling_sphere")),
    ("taylor_green.toml", Some("taylor_green")),
    ("channel.toml", Some("channel")),
    ("box.toml", Some("box")),
    ("coefficients.toml", None),
    ("coefficients-paper-table2.toml", None),
];

/// Value shapes of the keys.
#[derive(Clone, Copy, Debug)]
enum Ty {
    /// A float whose sensible values lie in [lo, hi].
    F(f64, f64),
    /// An unsigned integer whose sensible values lie in [lo, hi].
    U(u64, u64),
    /// Three unsigned integers, sensible in [lo, hi].
    U3(u64, u64),
    /// Three floats, sensible in [lo, hi].
    F3(f64, f64),
    /// Three booleans.
    B3,
    /// A boolean.
    B,
    /// One of the names (misspelled ones are generated too).
    E(&'static [&'static str]),
    /// A path.
    Path,
    /// `processes.pin`.
    Pin,
    /// `scene.spheres` of the box scene.
    Spheres,
    /// `scene.planes` of the box scene.
    Planes,
}

use Ty::*;

const GENERIC: &[(&str, Ty)] = &[
    ("fluid.tau", F(0.5, 2.0)),
    ("fluid.magic", F(0.01, 1.0)),
    ("fluid.precision", E(&["f64", "f32"])),
    ("fluid.velocity_limit", F(0.0, 1.0)),
    ("fluid.kernel", E(&["fused", "split"])),
    ("fluid.enabled", B),
    ("domain.blocks", U3(1, 4)),
    ("domain.block_size", U3(1, 24)),
    ("domain.periodic", B3),
    ("run.series_every", U(1, 3)),
    ("run.vtk_every", U(1, 3)),
    ("run.out", Path),
    ("processes.count", U(1, 4)),
    ("processes.threads_per_process", U(1, 2)),
    ("processes.steps_per_graph", U(1, 8)),
    ("processes.pin", Pin),
    ("processes.steal", E(&["process", "global"])),
    (
        "balance.strategy",
        E(&["none", "hilbert", "morton", "diffusive", "metis"]),
    ),
    ("balance.interval", U(1, 3)),
    ("balance.weights", E(&["cells", "estimator", "measured", "corrected"])),
    ("balance.forecast", B),
    ("balance.coefficients", Path),
    ("balance.split", E(&["greedy", "optimal"])),
    ("balance.flow_iterations", U(1, 30)),
    ("balance.diffusive_iterations", U(1, 30)),
    ("balance.diffusive_mode", E(&["push", "pull"])),
    ("balance.metis_imbalance", F(1.0, 3.0)),
    ("balance.latency", F(0.0, 1e-3)),
    ("balance.bandwidth", F(1e3, 1e11)),
    ("particles.subcycles", U(1, 20)),
    ("particles.restitution", F(0.0, 1.0)),
    ("particles.friction", F(0.0, 2.0)),
    ("particles.iterations", U(1, 50)),
    ("particles.relaxation", F(0.0, 2.0)),
    ("particles.grid_threshold", U(0, 100)),
    ("particles.contact_margin", F(0.0, 1.0)),
    ("particles.position_correction", F(0.0, 1.0)),
    ("particles.restitution_threshold", F(0.0, 0.01)),
    ("particles.gravity", F3(-0.01, 0.01)),
    ("particles.dt", F(0.1, 2.0)),
    ("particles.boundary", E(&["cli", "sbb"])),
    ("particles.force_averaging", B),
];

/// `[scene]` keys per kind (`kind` itself is generated separately).
fn scene_keys(kind: &str) -> &'static [(&'static str, Ty)] {
    match kind {
        "channel" | "couette" => &[
            ("resolution", U(2, 48)),
            ("reynolds", F(0.0, 100.0)),
            ("length", U(1, 16)),
            ("width", U(1, 16)),
        ],
        "taylor_green" => &[
            ("resolution", U(4, 40)),
            ("reynolds", F(0.0, 100.0)),
            ("time", F(0.0, 2.0)),
            ("depth", U(1, 40)),
        ],
        "cavity" => &[
            ("resolution", U(4, 40)),
            ("reynolds", F(0.0, 1000.0)),
            ("lid_velocity", F(0.0, 0.4)),
            ("turnovers", F(0.0, 20.0)),
        ],
        "box" => &[
            ("force", F3(-1e-4, 1e-4)),
            ("velocity", F3(-0.4, 0.4)),
            ("planes", Planes),
            ("spheres", Spheres),
            ("gravity", F3(-1e-3, 1e-3)),
            ("steps", U(0, 5)),
        ],
        "granular_box" => &[
            ("count", U(0, 600)),
            ("diameter", F(0.0, 10.0)),
            ("size", U3(4, 64)),
            ("fill_from", F(0.0, 40.0)),
            ("density", F(0.0, 5.0)),
            ("initial_speed", F(0.0, 0.5)),
            ("seed", U(0, 1000)),
            ("steps", U(0, 5)),
        ],
        "incline" => &[
            ("angle_deg", F(0.0, 60.0)),
            ("diameter", F(0.0, 8.0)),
            ("steps", U(0, 5)),
        ],
        "collision" => &[
            ("diameter", F(0.0, 8.0)),
            ("speed", F(0.0, 0.5)),
            ("impact_parameter", F(0.0, 1.0)),
            ("steps", U(0, 5)),
        ],
        "drag_array" => &[
            ("resolution", F(2.0, 24.0)),
            ("solid_fraction", F(0.0, 0.5)),
            ("reynolds", F(0.0, 10.0)),
            ("steps", U(0, 5)),
        ],
        "settling_sphere" => &[
            ("resolution", F(3.0, 10.0)),
            ("case", E(&["E1", "E2", "E3", "E4"])),
            ("fluid_density", F(0.0, 2000.0)),
            ("fluid_viscosity", F(0.0, 1.0)),
            ("particle_density", F(0.0, 3000.0)),
            ("density_ratio", F(1.0, 5.0)),
            ("diameter", F(0.0, 0.05)),
            ("box", F3(0.0, 0.3)),
            ("start_height", F(0.0, 0.2)),
            ("gravity", F(0.0, 20.0)),
            ("galileo", F(0.0, 500.0)),
            ("mach", F(0.0, 0.5)),
            ("duration", F(0.0, 2.0)),
        ],
        "hopper" => &[
            ("diameter", F(3.0, 10.0)),
            ("count", U(0, 600)),
            ("galileo", F(0.0, 500.0)),
            ("density_ratio", F(1.0, 5.0)),
            ("narrowing", F(0.0, 0.9)),
            ("funnel_height", F(0.05, 0.8)),
            ("seed", U(0, 1000)),
            ("steps", U(0, 5)),
        ],
        "calibration" => &[
            ("diameter", F(3.0, 12.0)),
            ("solid_fraction", F(0.0, 0.3)),
            ("galileo", F(0.0, 500.0)),
            ("density_ratio", F(1.0, 5.0)),
            ("top_offset", F(0.0, 2.0)),
            ("settling_speed", F(0.0, 0.1)),
            ("duration", F(0.0, 5.0)),
            ("seed", U(0, 1000)),
        ],
        _ => &[],
    }
}

const KINDS: [&str; 12] = [
    "channel",
    "couette",
    "taylor_green",
    "cavity",
    "box",
    "granular_box",
    "incline",
    "collision",
    "drag_array",
    "settling_sphere",
    "hopper",
    "calibration",
];

// ---------------------------------------------------------------------------------------------------------
// Strategies

/// Floats: sensible values, values at and past the bounds, non-finite values, wrong types.
fn float_value(lo: f64, hi: f64) -> BoxedStrategy<String> {
    let edges: &'static [&'static str] = &[
        "0",
        "-0.0",
        "0.5",
        "0.5000001",
        "0.4999999",
        "0.50000000000001",
        "1",
        "2",
        "-1",
        "1e-300",
        "5e-324",
        "1e300",
        "1.7976931348623157e308",
        "-1e300",
        "1e6",
        "1e9",
        "0.3",
        "0.9",
        "3",
        "60",
        "60.000001",
        "500",
        "500.1",
        "256",
        "256.5",
    ];
    let special: &'static [&'static str] = &[
        "nan", "inf", "-inf", "+inf", "-nan", "\"nan\"", "NaN", "Infinity", "\"0.7\"", "true", "[0.7]", "{x = 1}", "",
        "0.7.1", "1_000.5", "0x10", "1e", "'single'", "\"\"",
    ];
    prop_oneof![
        6 => (lo..=hi).prop_map(|v| format!("{v}")),
        2 => ((lo - (hi - lo) * 0.2)..=(hi + (hi - lo) * 0.2)).prop_map(|v| format!("{v}")),
        3 => prop::sample::select(edges).prop_map(str::to_string),
        1 => Just(format!("{lo}")),
        1 => Just(format!("{hi}")),
        2 => prop::sample::select(special).prop_map(str::to_string),
    ]
    .boxed()
}

/// Unsigned integers: sensible values, 0, negative, huge, overflowing, fractional, wrong types.
fn uint_value(lo: u64, hi: u64) -> BoxedStrategy<String> {
    let edges: &'static [&'static str] = &[
        "0",
        "1",
        "2",
        "3",
        "7",
        "-1",
        "-9223372036854775808",
        "9223372036854775807",
        "18446744073709551615",
        "99999999999999999999999",
        "4096",
        "4097",
        "65536",
        "1000000",
        "4294967296",
        "2.5",
        "1e3",
        "\"8\"",
        "true",
        "[1]",
        "",
        "0x10",
        "1_0",
    ];
    prop_oneof![
        8 => (lo..=hi).prop_map(|v| v.to_string()),
        3 => prop::sample::select(edges).prop_map(str::to_string),
        1 => (0u64..u64::MAX).prop_map(|v| v.to_string()),
    ]
    .boxed()
}

fn list3(elem: BoxedStrategy<String>) -> BoxedStrategy<String> {
    prop_oneof![
        10 => prop::array::uniform3(elem.clone()).prop_map(|[a, b, c]| format!("[{a}, {b}, {c}]")),
        1 => prop::collection::vec(elem, 0..6).prop_map(|v| format!("[{}]", v.join(","))),
        1 => Just("3".to_string()),
        1 => Just("\"[1,1,1]\"".to_string()),
    ]
    .boxed()
}

/// Three unsigned integers: mostly sensible, some odd splits and some huge ones.
fn uint3_value(lo: u64, hi: u64) -> BoxedStrategy<String> {
    let elem = prop_oneof![
        12 => (lo..=hi).prop_map(|v| v.to_string()),
        2 => prop::sample::select(&["1", "3", "5", "7", "11", "13"][..]).prop_map(str::to_string),
        1 => prop::sample::select(&["0", "-1", "1000", "100000", "4294967296", "9223372036854775807", "1.5", "\"2\""][..])
            .prop_map(str::to_string),
    ]
    .boxed();
    list3(elem)
}

fn float3_value(lo: f64, hi: f64) -> BoxedStrategy<String> {
    let elem = prop_oneof![
        12 => (lo..=hi).prop_map(|v| format!("{v}")),
        1 => prop::sample::select(&["0", "nan", "inf", "-inf", "1e300", "-1e300", "\"x\""][..]).prop_map(str::to_string),
    ]
    .boxed();
    list3(elem)
}

fn bool_value() -> BoxedStrategy<String> {
    prop_oneof![
        6 => prop::bool::ANY.prop_map(|b| b.to_string()),
        1 => prop::sample::select(&["1", "\"true\"", "yes", "True", ""][..]).prop_map(str::to_string),
    ]
    .boxed()
}

/// A name, as a TOML string or bare (bare names become strings), misspelled or of another case.
fn enum_value(names: &'static [&'static str]) -> BoxedStrategy<String> {
    prop_oneof![
        6 => prop::sample::select(names).prop_map(|n| format!("\"{n}\"")),
        3 => prop::sample::select(names).prop_map(str::to_string),
        2 => (prop::sample::select(names), mutation()).prop_map(|(n, m)| m.apply(n)),
        1 => prop::sample::select(names).prop_map(|n| n.to_uppercase()),
        1 => prop::sample::select(&["1", "[\"none\"]", "\"\"", "true"][..]).prop_map(str::to_string),
    ]
    .boxed()
}

fn path_value() -> BoxedStrategy<String> {
    prop::sample::select(
        &[
            "\"/nonexistent/dir/x\"",
            "\"configs/coefficients.toml\"",
            "\"configs/coefficients-paper-table2.toml\"",
            "\"configs/channel.toml\"",
            "\"/dev/null\"",
            "\"\"",
            "\"/\"",
            "/proc/self/mem",
            "42",
        ][..],
    )
    .prop_map(str::to_string)
    .boxed()
}

fn pin_value() -> BoxedStrategy<String> {
    prop::sample::select(
        &[
            "\"none\"",
            "none",
            "compact",
            "scatter",
            "\"0\"",
            "\"0,1\"",
            "\"0-1\"",
            "[0]",
            "[0, 1]",
            "[1, 0]",
            "[]",
            "[0, 0]",
            "\"1-0\"",
            "\"0,,1\"",
            "[99999]",
            "\"9999999999999999999\"",
            "[-1]",
            "\"all\"",
            "1",
        ][..],
    )
    .prop_map(str::to_string)
    .boxed()
}

/// `scene.spheres` of the box scene: inside, overlapping the walls or each other, outside, degenerate.
fn spheres_value() -> BoxedStrategy<String> {
    let coord = prop_oneof![
        8 => -4.0f64..40.0,
        1 => prop::sample::select(&[0.0, 16.0, 32.0, -0.0, 1e9, -1e9][..]),
    ];
    let radius = prop_oneof![
        8 => 0.5f64..6.0,
        1 => prop::sample::select(&[0.0, -1.0, 1e-9, 20.0, 1e6][..]),
    ];
    let vel = prop_oneof![6 => -0.05f64..0.05, 1 => prop::sample::select(&[0.0, 0.5, 10.0, -3.0][..])];
    let sphere = (
        prop::array::uniform3(coord),
        radius,
        prop_oneof![4 => 0.5f64..4.0, 1 => prop::sample::select(&[0.0, -1.0, 1e-12, 1e12][..])],
        prop::array::uniform3(vel),
        prop::bool::weighted(0.3),
        prop::bool::weighted(0.05),
    )
        .prop_map(|(c, r, d, v, fixed, extra)| {
            let extra = if extra { ", colour = 1" } else { "" };
            format!(
                "{{ centre = [{}, {}, {}], radius = {r}, density = {d}, velocity = [{}, {}, {}], fixed = {fixed}{extra} }}",
                c[0], c[1], c[2], v[0], v[1], v[2]
            )
        });
    prop_oneof![
        8 => prop::collection::vec(sphere.clone(), 0..5).prop_map(|v| format!("[{}]", v.join(", "))),
        // the same sphere many times: bodies overlapping each other completely
        1 => (sphere, 2usize..60).prop_map(|(s, n)| format!("[{}]", vec![s; n].join(", "))),
        1 => Just("[{ centre = [8, 8, 8] }]".to_string()),
        1 => Just("{ centre = [8, 8, 8], radius = 2 }".to_string()),
    ]
    .boxed()
}

fn planes_value() -> BoxedStrategy<String> {
    let plane = (
        prop::array::uniform3(prop_oneof![6 => -4.0f64..36.0, 1 => prop::sample::select(&[0.0, 1e300, 100.0][..])]),
        prop::array::uniform3(prop_oneof![6 => -1.0f64..1.0, 2 => Just(0.0), 1 => Just(1e-300)]),
    )
        .prop_map(|(p, n)| {
            format!(
                "{{ point = [{}, {}, {}], normal = [{}, {}, {}] }}",
                p[0], p[1], p[2], n[0], n[1], n[2]
            )
        });
    prop::collection::vec(plane, 0..4)
        .prop_map(|v| format!("[{}]", v.join(", ")))
        .boxed()
}

fn value_of(ty: Ty) -> BoxedStrategy<String> {
    match ty {
        F(lo, hi) => float_value(lo, hi),
        U(lo, hi) => uint_value(lo, hi),
        U3(lo, hi) => uint3_value(lo, hi),
        F3(lo, hi) => float3_value(lo, hi),
        B3 => list3(bool_value()),
        B => bool_value(),
        E(names) => enum_value(names),
        Path => path_value(),
        Pin => pin_value(),
        Spheres => spheres_value(),
        Planes => planes_value(),
    }
}

/// A typo of a key: a character dropped, doubled, swapped, replaced or appended, or the case changed.
#[derive(Clone, Debug)]
struct Mutation {
    kind: u8,
    at: usize,
    ch: char,
}

fn mutation() -> impl Strategy<Value = Mutation> {
    (
        0u8..6,
        any::<usize>(),
        prop::sample::select(&['a', 'e', 's', '_', '-', '.', ' ', 'é', 'x'][..]),
    )
        .prop_map(|(kind, at, ch)| Mutation { kind, at, ch })
}

impl Mutation {
    fn apply(&self, s: &str) -> String {
        let mut c: Vec<char> = s.chars().collect();
        if c.is_empty() {
            return self.ch.to_string();
        }
        let i = self.at % c.len();
        match self.kind {
            0 => {
                c.remove(i);
            }
            1 => c.insert(i, c[i]),
            2 if c.len() > 1 => {
                let n = c.len();
                c.swap(i, (i + 1) % n)
            }
            3 => c[i] = self.ch,
            4 => c.push(self.ch),
            _ => return s.to_uppercase(),
        }
        let out: String = c.into_iter().collect();
        if out == s {
            format!("{s}x")
        } else {
            out
        }
    }
}

/// All known keys of a scene file of `kind` with their shapes.
fn keys_of(kind: Option<&'static str>) -> Vec<(String, Ty)> {
    let mut keys: Vec<(String, Ty)> = GENERIC.iter().map(|(k, t)| (k.to_string(), *t)).collect();
    if let Some(kind) = kind {
        for (k, t) in scene_keys(kind) {
            keys.push((format!("scene.{k}"), *t));
        }
    }
    keys
}

/// One `--set` string for a file of `kind`.
fn set_string(kind: Option<&'static str>) -> BoxedStrategy<String> {
    let keys = keys_of(kind);
    let scene: Vec<(String, Ty)> = keys.iter().filter(|(k, _)| k.starts_with("scene.")).cloned().collect();
    let known =
        prop::sample::select(keys.clone()).prop_flat_map(|(k, t)| value_of(t).prop_map(move |v| format!("{k}={v}")));
    // scene keys get extra weight: they hold the bodies and the domain extent
    let scene_key = if scene.is_empty() {
        known.clone().boxed()
    } else {
        prop::sample::select(scene)
            .prop_flat_map(|(k, t)| value_of(t).prop_map(move |v| format!("{k}={v}")))
            .boxed()
    };
    let misspelled = (prop::sample::select(keys.clone()), mutation())
        .prop_flat_map(|((k, t), m)| value_of(t).prop_map(move |v| format!("{}={v}", m.apply(&k))));
    let kind_change = prop::sample::select(&KINDS[..]).prop_map(|k| format!("scene.kind={k}"));
    let odd = prop::sample::select(
        &[
            "",
            "=",
            "novalue",
            "=1",
            ".=1",
            "fluid..tau=0.7",
            "fluid.=0.7",
            " fluid.tau = 0.7 ",
            "fluid.tau==0.7",
            "fluid.tau=0.7=0.8",
            "fluid.tau.x=1",
            "fluid=1",
            "fluid=\"x\"",
            "scene=1",
            "scene={}",
            "scene.kind=1",
            "scene.kind=\"\"",
            "domain.blocks.x=1",
            "fluids.tau=0.7",
            "particle.subcycles=3",
            "run.stesp=2",
            "fluid.tau=[0.7",
            "fluid.tau=\"unterminated",
            "flüid.tau=0.7",
            "fluid.tau=0.7\n[scene]\nkind=\"box\"",
            "scene.kind=channel\u{7f}",
            "\u{feff}fluid.tau=0.7",
            "processes.pin.x=1",
            "balance={strategy=\"metis\"}",
            "domain={blocks=[1,1,1]}",
            "run.steps=3",
        ][..],
    )
    .prop_map(str::to_string);
    prop_oneof![
        6 => known,
        4 => scene_key,
        1 => misspelled,
        1 => kind_change,
        1 => odd,
    ]
    .boxed()
}

/// Extra command-line flags (values mostly valid: the flags' own errors are clap's).
fn flags() -> BoxedStrategy<Vec<String>> {
    let flag = prop_oneof![
        12 => (1usize..=4).prop_map(|p| vec!["--processes".to_string(), p.to_string()]),
        8 => (1usize..=2).prop_map(|t| vec!["--threads-per-process".to_string(), t.to_string()]),
        8 => prop::sample::select(&["none", "hilbert", "morton", "diffusive", "metis", "hilbrt"][..])
            .prop_map(|b| vec!["--balance".to_string(), b.to_string()]),
        4 => (1u64..=3).prop_map(|i| vec!["--interval".to_string(), i.to_string()]),
        4 => prop::sample::select(&["none", "compact", "scatter", "0", "0,1"][..])
            .prop_map(|p| vec!["--pin".to_string(), p.to_string()]),
        1 => prop::sample::select(&["--processes", "--steps", "--interval", "--threads-per-process", "--vtk"][..])
            .prop_flat_map(|f| prop::sample::select(&["-1", "x", "1e3", "", "18446744073709551616", "0"][..])
                .prop_map(move |v| vec![f.to_string(), v.to_string()])),
        2 => Just(vec!["--vtk".to_string(), "1".to_string()]),
        1 => Just(vec!["--bogus-flag".to_string()]),
    ];
    prop::collection::vec(flag, 0..3).prop_map(|v| v.concat()).boxed()
}

/// How the step count is bounded: `--steps`, `run.steps` or (rarely) both.
fn steps() -> BoxedStrategy<Vec<String>> {
    prop_oneof![
        8 => Just(vec!["--steps".to_string(), "2".to_string()]),
        2 => (0u64..=4).prop_map(|n| vec!["--steps".to_string(), n.to_string()]),
        2 => (0u64..=3).prop_map(|n| vec!["--set".to_string(), format!("run.steps={n}")]),
    ]
    .boxed()
}

/// A case on a scene file of `configs/`.
fn config_case() -> impl Strategy<Value = Case> {
    prop::sample::select(&CONFIGS[..]).prop_flat_map(|(file, kind)| {
        (prop::collection::vec(set_string(kind), 0..4), steps(), flags()).prop_map(move |(sets, steps, flags)| {
            let mut args = Vec::new();
            for s in sets {
                args.push("--set".to_string());
                args.push(s);
            }
            args.extend(steps);
            args.extend(flags);
            Case {
                source: Source::Config(file),
                args,
            }
        })
    })
}

fn config_text(file: &str) -> String {
    std::fs::read_to_string(configs().join(file)).expect("config readable")
}

/// A case on a broken file: empty, garbage, truncated, lines dropped or doubled, a line replaced.
fn file_case() -> impl Strategy<Value = Case> {
    let scene_files: Vec<&'static str> = CONFIGS.iter().filter(|c| c.1.is_some()).map(|c| c.0).collect();
    let truncated = (prop::sample::select(scene_files.clone()), any::<prop::sample::Index>()).prop_map(|(f, i)| {
        let t = config_text(f).into_bytes();
        let n = i.index(t.len() + 1);
        Source::Bytes(t[..n].to_vec())
    });
    let lines = (
        prop::sample::select(scene_files.clone()),
        any::<prop::sample::Index>(),
        0u8..4,
    )
        .prop_map(|(f, i, op)| {
            let t = config_text(f);
            let mut lines: Vec<String> = t.lines().map(str::to_string).collect();
            let k = i.index(lines.len());
            match op {
                0 => {
                    lines.remove(k);
                }
                1 => {
                    let l = lines[k].clone();
                    lines.insert(k, l);
                }
                2 => lines[k] = lines[k].replace('=', "= = "),
                _ => lines[k] = lines[k].replace('"', ""),
            }
            Source::Text(lines.join("\n"))
        });
    let generated = (
        prop::sample::select(&KINDS[..]),
        prop::collection::vec(any::<prop::sample::Index>(), 0..4),
    )
        .prop_flat_map(|(kind, _)| {
            let keys: Vec<(String, Ty)> = scene_keys(kind).iter().map(|(k, t)| (k.to_string(), *t)).collect();
            let line =
                prop::sample::select(keys).prop_flat_map(|(k, t)| value_of(t).prop_map(move |v| format!("{k} = {v}")));
            prop::collection::vec(line, 0..4).prop_map(move |l| {
                Source::Text(format!(
                    "[run]\nsteps = 2\n\n[scene]\nkind = \"{kind}\"\n{}\n",
                    l.join("\n")
                ))
            })
        });
    let source = prop_oneof![
        1 => Just(Source::Bytes(Vec::new())),
        1 => Just(Source::Text("\n\n# only a comment\n".to_string())),
        1 => Just(Source::Missing),
        2 => prop::collection::vec(any::<u8>(), 1..300).prop_map(Source::Bytes),
        1 => "[ -~\n]{0,200}".prop_map(Source::Text),
        4 => truncated,
        3 => lines,
        4 => generated,
    ];
    (source, steps(), prop::collection::vec(set_string(None), 0..2)).prop_map(|(source, steps, sets)| {
        let mut args = steps;
        for s in sets {
            args.push("--set".to_string());
            args.push(s);
        }
        Case { source, args }
    })
}

fn case() -> impl Strategy<Value = Case> {
    prop_oneof![4 => config_case(), 1 => file_case()]
}

// ---------------------------------------------------------------------------------------------------------
// Running a case

fn configs() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("configs")
}

fn scratch() -> PathBuf {
    std::env::temp_dir().join(format!("blockflow-fuzz-{}", std::process::id()))
}

/// The binary under test: `BLOCKFLOW_FUZZ_BIN` (e.g. a debug build, whose overflow checks find more),
/// else this package's.
fn binary() -> String {
    std::env::var("BLOCKFLOW_FUZZ_BIN").unwrap_or_else(|_| env!("CARGO_BIN_EXE_blockflow").to_string())
}

/// What a case did.
#[derive(Debug)]
struct Outcome {
    code: Option<i32>,
    signal: Option<i32>,
    timed_out: bool,
    stderr: String,
    summary: Option<String>,
    seconds: f64,
}

fn run_case(case: &Case, dir: &Path) -> Outcome {
    let _ = std::fs::remove_dir_all(dir);
    std::fs::create_dir_all(dir).unwrap();
    let scene = match &case.source {
        Source::Config(f) => configs().join(f),
        Source::Text(t) => {
            let p = dir.join("scene.toml");
            std::fs::write(&p, t).unwrap();
            p
        }
        Source::Bytes(b) => {
            let p = dir.join("scene.toml");
            std::fs::write(&p, b).unwrap();
            p
        }
        Source::Missing => dir.join("missing.toml"),
    };
    let out = dir.join("out");
    let stderr_path = dir.join("stderr.txt");
    let start = Instant::now();
    // `ulimit -v` caps the address space: an allocation past it aborts the run instead of the machine.
    let mut child = Command::new("sh")
        .arg("-c")
        .arg(format!("ulimit -v {} && exec \"$0\" \"$@\"", memory_cap_kib()))
        .arg(binary())
        .arg("run")
        .arg(&scene)
        .args(&case.args)
        .arg("--out")
        .arg(&out)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .env_remove("RUST_BACKTRACE")
        .env_remove("RUST_LIB_BACKTRACE")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&stderr_path).unwrap())
        .spawn()
        .expect("sh runs");
    let mut timed_out = false;
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if start.elapsed() > time_limit() {
            timed_out = true;
            let _ = child.kill();
            break child.wait().unwrap();
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    use std::os::unix::process::ExitStatusExt;
    Outcome {
        code: status.code(),
        signal: status.signal(),
        timed_out,
        stderr: String::from_utf8_lossy(&std::fs::read(&stderr_path).unwrap_or_default()).to_string(),
        summary: std::fs::read_to_string(out.join("summary.json")).ok(),
        seconds: start.elapsed().as_secs_f64(),
    }
}

/// Why an outcome breaks the contract; `None` when it keeps it.
fn verdict(o: &Outcome) -> Option<String> {
    let err = o.stderr.trim_end();
    if o.timed_out {
        return Some(format!("no exit within {:?} (hang)", time_limit()));
    }
    if let Some(sig) = o.signal {
        return Some(format!("killed by signal {sig} (abort, crash or out of memory): {err}"));
    }
    let code = o.code.unwrap_or(-1);
    for bad in [
        "panicked",
        "RUST_BACKTRACE",
        "memory allocation of",
        "stack backtrace",
        "thread '",
    ] {
        if err.contains(bad) {
            return Some(format!("exit {code} with a panic/abort on stderr: {err}"));
        }
    }
    if code == 0 {
        return match &o.summary {
            Some(s) if s.contains("\"status\": \"ok\"") => None,
            Some(s) => Some(format!("exit 0 but summary.json does not say ok: {s}")),
            None => Some("exit 0 without summary.json".to_string()),
        };
    }
    if err.is_empty() {
        return Some(format!("exit {code} with nothing on stderr"));
    }
    if err.lines().count() != 1 {
        return Some(format!(
            "exit {code} with {} lines on stderr: {err}",
            err.lines().count()
        ));
    }
    if !err.starts_with("error: ") {
        return Some(format!("exit {code}, stderr does not start with \"error: \": {err}"));
    }
    if !matches!(code, 1..=3) {
        return Some(format!("exit {code} (expected 1, 2 or 3): {err}"));
    }
    if let Some(s) = &o.summary {
        if s.contains("\"status\": \"ok\"") {
            return Some(format!("exit {code} but summary.json says ok: {err}"));
        }
        if code != 3 {
            return Some(format!("exit {code} (not an unstable run) left a summary.json: {err}"));
        }
    }
    None
}

/// The command that reproduces a case (for the failure report).
fn describe(case: &Case) -> String {
    let scene = match &case.source {
        Source::Config(f) => format!("configs/{f}"),
        Source::Text(t) => format!("<scene.toml: {t:?}>"),
        Source::Bytes(b) => match std::str::from_utf8(b) {
            Ok(t) => format!("<scene.toml: {t:?}>"),
            Err(_) => format!("<scene.toml bytes: {b:?}>"),
        },
        Source::Missing => "<missing.toml>".to_string(),
    };
    let args: Vec<String> = case
        .args
        .iter()
        .map(|a| {
            if a.is_empty() || a.contains(|c: char| !(c.is_ascii_alphanumeric() || "-_.=,/".contains(c))) {
                format!("'{}'", a.replace('\'', "'\\''"))
            } else {
                a.clone()
            }
        })
        .collect();
    format!("blockflow run {scene} {}", args.join(" "))
}

/// Counts of what the cases did.
#[derive(Default, Debug)]
struct Tally {
    ok: usize,
    refused: usize,
    unstable: usize,
    usage: usize,
    failed: usize,
    slowest: f64,
    slowest_case: usize,
}

/// Generates `n` cases from `seed` and runs them on `threads` threads; panics listing every failure.
fn fuzz(n: usize, seed: [u8; 32], threads: usize) {
    let config = ProptestConfig {
        cases: n as u32,
        failure_persistence: None,
        rng_algorithm: RngAlgorithm::ChaCha,
        ..ProptestConfig::default()
    };
    let mut runner = TestRunner::new_with_rng(config, TestRng::from_seed(RngAlgorithm::ChaCha, &seed));
    let strategy = case();
    let cases: Vec<Case> = (0..n)
        .map(|_| strategy.new_tree(&mut runner).expect("case generated").current())
        .collect();
    let next = AtomicUsize::new(0);
    let failures = Mutex::new(Vec::new());
    let tally = Mutex::new(Tally::default());
    let root = scratch().join(format!("fuzz-{n}"));
    let start = Instant::now();
    std::thread::scope(|s| {
        for t in 0..threads.max(1) {
            let (cases, next, failures, tally, root) = (&cases, &next, &failures, &tally, &root);
            s.spawn(move || loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                if i >= cases.len() {
                    break;
                }
                let dir = root.join(format!("t{t}"));
                let o = run_case(&cases[i], &dir);
                let v = verdict(&o);
                let mut ta = tally.lock().unwrap();
                if o.seconds > ta.slowest {
                    ta.slowest = o.seconds;
                    ta.slowest_case = i;
                }
                match (&v, o.code) {
                    (Some(_), _) => ta.failed += 1,
                    (None, Some(0)) => ta.ok += 1,
                    (None, Some(2)) => ta.usage += 1,
                    (None, Some(3)) => ta.unstable += 1,
                    (None, _) => ta.refused += 1,
                }
                drop(ta);
                if let Some(v) = v {
                    failures
                        .lock()
                        .unwrap()
                        .push(format!("case {i}: {v}\n    {}", describe(&cases[i])));
                }
            });
        }
    });
    let _ = std::fs::remove_dir_all(&root);
    let _ = std::fs::remove_dir(scratch());
    let tally = tally.into_inner().unwrap();
    let mut failures = failures.into_inner().unwrap();
    failures.sort();
    eprintln!(
        "fuzz: {n} cases in {:.1} s on {threads} threads: {} ran ok, {} refused with a message, {} unstable, {} \
         usage errors, {} failed; slowest case {:.2} s: {}",
        start.elapsed().as_secs_f64(),
        tally.ok,
        tally.refused,
        tally.unstable,
        tally.usage,
        tally.failed,
        tally.slowest,
        describe(&cases[tally.slowest_case])
    );
    assert!(
        failures.is_empty(),
        "{} failing cases:\n{}",
        failures.len(),
        failures.join("\n")
    );
}

fn threads() -> usize {
    std::env::var("BLOCKFLOW_FUZZ_THREADS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(2)
}

/// The CI part: a few hundred cases from a fixed seed.
#[test]
fn fuzz_configs_and_overrides() {
    fuzz(FUZZ_CI_CASES, FUZZ_SEED, threads());
}

/// The long run: `BLOCKFLOW_FUZZ_CASES` cases (default 10 000) from `BLOCKFLOW_FUZZ_SEED` (a number; default
/// a seed other than the CI one). `cargo test --release --test fuzz -- --ignored fuzz_many`.
#[test]
#[ignore]
fn fuzz_many() {
    let n = std::env::var("BLOCKFLOW_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(10_000);
    let s: u64 = std::env::var("BLOCKFLOW_FUZZ_SEED")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(2);
    let mut seed = [0u8; 32];
    seed[..8].copy_from_slice(&s.to_le_bytes());
    seed[8..].copy_from_slice(&FUZZ_SEED[8..]);
    fuzz(n, seed, threads());
}

// ---------------------------------------------------------------------------------------------------------
// Regressions: fixed inputs for the defects the fuzzing found

/// A fixed case that must keep the contract.
fn keeps_contract(source: Source, args: &[&str]) -> Outcome {
    let case = Case {
        source,
        args: args.iter().map(|s| s.to_string()).collect(),
    };
    static FIXED: AtomicUsize = AtomicUsize::new(0);
    let dir = scratch().join(format!("fixed-{}", FIXED.fetch_add(1, Ordering::Relaxed)));
    let o = run_case(&case, &dir);
    let _ = std::fs::remove_dir_all(&dir);
    if let Some(v) = verdict(&o) {
        panic!("{v}\n    {}", describe(&case));
    }
    o
}

/// A fixed case that must be refused with a one-line message containing every needle.
fn refused(source: Source, args: &[&str], needles: &[&str]) {
    let o = keeps_contract(source, args);
    assert_ne!(o.code, Some(0), "expected a refusal: {args:?}");
    for n in needles {
        assert!(o.stderr.contains(n), "message lacks {n:?}: {}", o.stderr);
    }
}

#[test]
fn fuzz_regressions() {
    use Source::Config as C;
    // empty files and garbage
    refused(Source::Bytes(Vec::new()), &["--steps", "2"], &["scene"]);
    refused(
        Source::Bytes(vec![0xff, 0x00, 0x13]),
        &["--steps", "2"],
        &["scene.toml"],
    );
    refused(C("coefficients.toml"), &["--steps", "2"], &["[scene]"]);
    // a valid case runs
    let o = keeps_contract(C("couette.toml"), &["--steps", "2"]);
    assert_eq!(o.code, Some(0));
}

/// Command-line errors of clap were several lines (the error, a tip, the usage, a pointer to --help).
#[test]
fn usage_errors_are_one_line() {
    use Source::Config as C;
    refused(C("channel.toml"), &["--steps", "-1"], &["'-1'"]);
    refused(C("channel.toml"), &["--steps", "x"], &["'x'", "--steps"]);
    refused(C("channel.toml"), &["--steps", "2", "--bogus-flag"], &["--bogus-flag"]);
    refused(
        C("channel.toml"),
        &["--steps", "2", "--processes", ""],
        &["--processes"],
    );
    // the missing argument is on clap's second line (`run` without a scene runs the demo; `study` needs one)
    let o = Command::new(binary())
        .args(["study", "--processes", "2"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(err.contains("<SCENE>"), "{err}");
}

/// Domains whose extent overflowed `usize` (blocks × block_size, or a scene's resolution) wrapped around:
/// a panic indexing the bodies' blocks (hopper), a "no fluid cell in the [0, 0, 1]-cell domain" message
/// (box), a capacity-overflow panic (taylor_green).
#[test]
fn overflowing_domains_are_refused() {
    use Source::Config as C;
    let huge = ["--steps", "2", "--set", "domain.blocks=[4294967296,4294967296,4]"];
    refused(C("hopper-small.toml"), &huge, &["domain.blocks", "between 1 and"]);
    refused(C("calibration.toml"), &huge, &["domain.blocks", "between 1 and"]);
    let both = [
        "--steps",
        "2",
        "--set",
        "domain.blocks=[4294967296,4294967296,1]",
        "--set",
        "domain.block_size=[4294967296,4294967296,1]",
    ];
    refused(C("box.toml"), &both, &["domain.block_size", "between 1 and"]);
    let spheres = "scene.spheres=[{centre=[1,1,1],radius=0.5}]";
    refused(
        C("box.toml"),
        &[&both[..], &["--set", spheres]].concat(),
        &["domain.block_size"],
    );
    for (file, key) in [
        ("taylor_green.toml", "scene.resolution=4294967296"),
        ("taylor_green.toml", "scene.resolution=911993056309129300"),
        // the steady-state step count squared the width in integers first (an overflow panic in a
        // debug build: BLOCKFLOW_FUZZ_BIN)
        ("channel.toml", "scene.resolution=4294967296"),
        ("couette.toml", "scene.width=4294967296"),
        ("cavity.toml", "scene.resolution=2000000"),
        ("settling_sphere.toml", "scene.box=[1e300,0.1,0.16]"),
    ] {
        refused(C(file), &["--steps", "2", "--set", key], &["cells", "between 1 and"]);
    }
}

/// Body counts past what can be allocated aborted the run while the scene placed its bodies (before any
/// memory estimate): the count is bounded and named.
#[test]
fn huge_body_counts_are_refused() {
    use Source::Config as C;
    refused(
        C("granular_box.toml"),
        &[
            "--steps",
            "2",
            "--set",
            "scene.size=[100000,100000,100000]",
            "--set",
            "scene.count=1000000000",
        ],
        &["scene.count", "at most"],
    );
    refused(
        C("hopper-small.toml"),
        &["--steps", "2", "--set", "scene.count=18446744073709551615"],
        &["scene.count"],
    );
    refused(
        C("calibration.toml"),
        &["--steps", "2", "--set", "domain.blocks=[400,400,400]"],
        &["scene.solid_fraction", "spheres"],
    );
}

/// The calibration scene's random placement tested every candidate against every placed sphere, up to
/// 2000 × count candidates: a jammed thin box (a high solid fraction under a low top wall) ran for minutes.
/// Placement now bins the spheres in a grid and gives up after 100 000 rejections in a row.
#[test]
fn jammed_calibration_placement_is_refused_quickly() {
    let start = Instant::now();
    refused(
        Source::Config("calibration.toml"),
        &[
            "--steps",
            "1",
            "--set",
            "domain.blocks=[16,16,1]",
            "--set",
            "scene.top_offset=0.6",
            "--set",
            "scene.solid_fraction=0.3",
        ],
        &["scene.solid_fraction", "could not place"],
    );
    assert!(start.elapsed() < Duration::from_secs(10), "took {:?}", start.elapsed());
}

/// A hopper with no spheres said "0 layers of 25 spheres reach below the funnel top" (an underflow of
/// the layer count); it is a fluid-only hopper and runs.
#[test]
fn hopper_without_spheres_runs() {
    let o = keeps_contract(
        Source::Config("hopper-small.toml"),
        &["--steps", "2", "--set", "scene.count=0"],
    );
    assert_eq!(o.code, Some(0), "{}", o.stderr);
}

/// Thousands of worker threads under the fuzzing's address-space cap: a thread that could not map its
/// signal stack aborted the process. The threads' stacks are part of the memory estimate, and the
/// message names the process keys. Thousands of in-process ranks each built the whole state at once and
/// aborted on an allocation: their estimate counts the state once per rank.
#[test]
fn thread_counts_past_the_memory_are_refused() {
    use Source::Config as C;
    refused(
        C("hopper-small.toml"),
        &["--steps", "2", "--ranks", "4096"],
        &["use fewer ranks (processes.ranks = 4096", "4096 × (PDFs"],
    );
    for (file, key) in [
        ("box.toml", "processes.count=4096"),
        ("calibration.toml", "processes.threads_per_process=4096"),
    ] {
        refused(
            C(file),
            &["--steps", "2", "--set", key],
            &["worker threads", "processes.threads_per_process", "processes.count"],
        );
    }
}

/// A `--set` value that went on with lines of TOML (`0.7\n[scene]\nkind="box"`) took the first value and
/// dropped the rest, and a message that quoted it was several lines. It is refused, on one line.
#[test]
fn multi_line_set_values_are_refused_on_one_line() {
    refused(
        Source::Config("taylor_green.toml"),
        &["--steps", "2", "--set", "fluid.tau=0.7\n[scene]\nkind=\"box\""],
        &["--set fluid.tau", "more than one TOML value"],
    );
    refused(
        Source::Config("taylor_green.toml"),
        &[
            "--steps",
            "2",
            "--set",
            "fluid=\"x\"",
            "--set",
            "fluid.tau=0.7\n[scene]\nkind=\"box\"",
        ],
        &["--set fluid.tau"],
    );
}
