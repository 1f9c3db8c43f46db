//! What a task of the step graph is: its kind ([`TaskKind`]) and where in the graph run it sits
//! ([`Payload`]: step, rigid-body sub-step), packed into the scheduler's opaque `TaskSpec::payload`.

use crate::physics::parts::Part;
use blockflow_scheduler::TaskSpec;

/// The kinds of task of a step (see the table in the module docs of [`super`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[repr(u8)]
pub enum TaskKind {
    /// Pack the PDFs a receiver in another process needs into message slots.
    Send = 0,
    /// Fill the block's ghost layer (direct copies and unpacked messages).
    Comm = 1,
    /// Walls and particle surfaces (eq. 6) with the momentum exchange (eqs. 7–9).
    Boundary = 2,
    /// Stream and collide, the LBM sweep (eqs. 2–5).
    Sweep = 3,
    /// A rigid-body sub-step of the block: contacts and velocity changes.
    Rb = 4,
    /// The synchronisation after a rigid-body sub-step: integrate, hand over, publish.
    RbSync = 5,
    /// Map the bodies near the block into its overlay (Algorithm 5).
    Map = 6,
    /// Rebuild the cells bodies uncovered (Algorithm 6).
    Reconstruct = 7,
    /// Sum the hydrodynamic forces of the bodies the block published.
    Forces = 8,
    /// `run.no_skip` only: re-derive the static geometry and check it.
    StaticMap = 9,
}

impl TaskKind {
    /// Every kind, in index order.
    pub const ALL: [TaskKind; 10] = [
        TaskKind::Send,
        TaskKind::Comm,
        TaskKind::Boundary,
        TaskKind::Sweep,
        TaskKind::Rb,
        TaskKind::RbSync,
        TaskKind::Map,
        TaskKind::Reconstruct,
        TaskKind::Forces,
        TaskKind::StaticMap,
    ];

    /// Name in outputs (`summary.json`'s `tasks_by_kind`).
    pub fn name(self) -> &'static str {
        match self {
            TaskKind::Send => "send",
            TaskKind::Comm => "comm",
            TaskKind::Boundary => "boundary",
            TaskKind::Sweep => "sweep",
            TaskKind::Rb => "rb",
            TaskKind::RbSync => "rb_sync",
            TaskKind::Map => "map",
            TaskKind::Reconstruct => "reconstruct",
            TaskKind::Forces => "forces",
            TaskKind::StaticMap => "static_map",
        }
    }

    /// The part of the step a task of this kind is timed under.
    pub fn part(self) -> Part {
        match self {
            TaskKind::Send | TaskKind::Comm => Part::Exchange,
            TaskKind::Boundary => Part::Boundary,
            TaskKind::Sweep => Part::Lbm,
            TaskKind::Rb | TaskKind::RbSync | TaskKind::Forces => Part::RigidBody,
            TaskKind::Map | TaskKind::StaticMap => Part::Map,
            TaskKind::Reconstruct => Part::Reconstruct,
        }
    }

    /// Index of the kind.
    pub fn index(self) -> usize {
        self as usize
    }
}

/// One value per [`TaskKind`].
pub type ByKind<V> = [V; 10];

/// Where a task sits in its graph run: its kind, the step inside the run and the rigid-body sub-step
/// inside the step. Packed as bits 0–3 kind, 4–11 sub-step, 12– step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Payload {
    /// The kind.
    pub kind: TaskKind,
    /// Step inside the graph run (0-based).
    pub step: usize,
    /// Rigid-body sub-step inside the step (0 for tasks that are not sub-steps).
    pub sub: usize,
}

impl Payload {
    /// A task of `kind` at step `step` of the run.
    pub fn new(kind: TaskKind, step: usize) -> Self {
        Payload { kind, step, sub: 0 }
    }

    /// A rigid-body sub-step task.
    pub fn sub_step(kind: TaskKind, step: usize, sub: usize) -> Self {
        Payload { kind, step, sub }
    }

    /// The packed form (`TaskSpec::payload`).
    pub fn encode(self) -> u32 {
        debug_assert!(self.sub < 256, "at most 255 sub-steps");
        ((self.step as u32) << 12) | ((self.sub as u32) << 4) | self.kind as u32
    }

    /// The payload of a packed value.
    pub fn decode(bits: u32) -> Self {
        Payload {
            kind: TaskKind::ALL[(bits & 15) as usize],
            sub: ((bits >> 4) & 0xff) as usize,
            step: (bits >> 12) as usize,
        }
    }

    /// The payload of a task.
    pub fn of(spec: &TaskSpec) -> Self {
        Self::decode(spec.payload)
    }
}

/// The task of `kind` at `payload` of block `block`, owned by `owner`, timed under its kind's part.
pub fn spec(owner: u32, block: usize, payload: Payload) -> TaskSpec {
    TaskSpec {
        owner,
        part: payload.kind.part() as u8,
        block: block as u32,
        payload: payload.encode(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn payloads_round_trip() {
        for kind in TaskKind::ALL {
            for (step, sub) in [(0, 0), (3, 9), (4095, 255)] {
                let p = Payload::sub_step(kind, step, sub);
                assert_eq!(Payload::decode(p.encode()), p);
            }
        }
        assert_eq!(TaskKind::Comm.part(), Part::Exchange);
    }
}
