//! Procedural meshes of the stability suite: closed surfaces with shared vertices (icosphere,
//! torus, a cube made of shared-edge triangles), a fan around one vertex, a tessellated plane,
//! slivers and needles, a detailed bumpy sphere (the "teapot" stand-in) and an inward box.
//!
//! Every mesh is indexed with shared vertices, so that neighbouring triangles use bit-identical
//! edge endpoints: a watertight ray-triangle test can then never let a ray through an edge or a
//! vertex. Transforms are evaluated in `f64` and rounded once to `f32`, which is exactly how a
//! translated or scaled scene loses precision in a real file.

use glam::{DVec3, Vec3};

use crate::builtin::Geometry;

/// An indexed triangle mesh (counter-clockwise triangles seen from the side the normal points
/// to; normals are left to [`crate::SceneBuilder`], which averages face normals).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriMesh {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Triangles as indices into `positions`.
    pub indices: Vec<[u32; 3]>,
}

impl TriMesh {
    /// The three corners of triangle `t`.
    pub fn triangle(&self, t: usize) -> [Vec3; 3] {
        self.indices[t].map(|i| self.positions[i as usize])
    }

    /// Each vertex mapped through `f` in `f64`, rounded once to `f32`.
    pub fn map(mut self, f: impl Fn(DVec3) -> DVec3) -> TriMesh {
        for p in &mut self.positions {
            *p = f(p.as_dvec3()).as_vec3();
        }
        self
    }

    /// Scaled by `s` about the origin, then translated by `t` (in `f64`, rounded once).
    pub fn scaled_translated(self, s: f64, t: DVec3) -> TriMesh {
        self.map(|p| p * s + t)
    }

    /// Every edge `(a, b)` with `a < b`, once, in a deterministic order.
    pub fn edges(&self) -> Vec<(u32, u32)> {
        let mut e: Vec<(u32, u32)> = self
            .indices
            .iter()
            .flat_map(|&[a, b, c]| [(a, b), (b, c), (c, a)])
            .map(|(a, b)| (a.min(b), a.max(b)))
            .collect();
        e.sort_unstable();
        e.dedup();
        e
    }

    /// Whether every edge is shared by exactly two triangles with opposite orientation (a
    /// closed, consistently oriented surface).
    pub fn is_closed(&self) -> bool {
        let mut directed: Vec<(u32, u32)> = self
            .indices
            .iter()
            .flat_map(|&[a, b, c]| [(a, b), (b, c), (c, a)])
            .collect();
        directed.sort_unstable();
        let unique = directed.windows(2).all(|w| w[0] != w[1]);
        unique
            && directed
                .iter()
                .all(|&(a, b)| directed.binary_search(&(b, a)).is_ok())
    }

    /// Appends `other`'s triangles (re-indexed).
    pub fn append(&mut self, other: &TriMesh) {
        let base = self.positions.len() as u32;
        self.positions.extend_from_slice(&other.positions);
        self.indices
            .extend(other.indices.iter().map(|t| t.map(|i| i + base)));
    }
}

impl From<Geometry> for TriMesh {
    fn from(g: Geometry) -> TriMesh {
        TriMesh {
            positions: g.positions,
            indices: g.indices,
        }
    }
}

/// A unit icosphere at the origin, subdivided `levels` times (20·4^levels triangles, outward).
pub fn icosphere(levels: u32) -> TriMesh {
    Geometry::icosphere(Vec3::ZERO, 1.0, levels).into()
}

/// A torus around the `z` axis: tube centre circle of radius `major`, tube radius `minor`,
/// `nu` segments around the axis and `nv` around the tube (2·nu·nv triangles, outward, the
/// seams shared).
pub fn torus(major: f64, minor: f64, nu: u32, nv: u32) -> TriMesh {
    let mut m = TriMesh::default();
    for i in 0..nu {
        let u = std::f64::consts::TAU * i as f64 / nu as f64;
        for j in 0..nv {
            let v = std::f64::consts::TAU * j as f64 / nv as f64;
            let r = major + minor * v.cos();
            m.positions
                .push(DVec3::new(r * u.cos(), r * u.sin(), minor * v.sin()).as_vec3());
        }
    }
    let id = |i: u32, j: u32| (i % nu) * nv + (j % nv);
    for i in 0..nu {
        for j in 0..nv {
            let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
            m.indices.extend([[a, b, c], [a, c, d]]);
        }
    }
    m
}

/// The cube `[-1, 1]³` with each face an `n × n` grid of quads (12·n² triangles), every
/// vertex shared by all the faces that meet there (edges and corners included), outward.
pub fn shared_edge_cube(n: u32) -> TriMesh {
    let mut m = TriMesh::default();
    let mut ids = std::collections::BTreeMap::new();
    let coord = |k: u32| -1.0 + 2.0 * k as f64 / n as f64;
    let mut vertex = |m: &mut TriMesh, g: [u32; 3]| -> u32 {
        *ids.entry(g).or_insert_with(|| {
            m.positions
                .push(DVec3::new(coord(g[0]), coord(g[1]), coord(g[2])).as_vec3());
            m.positions.len() as u32 - 1
        })
    };
    // Each face: the fixed axis, its value (0 or n) and the two in-face axes.
    for axis in 0..3 {
        for side in [0, n] {
            let (p, q) = ((axis + 1) % 3, (axis + 2) % 3);
            for i in 0..n {
                for j in 0..n {
                    let g = |di: u32, dj: u32| {
                        let mut g = [0u32; 3];
                        g[axis] = side;
                        g[p] = i + di;
                        g[q] = j + dj;
                        g
                    };
                    let (a, b, c, d) = (
                        vertex(&mut m, g(0, 0)),
                        vertex(&mut m, g(1, 0)),
                        vertex(&mut m, g(1, 1)),
                        vertex(&mut m, g(0, 1)),
                    );
                    // (p, q, axis) is right-handed: p × q points along +axis.
                    if side == n {
                        m.indices.extend([[a, b, c], [a, c, d]]);
                    } else {
                        m.indices.extend([[a, c, b], [a, d, c]]);
                    }
                }
            }
        }
    }
    m
}

/// Rim vertices of [`fan`]: the corners and edge midpoints of the square `[-1, 1]²` in `z = 0`,
/// counter-clockwise, all exactly representable.
pub const FAN_RIM: [[f32; 2]; 8] = [
    [1.0, 0.0],
    [1.0, 1.0],
    [0.0, 1.0],
    [-1.0, 1.0],
    [-1.0, 0.0],
    [-1.0, -1.0],
    [0.0, -1.0],
    [1.0, -1.0],
];

/// Eight triangles around the centre vertex (index 0, the origin) in `z = 0`, facing `+z`:
/// every inner edge is shared by two triangles and the centre by all eight.
pub fn fan() -> TriMesh {
    let mut m = TriMesh {
        positions: vec![Vec3::ZERO],
        indices: Vec::new(),
    };
    m.positions
        .extend(FAN_RIM.iter().map(|&[x, y]| Vec3::new(x, y, 0.0)));
    for k in 0..8u32 {
        m.indices.push([0, 1 + k, 1 + (k + 1) % 8]);
    }
    m
}

/// The square `[-1, 1]²` in `z = 0` as an `n × n` grid of quads (2·n² triangles, shared
/// vertices), facing `+z`.
pub fn grid_plane(n: u32) -> TriMesh {
    let mut m = TriMesh::default();
    for j in 0..=n {
        for i in 0..=n {
            let c = |k: u32| -1.0 + 2.0 * k as f64 / n as f64;
            m.positions.push(DVec3::new(c(i), c(j), 0.0).as_vec3());
        }
    }
    let id = |i: u32, j: u32| j * (n + 1) + i;
    for j in 0..n {
        for i in 0..n {
            let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
            m.indices.extend([[a, b, c], [a, c, d]]);
        }
    }
    m
}

/// The unit square `[0, 1]²` in `z = 0` cut into `n` vertical strips, each split along its
/// diagonal: 2n slivers of aspect ratio about `n`, shared vertices, facing `+z`.
pub fn sliver_square(n: u32) -> TriMesh {
    let mut m = TriMesh::default();
    for i in 0..=n {
        let x = i as f64 / n as f64;
        m.positions.push(DVec3::new(x, 0.0, 0.0).as_vec3());
        m.positions.push(DVec3::new(x, 1.0, 0.0).as_vec3());
    }
    for i in 0..n {
        let (a, b, c, d) = (2 * i, 2 * i + 2, 2 * i + 3, 2 * i + 1);
        m.indices.extend([[a, b, c], [a, c, d]]);
    }
    m
}

/// Needles: `n` triangles fanning from the apex `(length, 0, 0)` to `n + 1` points spread
/// over `y ∈ [-width/2, width/2]` on the `y` axis, in `z = 0`, facing `+z`, shared edges.
pub fn needle_fan(n: u32, length: f64, width: f64) -> TriMesh {
    let mut m = TriMesh {
        positions: vec![DVec3::new(length, 0.0, 0.0).as_vec3()],
        indices: Vec::new(),
    };
    for i in 0..=n {
        let y = width * (i as f64 / n as f64 - 0.5);
        m.positions.push(DVec3::new(0.0, y, 0.0).as_vec3());
    }
    for i in 0..n {
        m.indices.push([0, 2 + i, 1 + i]);
    }
    m
}

/// A detailed closed mesh standing in for a teapot: an icosphere of `levels` subdivisions
/// whose radius is modulated by a few smooth bumps (`amplitude` relative), outward.
pub fn bumpy_sphere(levels: u32, amplitude: f64) -> TriMesh {
    icosphere(levels).map(|p| {
        let d = p.normalize();
        let bump = (5.0 * d.x).sin() * (4.0 * d.y).cos() + 0.5 * (7.0 * d.z).sin();
        d * (1.0 + amplitude * bump)
    })
}

/// The box from `min` to `max` with inward-facing faces (12 triangles, shared corners).
pub fn inward_box(min: Vec3, max: Vec3) -> TriMesh {
    let centre = (min + max).as_dvec3() * 0.5;
    let half = (max - min).as_dvec3() * 0.5;
    let mut m = shared_edge_cube(1).map(|p| centre + p * half);
    for t in &mut m.indices {
        t.swap(1, 2);
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closed_meshes_are_closed() {
        assert!(icosphere(2).is_closed());
        assert!(torus(1.0, 0.3, 12, 8).is_closed());
        let cube = shared_edge_cube(4);
        assert!(cube.is_closed());
        assert_eq!(cube.indices.len(), 12 * 16);
        // V - E + F = 2 for a sphere, 0 for a torus.
        let chi = |m: &TriMesh| {
            m.positions.len() as i64 - m.edges().len() as i64 + m.indices.len() as i64
        };
        assert_eq!(chi(&cube), 2);
        assert_eq!(chi(&torus(1.0, 0.3, 12, 8)), 0);
        assert!(inward_box(Vec3::splat(-2.0), Vec3::splat(3.0)).is_closed());
        assert!(bumpy_sphere(2, 0.1).is_closed());
        // Open meshes are not.
        assert!(!fan().is_closed());
        assert!(!grid_plane(2).is_closed());
    }

    #[test]
    fn orientation_is_outward_or_up() {
        let outward = |m: &TriMesh, centre: Vec3| {
            (0..m.indices.len()).all(|t| {
                let [a, b, c] = m.triangle(t);
                (b - a).cross(c - a).dot((a + b + c) / 3.0 - centre) > 0.0
            })
        };
        assert!(outward(&shared_edge_cube(3), Vec3::ZERO));
        assert!(outward(&icosphere(1), Vec3::ZERO));
        assert!(!outward(&inward_box(-Vec3::ONE, Vec3::ONE), Vec3::ZERO));
        for m in [
            fan(),
            grid_plane(3),
            sliver_square(8),
            needle_fan(5, 10.0, 1.0),
        ] {
            for t in 0..m.indices.len() {
                let [a, b, c] = m.triangle(t);
                assert!((b - a).cross(c - a).z > 0.0, "triangle {t} faces down");
            }
        }
    }

    #[test]
    fn slivers_cover_the_square() {
        let m = sliver_square(64);
        let area: f64 = (0..m.indices.len())
            .map(|t| {
                let [a, b, c] = m.triangle(t).map(|p| p.as_dvec3());
                (b - a).cross(c - a).length() / 2.0
            })
            .sum();
        assert!((area - 1.0).abs() < 1e-9, "{area}");
    }

    #[test]
    fn transforms_round_once() {
        let m = grid_plane(1).scaled_translated(2.0, DVec3::new(1e7, 0.0, 0.0));
        assert_eq!(m.positions[0], Vec3::new(1e7 - 2.0, -2.0, 0.0));
    }
}
