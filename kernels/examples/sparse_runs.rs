//! What a sweep costs per block when its fluid runs are short or sparse: one AA step of 300 blocks of
//! 16³ cells (f64, about 300 MB, far past L3) for several run patterns, microseconds per block and
//! nanoseconds per cell and per run. `NB=30` (in L3) or `NB=2` (in L2) give the in-cache figures;
//! `PARITY=0` or `1` times the even (in-place) or the odd AA steps alone.
//!
//! `L=4,8,13,16` times runs of those lengths instead, one in every row: starting at x = 1 or ending at
//! x = N, the same in every plane or one cell shorter in every other plane (a wall that cuts the planes
//! differently). `N=32 NB=40` takes blocks of 32³ cells (about 250 MB).
//!
//! `cargo run --release -p blockflow-kernels --example sparse_runs`

use blockflow_kernels::field::{Layout, PdfField};
use blockflow_kernels::sweep::{aa_step, full_segments, Segment};
use blockflow_kernels::TrtParams;
use std::time::Instant;

fn main() {
    let n: usize = std::env::var("N").ok().and_then(|s| s.parse().ok()).unwrap_or(16);
    let l = Layout::new::<f64>([n, n, n]);
    let blocks: usize = std::env::var("NB").ok().and_then(|s| s.parse().ok()).unwrap_or(300);
    // `PARITY=0` times only the AA pattern's even steps (in place), `PARITY=1` only its odd ones.
    let parity: Option<u64> = std::env::var("PARITY").ok().and_then(|s| s.parse().ok());
    let mut fields: Vec<PdfField<f64>> = (0..blocks).map(|b| PdfField::new(l, (b % 8) * 64)).collect();
    for f in fields.iter_mut() {
        f.data_mut().fill(1e-3);
    }
    let p = TrtParams {
        tau: 0.6,
        magic: 3.0 / 16.0,
        force: [0.0; 3],
    };
    // A wall-cut block: plane z holds its first 13z/16 rows (105 rows in all).
    let rows_of = |z: usize| z * 13 / 16;
    let runs = |f: &dyn Fn(usize, usize) -> Option<(usize, usize)>| -> Vec<Segment> {
        let mut v = Vec::new();
        for z in 1..=n {
            for y in 1..=n {
                if let Some((x0, len)) = f(y, z) {
                    v.push(Segment {
                        start: l.idx(x0, y, z),
                        len,
                    });
                }
            }
        }
        v
    };
    let patterns: Vec<(&str, Vec<Segment>)> = vec![
        ("full block", full_segments(&l)),
        ("wall-cut, full rows", runs(&|y, z| (y <= rows_of(z)).then_some((1, n)))),
        ("wall-cut, 7 cells", runs(&|y, z| (y <= rows_of(z)).then_some((1, 7)))),
        ("8 of 16 cells", runs(&|_, _| Some((1, 8)))),
        ("8 cells, shifted", runs(&|y, z| Some((1 + (y + z) % 9, 8)))),
        ("every other row", runs(&|y, z| ((y + z) % 2 == 0).then_some((1, n)))),
        // Full rows, cut by plane in three ways: whole planes left out, the same rows of every plane,
        // and (above) rows cut where a sloped wall crosses each plane.
        ("first 7 planes, full rows", runs(&|_, z| (z <= 7).then_some((1, n)))),
        ("every other plane", runs(&|_, z| (z % 2 == 0).then_some((1, n)))),
        ("rows y <= 7 of every plane", runs(&|y, _| (y <= 7).then_some((1, n)))),
        ("rows y >= 10 of every plane", runs(&|y, _| (y >= 10).then_some((1, n)))),
        // The same rows but one, changing from plane to plane, or every fourth plane.
        (
            "rows y <= 6 + z mod 2",
            runs(&|y, z| (y <= 6 + z % 2).then_some((1, n))),
        ),
        (
            "rows y <= 6 + (z / 4) mod 2",
            runs(&|y, z| (y <= 6 + (z / 4) % 2).then_some((1, n))),
        ),
    ];
    let lens: Option<Vec<usize>> = std::env::var("L").ok().map(|s| {
        s.split(',')
            .filter_map(|x| x.parse().ok())
            .filter(|&l| l >= 1 && l <= n)
            .collect()
    });
    let cases: Vec<(String, Vec<Segment>)> = match lens {
        None => patterns
            .into_iter()
            .map(|(name, segs)| (name.to_string(), segs))
            .collect(),
        Some(lens) => lens
            .into_iter()
            .flat_map(|len| {
                // One cell shorter in every other plane (at least one cell).
                let m = move |z: usize| (len - z % 2).max(1);
                [
                    (format!("L = {len} from x = 1"), runs(&|_, _| Some((1, len)))),
                    (format!("L = {len} to x = N"), runs(&|_, _| Some((n + 1 - len, len)))),
                    (
                        format!("L = {len} from x = 1, ±1 by plane"),
                        runs(&|_, z| Some((1, m(z)))),
                    ),
                    (
                        format!("L = {len} to x = N, ±1 by plane"),
                        runs(&|_, z| Some((n + 1 - m(z), m(z)))),
                    ),
                ]
            })
            .collect(),
    };
    println!("| runs | count | cells | µs per block | ns per cell | ns per run |\n|---|---:|---:|---:|---:|---:|");
    for round in 0..2 {
        for (name, segs) in &cases {
            let cells: usize = segs.iter().map(|s| s.len).sum();
            let steps = 20;
            let t = Instant::now();
            for step in 0..steps {
                let step = parity.map_or(step, |q| 2 * step + q);
                for f in fields.iter_mut() {
                    aa_step(f, step, segs, &p);
                }
            }
            let per = t.elapsed().as_secs_f64() / (steps as usize * blocks) as f64;
            if round == 1 {
                println!(
                    "| {name} | {} | {cells} | {:.1} | {:.1} | {:.0} |",
                    segs.len(),
                    per * 1e6,
                    per * 1e9 / cells as f64,
                    per * 1e9 / segs.len() as f64
                );
            }
        }
    }
}
