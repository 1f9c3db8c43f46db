//! The parts of a time step (Algorithm 1 of the paper): the vocabulary every task, timer, trace, summary
//! and workload model uses for "where the time went".

use std::ops::{Index, IndexMut};

/// A part of the time step. LBM, boundary handling, mapping (Coup1), reconstruction (Coup2) and rigid body
/// are the paper's parts (eqs. 10–14); the ghost exchange is reported beside them but is not part of the
/// workload m_tot (eq. 16).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[repr(u8)]
pub enum Part {
    /// Stream and collide (Algorithms 2 and 3).
    Lbm = 0,
    /// Boundary handling at walls and particle surfaces (Algorithm 4).
    Boundary = 1,
    /// Ghost-layer exchange between blocks.
    Exchange = 2,
    /// Rigid-body sub-steps and the hydrodynamic force sums (Algorithm 7).
    RigidBody = 3,
    /// Particle mapping, Coup1 (Algorithm 5).
    Map = 4,
    /// PDF reconstruction of uncovered cells, Coup2 (Algorithm 6).
    Reconstruct = 5,
}

impl Part {
    /// Every part, in index order.
    pub const ALL: [Part; 6] = [
        Part::Lbm,
        Part::Boundary,
        Part::Exchange,
        Part::RigidBody,
        Part::Map,
        Part::Reconstruct,
    ];

    /// The part of an index (`TaskSpec::part`).
    pub fn from_index(i: u8) -> Part {
        Part::ALL[i as usize]
    }

    /// Index of the part (`TaskSpec::part`).
    pub fn index(self) -> usize {
        self as usize
    }

    /// Name in outputs (`summary.json`, traces): `lbm`, `boundary`, `exchange`, `rigid_body`, `map`,
    /// `reconstruct`.
    pub fn name(self) -> &'static str {
        match self {
            Part::Lbm => "lbm",
            Part::Boundary => "boundary",
            Part::Exchange => "exchange",
            Part::RigidBody => "rigid_body",
            Part::Map => "map",
            Part::Reconstruct => "reconstruct",
        }
    }

    /// Label in tables and figures: `LBM`, `boundary`, `exchange`, `rigid body`, `map`, `reconstruct`.
    pub fn label(self) -> &'static str {
        match self {
            Part::Lbm => "LBM",
            Part::Boundary => "boundary",
            Part::Exchange => "exchange",
            Part::RigidBody => "rigid body",
            Part::Map => "map",
            Part::Reconstruct => "reconstruct",
        }
    }

    /// Whether the part counts into the workload m_tot of eq. (16) (every part but the exchange).
    pub fn is_workload(self) -> bool {
        self != Part::Exchange
    }

    /// Colour of the part in a Chrome trace (a trace-viewer colour name).
    pub fn trace_colour(self) -> &'static str {
        match self {
            Part::Lbm => "thread_state_running",
            Part::Boundary => "yellow",
            Part::Exchange => "thread_state_iowait",
            Part::RigidBody => "bad",
            Part::Map => "rail_animation",
            Part::Reconstruct => "olive",
        }
    }
}

/// One value per [`Part`], indexed by it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ByPart<V>(pub [V; 6]);

impl<V> Index<Part> for ByPart<V> {
    type Output = V;
    fn index(&self, p: Part) -> &V {
        &self.0[p as usize]
    }
}

impl<V> IndexMut<Part> for ByPart<V> {
    fn index_mut(&mut self, p: Part) -> &mut V {
        &mut self.0[p as usize]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parts_round_trip_through_their_index() {
        for p in Part::ALL {
            assert_eq!(Part::from_index(p.index() as u8), p);
        }
        let mut t = ByPart::<u64>::default();
        t[Part::Map] += 3;
        assert_eq!(t.0[4], 3);
        assert!(!Part::Exchange.is_workload() && Part::Map.is_workload());
    }
}
