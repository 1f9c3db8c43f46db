//! Scene geometry voxelised into cell flags: the domain's wall faces (non-periodic axes) and planes of any
//! orientation (half-spaces), each resting or moving tangentially.

use crate::physics::domain::DomainSpec;

/// Cell flag bits.
pub mod flags {
    /// A fluid cell (computed).
    pub const FLUID: u8 = 1;
    /// A fluid cell with at least one wall neighbour (has bounce-back links).
    pub const NEAR_BOUNDARY: u8 = 2;
    /// A resting wall cell next to fluid (simple bounce-back).
    pub const NOSLIP: u8 = 4;
    /// A moving wall cell next to fluid (bounce-back with the wall's momentum).
    pub const MOVING_WALL: u8 = 8;
    /// A solid cell with no fluid neighbour: never computed nor read.
    pub const OUTSIDE: u8 = 16;
    /// A cell covered by a particle (VTK output only; the overlay of `coupling` holds the owners).
    pub const PARTICLE: u8 = 32;
}

/// A half-space boundary: cells whose centre x satisfies `normal · x < offset` are solid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WallPlane {
    /// Unit normal pointing into the fluid.
    pub normal: [f64; 3],
    /// Signed distance of the plane from the origin along `normal` (cells).
    pub offset: f64,
    /// Tangential velocity of the wall (lattice units); zero for a resting wall.
    pub velocity: [f64; 3],
}

impl WallPlane {
    /// A plane through `point` with normal `normal` (normalised here) pointing into the fluid.
    pub fn through(point: [f64; 3], normal: [f64; 3], velocity: [f64; 3]) -> Option<WallPlane> {
        let len = (normal[0] * normal[0] + normal[1] * normal[1] + normal[2] * normal[2]).sqrt();
        if len.is_nan() || len <= 0.0 || !len.is_finite() {
            return None;
        }
        let n = [normal[0] / len, normal[1] / len, normal[2] / len];
        Some(WallPlane {
            normal: n,
            offset: n[0] * point[0] + n[1] * point[1] + n[2] * point[2],
            velocity,
        })
    }

    /// An axis-aligned wall at coordinate `position` (cells, may be fractional) along `axis`; `lower`
    /// keeps the fluid above it (solid below), otherwise below it.
    pub fn axis_wall(axis: usize, position: f64, lower: bool) -> WallPlane {
        let mut n = [0.0; 3];
        n[axis] = if lower { 1.0 } else { -1.0 };
        WallPlane {
            normal: n,
            offset: if lower { position } else { -position },
            velocity: [0.0; 3],
        }
    }

    /// Whether a point lies on the solid side.
    pub fn solid(&self, x: [f64; 3]) -> bool {
        self.normal[0] * x[0] + self.normal[1] * x[1] + self.normal[2] * x[2] < self.offset
    }
}

/// The boundary of the domain along one non-periodic face.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FaceWall {
    /// Wall velocity (zero: resting no-slip wall).
    pub velocity: [f64; 3],
}

/// Everything that decides whether a cell is fluid or wall.
#[derive(Clone, Debug, Default)]
pub struct Geometry {
    /// Walls at the low and high face of each axis; used only on non-periodic axes (absent: resting wall).
    pub faces: [[Option<FaceWall>; 2]; 3],
    /// Planes (half-spaces) cutting into the domain.
    pub planes: Vec<WallPlane>,
    /// No fluid anywhere (`fluid.enabled = false`): every cell is solid, blocks get no fluid work.
    pub no_fluid: bool,
}

/// What a cell is, before neighbourhood flags are added.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CellKind {
    /// Fluid.
    Fluid,
    /// Wall with the given velocity.
    Wall([f64; 3]),
}

impl Geometry {
    /// Classifies global cell `g` (may lie in the ghost layer outside the domain). Outside a non-periodic
    /// face the cell is that face's wall (moving faces win at edges and corners, so a lid covers its whole
    /// plane and the moving-wall terms cancel in pairs: mass stays exact); inside, the first plane that
    /// claims the cell centre decides.
    pub fn classify(&self, d: &DomainSpec, g: [i64; 3]) -> CellKind {
        if self.no_fluid {
            return CellKind::Wall([0.0; 3]);
        }
        let g = d.wrap(g);
        let n = d.cells();
        let mut wall: Option<[f64; 3]> = None;
        for a in 0..3 {
            let side = if g[a] < 0 {
                0
            } else if g[a] >= n[a] as i64 {
                1
            } else {
                continue;
            };
            let v = self.faces[a][side].map_or([0.0; 3], |f| f.velocity);
            wall = Some(match wall {
                Some(w) if w != [0.0; 3] => w,
                _ => v,
            });
        }
        if let Some(v) = wall {
            return CellKind::Wall(v);
        }
        let c = [g[0] as f64 + 0.5, g[1] as f64 + 0.5, g[2] as f64 + 0.5];
        for p in &self.planes {
            if p.solid(c) {
                return CellKind::Wall(p.velocity);
            }
        }
        CellKind::Fluid
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn planes_and_faces() {
        let d = DomainSpec {
            blocks: [1, 1, 1],
            block_size: [10, 10, 10],
            periodic: [true, false, false],
        };
        let mut g = Geometry::default();
        g.faces[1][1] = Some(FaceWall {
            velocity: [0.1, 0.0, 0.0],
        });
        g.planes.push(WallPlane::axis_wall(2, 7.5, false)); // top wall at z = 7.5
        g.planes
            .push(WallPlane::through([0.0, 0.0, 2.0], [1.0, 0.0, 1.0], [0.0; 3]).unwrap());
        assert_eq!(g.classify(&d, [-1, 3, 3]), CellKind::Fluid); // periodic x
        assert_eq!(g.classify(&d, [3, -1, 3]), CellKind::Wall([0.0; 3]));
        assert_eq!(g.classify(&d, [3, 10, 3]), CellKind::Wall([0.1, 0.0, 0.0]));
        assert_eq!(g.classify(&d, [3, 10, -1]), CellKind::Wall([0.1, 0.0, 0.0])); // lid wins the edge
        assert_eq!(g.classify(&d, [3, 3, 8]), CellKind::Wall([0.0; 3])); // centre 8.5 beyond z = 7.5
        assert_eq!(g.classify(&d, [3, 3, 7]), CellKind::Fluid); // centre 7.5 on the plane: fluid
        assert_eq!(g.classify(&d, [0, 3, 0]), CellKind::Wall([0.0; 3])); // (x + z)/√2 = 0.71 < 1.41
        assert_eq!(g.classify(&d, [3, 3, 3]), CellKind::Fluid);
    }
}
