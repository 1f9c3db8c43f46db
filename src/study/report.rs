//! Table 3 of the paper from the counterfactual strategies: relative run time, balancing fraction, mean
//! edge cut and median load imbalance per strategy; as markdown, CSV and `study.json`.

use super::Candidate;
use crate::metrics::interval::IntervalStats;
use crate::util::stats::median_finite;
use serde::Serialize;

/// One row of Table 3.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    /// Strategy name.
    pub name: String,
    /// Modeled run time (`graph` model, balancing included) relative to `none`, in percent change
    /// (the paper's "relative runtime": −14 % for the space-filling curves).
    pub relative_runtime: f64,
    /// The same in the `bsp` model.
    pub relative_runtime_bsp: f64,
    /// Share of the run spent balancing (weights, partition and the graph's recompile by the CPU clock,
    /// migration modeled), percent.
    pub balance_fraction: f64,
    /// Mean over intervals of the edge cut eq. (17) per process.
    pub edge_cut_mean: f64,
    /// Mean over intervals of the edge cut eq. (17) summed over all processes, each cut contact counted
    /// by both processes it joins (the paper's Table 3 column, as waLBerla evaluates it).
    pub edge_cut_total: f64,
    /// Median over intervals of the measured load imbalance eq. (18).
    pub imbalance_median: f64,
    /// Median over intervals of the load imbalance the weights predicted.
    pub predicted_imbalance_median: f64,
    /// Blocks moved over the run.
    pub migrated_blocks: u64,
    /// Blocks that would have moved without METIS relabelling.
    pub migrated_unrelabelled: Option<u64>,
    /// Serialised bytes moved over the run.
    pub migrated_bytes: u64,
    /// Modeled seconds, `graph` model, balancing included.
    pub graph_seconds: f64,
    /// Modeled seconds, `bsp` model, balancing included.
    pub bsp_seconds: f64,
    /// Seconds of balancing.
    pub balance_seconds: f64,
    /// The strategy's intervals.
    pub intervals: Vec<IntervalStats>,
}

/// Median of the finite values (NaN when none).
pub fn median(v: impl Iterator<Item = f64>) -> f64 {
    median_finite(&v.collect::<Vec<f64>>())
}

/// Table 3 rows, relative to the strategy named `none` (or the first one).
pub fn rows(candidates: &[Candidate]) -> Vec<Row> {
    let mut rows: Vec<Row> = candidates
        .iter()
        .map(|s| {
            let iv = s.intervals();
            let processes = s.log.machine().processes as f64;
            let cut_mean = if iv.is_empty() {
                0.0
            } else {
                iv.iter().map(|i| i.edge_cut_mean).sum::<f64>() / iv.len() as f64
            };
            let bal: f64 = iv.iter().map(|i| i.balance_seconds).sum();
            let graph = iv.iter().map(|i| i.modeled_seconds).sum::<f64>() + bal;
            let bsp = iv.iter().map(|i| i.bsp_seconds).sum::<f64>() + bal;
            let unrel: Vec<u64> = iv.iter().filter_map(|i| i.migrated_unrelabelled).collect();
            Row {
                name: s.name.clone(),
                relative_runtime: 0.0,
                relative_runtime_bsp: 0.0,
                balance_fraction: if graph > 0.0 { 100.0 * bal / graph } else { 0.0 },
                edge_cut_mean: cut_mean,
                edge_cut_total: 2.0 * processes * cut_mean,
                imbalance_median: median(iv.iter().map(|i| i.imbalance)),
                predicted_imbalance_median: median(iv.iter().map(|i| i.predicted_imbalance)),
                migrated_blocks: iv.iter().map(|i| i.migrated_blocks).sum(),
                migrated_unrelabelled: (!unrel.is_empty()).then(|| unrel.iter().sum()),
                migrated_bytes: iv.iter().map(|i| i.migrated_bytes).sum(),
                graph_seconds: graph,
                bsp_seconds: bsp,
                balance_seconds: bal,
                intervals: iv.to_vec(),
            }
        })
        .collect();
    let base = rows.iter().find(|r| r.name == "none").or(rows.first()).cloned();
    if let Some(b) = base {
        for r in &mut rows {
            r.relative_runtime = pct(r.graph_seconds, b.graph_seconds);
            r.relative_runtime_bsp = pct(r.bsp_seconds, b.bsp_seconds);
        }
    }
    rows
}

fn pct(x: f64, base: f64) -> f64 {
    if base > 0.0 {
        100.0 * (x / base - 1.0)
    } else {
        0.0
    }
}

/// Table 3 as markdown.
pub fn markdown(rows: &[Row]) -> String {
    let mut s = String::from(
        "| strategy | relative runtime (graph) | relative runtime (bsp) | balancing | mean edge cut (total) | median LI \
         | median predicted LI | blocks migrated | MB migrated |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for r in rows {
        let migrated = match r.migrated_unrelabelled {
            Some(u) => format!("{} ({u} unrelabelled)", r.migrated_blocks),
            None => r.migrated_blocks.to_string(),
        };
        s += &format!(
            "| {} | {:+.1} % | {:+.1} % | {:.2} % | {:.0} | {:.1} % | {} | {} | {:.1} |\n",
            r.name,
            r.relative_runtime,
            r.relative_runtime_bsp,
            r.balance_fraction,
            r.edge_cut_total,
            100.0 * r.imbalance_median,
            if r.predicted_imbalance_median.is_finite() {
                format!("{:.1} %", 100.0 * r.predicted_imbalance_median)
            } else {
                "–".to_string()
            },
            migrated,
            r.migrated_bytes as f64 / 1e6
        );
    }
    s
}

/// Table 3 as CSV.
pub fn csv(rows: &[Row]) -> String {
    let mut s = String::from(
        "strategy,relative_runtime,relative_runtime_bsp,balance_fraction,edge_cut_mean,edge_cut_total,imbalance_median,\
         predicted_imbalance_median,migrated_blocks,migrated_unrelabelled,migrated_bytes,graph_seconds,bsp_seconds,\
         balance_seconds\n",
    );
    for r in rows {
        s += &format!(
            "{},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{},{},{},{:.6e},{:.6e},{:.6e}\n",
            r.name,
            r.relative_runtime,
            r.relative_runtime_bsp,
            r.balance_fraction,
            r.edge_cut_mean,
            r.edge_cut_total,
            r.imbalance_median,
            r.predicted_imbalance_median,
            r.migrated_blocks,
            r.migrated_unrelabelled.map_or(String::new(), |u| u.to_string()),
            r.migrated_bytes,
            r.graph_seconds,
            r.bsp_seconds,
            r.balance_seconds
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn candidate(name: &str, secs: &[f64], li: &[f64]) -> Candidate {
        let m = crate::metrics::cost_model::Machine {
            processes: 1,
            threads: 1,
            global: false,
            comm: Default::default(),
        };
        let mut c = Candidate::new(name, None, vec![0], &[], m);
        let d = crate::physics::domain::DomainSpec {
            blocks: [1, 1, 1],
            block_size: [4, 4, 4],
            periodic: [false; 3],
        };
        for (i, (&g, &l)) in secs.iter().zip(li).enumerate() {
            let cur = c.log.current_mut();
            cur.modeled_seconds = g;
            cur.bsp_seconds = 2.0 * g;
            let iv = c.log.close(i as u64 + 1, &[1.0], &d).unwrap();
            iv.imbalance = l;
            iv.predicted_imbalance = f64::NAN;
        }
        c
    }

    #[test]
    fn relative_runtime_and_medians() {
        let rows = rows(&[
            candidate("none", &[1.0, 1.0, 2.0], &[0.6, 0.5, 0.7]),
            candidate("hilbert", &[1.0, 1.0, 1.0], &[0.1, 0.3, 0.2]),
        ]);
        assert_eq!(rows[0].relative_runtime, 0.0);
        assert!((rows[1].relative_runtime + 25.0).abs() < 1e-12);
        assert!((rows[1].relative_runtime_bsp + 25.0).abs() < 1e-12);
        assert_eq!(rows[0].imbalance_median, 0.6);
        assert_eq!(rows[1].imbalance_median, 0.2);
        assert!(rows[1].predicted_imbalance_median.is_nan());
        assert!(markdown(&rows).contains("| hilbert | -25.0 % |"));
        assert_eq!(csv(&rows).lines().count(), 3);
    }
}
