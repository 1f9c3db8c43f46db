//! The two forms of the workload functions: the paper's eqs. (10)–(14) and `blockflow`'s, whose
//! regressors are the work this engine's tasks do. Both are linear in their coefficients, so one fit
//! ([`super::fit()`]) serves both; a coefficients file names its form (`model = "paper" | "blockflow"`).
//!
//! Why a second form (section 3.5: the functions depend on the algorithms): here the mapping task also
//! finds the links and takes a nearly free fast path when no body is near, the boundary pass costs per
//! link (δ_q and the momentum exchange per link), and the rigid-body task solves every contact it sees.
//! The `blockflow` terms, beside the paper's equation each replaces (every coupling term multiplied by
//! [F > 0], every coefficient a cost ≥ 0; LBM and BH fitted together, [`Model::fit_groups`]):
//!
//! | part | paper | `blockflow` |
//! |---|---|---|
//! | LBM | eq. (10): a1·C + a2·F + a3 | F, fluid runs (a row set-up each), stream breaks (runs that restart the memory streams: more than six rows past the run before, e.g. where a sloping wall moves the first fluid row of a plane), tail runs × row pitch (runs whose last len mod lanes cells the kernel updates in one vector tail step, each weighted by its row's length in memory, ghosts and padding included: a cut row costs its whole row, and fitted per block size alone a tail cost 142, 191 and 351 ns at 12³, 16³ and 32³, 8.9–9.8 ns per element of the pitches 16, 20 and 36), [F > 0], C·[F > 0] (the lines of the whole block the sweep's streams run through), C·[F > 0]·[no links] (a block no boundary pass has warmed sweeps from memory), NB (fluid cells next to a wall or body, whose neighbours' lines the boundary pass has just written) |
//! | BH | eq. (11): a1·C + a2·NB + a3 | wall links, cache lines they touch, particle links, link cells, [links > 0] (a block without links has no boundary pass) |
//! | Coup1 | eq. (12): a1·C + a2·F + a3·P_L + a4·P_S + a5 | [map active], C·[map active], bounding-box cells visited, rows derived, link cells, bodies mapped |
//! | Coup2 | eq. (13): as eq. (12) | [map active], cells turned fluid, cells covered |
//! | RB | eq. (14): S·(a1·(P_L+P_S)² + a2·P_L + a3·P_S + a4·K + a5) | S·[active], S·(P_L+P_S)², S·(P_L+P_S), S·K_seen, S·(list entries scanned), P_L (the force sum, once per step) |

use super::Quantities;

/// Which form of the workload functions a set of coefficients belongs to.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Model {
    /// Eqs. (10)–(14) of the paper, coefficients `a1` … `a5` per part.
    #[default]
    Paper,
    /// This engine's regressors (module table), coefficients named for what they multiply.
    Blockflow,
}

/// Most regressors of any part in any model.
pub const MAX_TERMS: usize = 9;

/// The regressor values of one part for one block and step (the first `len` entries of `v`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Row {
    v: [f64; MAX_TERMS],
    len: usize,
}

impl Row {
    fn of(values: &[f64]) -> Row {
        let mut v = [0.0; MAX_TERMS];
        v[..values.len()].copy_from_slice(values);
        Row { v, len: values.len() }
    }

    /// The values.
    pub fn as_slice(&self) -> &[f64] {
        &self.v[..self.len]
    }

    /// Σ a_j·x_j.
    pub fn dot(&self, a: &[f64]) -> f64 {
        self.as_slice().iter().zip(a).map(|(x, a)| x * a).sum()
    }
}

/// The key and meaning of every coefficient of a part.
type Terms = &'static [(&'static str, &'static str)];

const PAPER: [Terms; 5] = [
    &[("a1", "C"), ("a2", "F"), ("a3", "1")],
    &[("a1", "C"), ("a2", "NB"), ("a3", "1")],
    &[("a1", "C"), ("a2", "F"), ("a3", "PL"), ("a4", "PS"), ("a5", "1")],
    &[("a1", "C"), ("a2", "F"), ("a3", "PL"), ("a4", "PS"), ("a5", "1")],
    &[
        ("a1", "S*(PL+PS)^2"),
        ("a2", "S*PL"),
        ("a3", "S*PS"),
        ("a4", "S*K"),
        ("a5", "S"),
    ],
];

const BLOCKFLOW: [Terms; 5] = [
    &[
        ("fluid_cells", "fluid cells F"),
        ("runs", "runs of fluid cells"),
        ("breaks", "runs that restart the memory streams"),
        (
            "tail_row_elements",
            "row pitch (elements) x runs that end in a vector tail step",
        ),
        ("shifted_runs", "runs of planes whose runs differ from the plane before"),
        ("active", "1 if F > 0"),
        ("cells", "C if F > 0"),
        (
            "cold_cells",
            "C if F > 0 and the block has no links (no boundary pass before the sweep)",
        ),
        ("near_boundary", "fluid cells next to a wall or body (NB)"),
    ],
    &[
        ("wall_links", "bounce-back links at walls"),
        ("wall_lines", "cache lines the wall links touch"),
        ("particle_links", "links into particle cells"),
        ("link_cells", "fluid cells with a particle link"),
        ("active", "1 if F > 0 and the block has links (a boundary pass runs)"),
    ],
    &[
        ("active", "1 if the mapping left its fast path"),
        ("cells", "C if the mapping left its fast path"),
        ("box_cells", "bounding-box cells visited"),
        ("rows", "rows derived again"),
        ("link_cells", "fluid cells with a particle link"),
        ("bodies", "bodies mapped"),
    ],
    &[
        ("active", "1 if the mapping left its fast path"),
        ("turned", "cells turned fluid (reconstructed)"),
        ("covered", "cells covered by a body"),
    ],
    &[
        ("active", "S if the block has rigid-body tasks"),
        ("pairs", "S*(PL+PS)^2"),
        ("bodies", "S*(PL+PS)"),
        ("contacts_seen", "S*contacts seen"),
        ("scanned", "S*list entries scanned"),
        ("published", "PL (force sum, once per step)"),
    ],
];

impl Model {
    /// The name used in files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Model::Paper => "paper",
            Model::Blockflow => "blockflow",
        }
    }

    /// The model of a name (`paper` or `blockflow`).
    pub fn parse(s: &str) -> Option<Model> {
        match s {
            "paper" => Some(Model::Paper),
            "blockflow" => Some(Model::Blockflow),
            _ => None,
        }
    }

    /// Key and meaning of every coefficient of part `part` (index into [`super::PARTS`]).
    pub fn terms(self, part: usize) -> Terms {
        match self {
            Model::Paper => PAPER[part],
            Model::Blockflow => BLOCKFLOW[part],
        }
    }

    /// Whether the fit constrains the coefficients to be ≥ 0. The paper's form needs negative
    /// intercepts (its Table 2 has them) and relies on the floor; every `blockflow` coefficient is the
    /// cost of one unit of work.
    pub fn non_negative(self) -> bool {
        self == Model::Blockflow
    }

    /// The parts fitted together, as one least-squares problem against the sum of their measured times
    /// ([`super::fit()`]): every part alone in the paper's form (section 3.4); LBM and BH together in
    /// `blockflow`'s. Here a block's sweep runs right after its boundary pass, which has just brought
    /// in lines the sweep reads (wall links across the rows touch one line per row), so how the
    /// measured time splits between the two depends on the walls' orientation, and only their sum is a
    /// function of the regressors with costs ≥ 0. In the 16³ hopper, fully fluid blocks (same F, runs
    /// and NB) sweep in 4.7 ms per 100 steps next to a wall normal to x and in 6.5 ms next to one normal
    /// to y, whose links share lines; fitted apart, the sweep would need a negative cost per wall line.
    pub fn fit_groups(self) -> &'static [&'static [usize]] {
        match self {
            Model::Paper => &[&[0], &[1], &[2], &[3], &[4]],
            Model::Blockflow => &[&[0, 1], &[2], &[3], &[4]],
        }
    }

    /// The regressors of part `part` for quantities `q`.
    pub fn row(self, part: usize, q: &Quantities) -> Row {
        match self {
            Model::Paper => paper_row(part, q),
            Model::Blockflow => blockflow_row(part, q),
        }
    }
}

fn paper_row(part: usize, q: &Quantities) -> Row {
    match part {
        0 => Row::of(&[q.c, q.f, 1.0]),
        1 => Row::of(&[q.c, q.nb, 1.0]),
        2 | 3 => Row::of(&[q.c, q.f, q.pl, q.ps, 1.0]),
        4 => {
            let p = q.pl + q.ps;
            Row::of(&[q.s * p * p, q.s * q.pl, q.s * q.ps, q.s * q.k, q.s])
        }
        _ => unreachable!("part index {part} out of range"),
    }
}

fn blockflow_row(part: usize, q: &Quantities) -> Row {
    let fluid = f64::from(u8::from(q.f > 0.0));
    let links = f64::from(u8::from(q.wall_links + q.particle_links > 0.0));
    match part {
        0 => Row::of(&[
            q.f,
            q.runs,
            q.breaks,
            q.tail_runs * q.row_pitch,
            q.shifted_runs,
            fluid,
            q.c * fluid,
            q.c * fluid * (1.0 - links),
            q.nb,
        ]),
        1 => Row::of(&[q.wall_links, q.wall_lines, q.particle_links, q.link_cells, links].map(|x| x * fluid)),
        2 => Row::of(
            &[
                q.map_active,
                q.c * q.map_active,
                q.box_cells,
                q.rows_derived,
                q.link_cells * q.map_active,
                q.map_bodies,
            ]
            .map(|x| x * fluid),
        ),
        3 => Row::of(&[q.map_active, q.turned, q.covered].map(|x| x * fluid)),
        4 => {
            let p = q.pl + q.ps;
            Row::of(&[
                q.s * q.rb_active,
                q.s * p * p,
                q.s * p,
                q.s * q.contacts_seen,
                q.s * q.scanned,
                q.pl,
            ])
        }
        _ => unreachable!("part index {part} out of range"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_rows_are_eqs_10_to_14() {
        let q = Quantities {
            c: 4096.0,
            f: 3000.0,
            nb: 500.0,
            pl: 2.0,
            ps: 3.0,
            k: 4.0,
            s: 10.0,
            ..Default::default()
        };
        let m = Model::Paper;
        assert_eq!(m.row(0, &q).as_slice(), &[4096.0, 3000.0, 1.0]);
        assert_eq!(m.row(1, &q).as_slice(), &[4096.0, 500.0, 1.0]);
        assert_eq!(m.row(2, &q), m.row(3, &q));
        assert_eq!(m.row(4, &q).as_slice(), &[250.0, 20.0, 30.0, 40.0, 10.0]);
        for p in 0..5 {
            assert_eq!(m.row(p, &q).as_slice().len(), m.terms(p).len());
            assert_eq!(
                Model::Blockflow.row(p, &q).as_slice().len(),
                Model::Blockflow.terms(p).len()
            );
        }
    }

    #[test]
    fn blockflow_coupling_terms_vanish_without_fluid() {
        let q = Quantities {
            c: 4096.0,
            f: 0.0,
            wall_links: 100.0,
            map_active: 1.0,
            box_cells: 999.0,
            turned: 5.0,
            pl: 1.0,
            s: 10.0,
            rb_active: 1.0,
            ..Default::default()
        };
        let m = Model::Blockflow;
        for p in 0..4 {
            assert!(m.row(p, &q).as_slice().iter().all(|&x| x == 0.0), "part {p}");
        }
        // The rigid-body part does not need fluid.
        assert_eq!(m.row(4, &q).as_slice(), &[10.0, 10.0, 10.0, 0.0, 0.0, 1.0]);
        assert_eq!(Model::parse("blockflow"), Some(Model::Blockflow));
        // A fluid block without links has no boundary pass: no BH work at all, intercept included.
        let open = Quantities {
            c: 4096.0,
            f: 4096.0,
            ..Default::default()
        };
        assert!(m.row(1, &open).as_slice().iter().all(|&x| x == 0.0));
        let walled = Quantities {
            wall_links: 5.0,
            ..open
        };
        assert_eq!(m.row(1, &walled).as_slice(), &[5.0, 0.0, 0.0, 0.0, 1.0]);
        assert_eq!(
            m.row(0, &open).as_slice(),
            &[4096.0, 0.0, 0.0, 0.0, 0.0, 1.0, 4096.0, 4096.0, 0.0]
        );
        assert_eq!(
            m.row(0, &walled).as_slice(),
            &[4096.0, 0.0, 0.0, 0.0, 0.0, 1.0, 4096.0, 0.0, 0.0]
        );
        // A run cut short weighs its row's pitch: 3 tail runs in rows of 20 elements.
        let cut = Quantities {
            runs: 256.0,
            tail_runs: 3.0,
            row_pitch: 20.0,
            ..walled
        };
        assert_eq!(m.row(0, &cut).as_slice()[3], 60.0);
        assert_eq!(m.terms(0)[3].0, "tail_row_elements");
        assert_eq!(Model::parse(Model::Paper.name()), Some(Model::Paper));
        assert_eq!(Model::parse("cells"), None);
    }
}
