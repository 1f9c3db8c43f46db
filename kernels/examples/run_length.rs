//! What a run costs against its length: one AA step (an even and an odd one alternately) of `NB` blocks
//! of `N`³ cells (f64; default 40 blocks of 32³, about 250 MB, far past L3) whose every row holds one run
//! of L cells, starting at x = 1 or ending at x = N, with the same length in every plane or one cell
//! shorter in every other plane (a wall that cuts the planes differently). Microseconds per block and
//! nanoseconds per cell and per run.
//!
//! `cargo run --release -p blockflow-kernels --example run_length`; `N=16 NB=300` for 16³ blocks,
//! `L=12,13,16` for other run lengths, `PARITY=0` or `1` for the even (in-place) or the odd AA steps alone.

use blockflow_kernels::field::{Layout, PdfField};
use blockflow_kernels::sweep::{aa_step, Segment};
use blockflow_kernels::TrtParams;
use std::time::Instant;

fn main() {
    let n: usize = std::env::var("N").ok().and_then(|s| s.parse().ok()).unwrap_or(32);
    let l = Layout::new::<f64>([n, n, n]);
    let blocks: usize = std::env::var("NB").ok().and_then(|s| s.parse().ok()).unwrap_or(40);
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
    let lens: Vec<usize> = std::env::var("L")
        .ok()
        .map(|s| s.split(',').filter_map(|x| x.parse().ok()).collect())
        .unwrap_or_else(|| vec![4, 8, 13, 16, 24, n]);
    let mut cases: Vec<(String, Vec<Segment>)> = Vec::new();
    for len in lens.iter().copied() {
        if len == 0 || len > n {
            continue;
        }
        cases.push((format!("L={len} from x=1"), runs(&|_, _| Some((1, len)))));
        cases.push((format!("L={len} to x=n"), runs(&|_, _| Some((n + 1 - len, len)))));
        cases.push((
            format!("L={len} from x=1, +-1 by plane"),
            runs(&move |_, z| Some((1, (len - (z % 2)).max(1)))),
        ));
        cases.push((
            format!("L={len} to x=n, +-1 by plane"),
            runs(&move |_, z| {
                let m = (len - (z % 2)).max(1);
                Some((n + 1 - m, m))
            }),
        ));
    }
    println!("| runs | count | cells | µs per block | ns per cell | ns per run |\n|---|---:|---:|---:|---:|---:|");
    for round in 0..2 {
        for (name, segs) in &cases {
            let cells: usize = segs.iter().map(|s| s.len).sum();
            let steps = 10;
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
