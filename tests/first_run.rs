//! The first run a new user makes: `blockflow run` without a scene runs the built-in demo (spheres in a
//! hopper on 2 virtual processes, rebalanced every 100 steps by measured workload) and writes its
//! figures, pictures and report. Checks: the figures and pictures decode at their documented size, the
//! GIF has one frame per picture, every file the report
//! links exists, and the load imbalance after the first rebalance is below that of the initial
//! assignment (which splits by fluid cells and so leaves most of the spheres' work on one process).

use blockflow::util::stats::median;
use std::path::{Path, PathBuf};
use std::process::Command;

/// Width and height from a PNG's IHDR chunk, after checking the signature.
fn png_size(path: &Path) -> (u32, u32) {
    let png = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n", "{} is not a PNG", path.display());
    assert_eq!(&png[12..16], b"IHDR");
    let be = |i: usize| u32::from_be_bytes(png[i..i + 4].try_into().unwrap());
    (be(16), be(20))
}

/// The targets of the markdown links and images `[..](target)` in `text`.
fn link_targets(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut rest = text;
    while let Some(i) = rest.find("](") {
        let tail = &rest[i + 2..];
        let end = tail.find(')').expect("closed link");
        out.push(tail[..end].to_string());
        rest = &tail[end..];
    }
    out
}

#[test]
fn the_demo_balances_draws_and_reports() {
    let out = std::env::temp_dir().join(format!("blockflow-first-run-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    // Five intervals of the demo (the full demo is 2000 steps).
    let o = Command::new(env!("CARGO_BIN_EXE_blockflow"))
        .args(["run", "--steps", "500", "--out"])
        .arg(&out)
        .current_dir(std::env::temp_dir())
        .output()
        .expect("binary runs");
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{stdout}{}", String::from_utf8_lossy(&o.stderr));
    for needle in [
        "hopper: 500 steps",
        "load imbalance eq. (18) per interval",
        "migrated",
        "LBM",
    ] {
        assert!(stdout.contains(needle), "{needle:?} not in\n{stdout}");
    }
    // Sizes from io::plots::run::{BALANCE_FIGURE_SIZE, PARTS_FIGURE_SIZE}.
    assert_eq!(png_size(&out.join("balance.png")), (1400, 1100));
    assert_eq!(png_size(&out.join("parts.png")), (1400, 800));
    // The demo draws the plane y = 24 every 100 steps (run.png_every): steps 0 to 500, 48 x 72 cells at
    // 10 pixels per cell with the axes and the legend strip (io::plots::slice::image_size).
    let pictures: Vec<PathBuf> = (0..=5)
        .map(|k| out.join(format!("slices/step-{:08}.png", 100 * k)))
        .collect();
    for p in &pictures {
        let img = image::open(p).unwrap_or_else(|e| panic!("{} does not decode: {e}", p.display()));
        assert_eq!((img.width(), img.height()), (880, 850), "{}", p.display());
    }
    let mut opts = gif::DecodeOptions::new();
    opts.set_color_output(gif::ColorOutput::RGBA);
    let mut gif = opts
        .read_info(std::fs::File::open(out.join("slices.gif")).unwrap())
        .unwrap();
    let mut frames = 0;
    while let Some(f) = gif.read_next_frame().unwrap() {
        assert_eq!((f.width, f.height), (880, 850));
        frames += 1;
    }
    assert_eq!(frames, pictures.len(), "one GIF frame per picture");
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    let links = link_targets(&report);
    for must in [
        "balance.png",
        "parts.png",
        "slices.gif",
        "summary.json",
        "effective.toml",
    ] {
        assert!(links.iter().any(|l| l == must), "report.md does not link {must}");
    }
    for l in &links {
        assert!(
            PathBuf::from(&out).join(l).exists(),
            "report.md links {l}, which is missing"
        );
    }
    let s: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("summary.json")).unwrap()).unwrap();
    let li: Vec<f64> = s["balance"]["imbalance"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert_eq!(li.len(), 5, "{li:?}");
    assert!(s["balance"]["migrated_blocks"].as_u64().unwrap() > 0);
    // The initial split by cells leaves about a quarter more work on one process (27 % measured); after
    // the first rebalance by measured load the intervals sit at a few per cent of timing noise.
    let after = median(&li[1..]);
    assert!(
        after < li[0],
        "LI after the first rebalance {after} not below the first interval's {}",
        li[0]
    );
    std::fs::remove_dir_all(&out).ok();
}
