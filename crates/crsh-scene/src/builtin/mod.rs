//! Built-in procedural scenes that need no files, and the geometry helpers they share.
//!
//! - [`cornell_mirrors`]: the thesis's CORNELL — an icosphere inside a closed box of six
//!   mirror walls, one point light (reflection-heavy).
//! - [`office_boxes`]: a deterministic procedural office with ~140 separate meshes and two
//!   lights (shadow-ray work), plus one glass and one mirror object.
//!
//! - `cornell-mirrors-animated`: `cornell-mirrors` with a spinning, bouncing cube, a waving
//!   flag and a twisting column ([`CORNELL_MIRRORS_ANIMATED`], a manifest of built-in shapes:
//!   see [`crate::animation`]).
//! - [`glass_sphere`]: seed 004 §7's refractive object that fills the whole view — a clear
//!   glass UV sphere in a box of diffuse walls (refraction-heavy). `glass-sphere` has 5000
//!   object triangles; `glass-sphere-N` exactly `N` (even, 8..=200000, `N/2 = s·(t−1)` with
//!   `s ≥ 3`, `t − 1 ≥ 2`), e.g. the paper's `glass-sphere-100`, `-500`, `-1000`. [`NAMES`]
//!   lists only the parameterless name; [`is_name`] and [`PATTERNS`] cover the sized ones.
//! - [`glass_shell`]: the same corridor, camera and light around a hollow glass sphere (outer
//!   radius 1, concentric cavity of radius 0.6), so paths refract up to 4 times and 27.5 % of
//!   them are totally internally reflected. `glass-shell` has 5000 object triangles (2500 per
//!   sphere); `glass-shell-N` exactly `N` (a multiple of 4, 16..=200000, `N/4 = s·(t−1)`).
//!
//! Every built-in is deterministic: the same arrays on every call and machine.

pub mod cornell_mirrors;
pub mod glass_shell;
pub mod glass_sphere;
pub mod office_boxes;

use std::path::Path;

use glam::Vec3;

use crate::animation::AnimatedScene;
use crate::error::SceneError;
use crate::manifest::Manifest;
use crate::model::{Scene, SceneBuilder};

/// Names of the parameterless built-in scenes, as accepted by [`build`] and [`crate::load`].
/// The sized forms of [`PATTERNS`] (`glass-sphere-N`, `glass-shell-N`) are accepted too:
/// [`is_name`].
pub const NAMES: &[&str] = &[
    "cornell-mirrors",
    "office-boxes",
    "cornell-mirrors-animated",
    "glass-sphere",
    "glass-shell",
];

/// The parameterless built-ins that never move (a manifest may `extends` them, and the sized
/// forms of [`PATTERNS`], which never move either: [`is_static`]).
pub const STATIC_NAMES: &[&str] = &[
    "cornell-mirrors",
    "office-boxes",
    "glass-sphere",
    "glass-shell",
];

/// The parameterized built-in names, for listings: the pattern and what it means.
pub const PATTERNS: &[(&str, &str)] = &[
    (
        "glass-sphere-N",
        "glass-sphere with exactly N object triangles (N even, 8..=200000, N/2 = s*(t-1), \
         s >= 3, t-1 >= 2; seed 004's 100, 500, 1000, 5000)",
    ),
    (
        "glass-shell-N",
        "glass-shell with exactly N object triangles, N/2 per sphere (N a multiple of 4, \
         16..=200000, N/4 = s*(t-1), s >= 3, t-1 >= 2; seed 004's 100, 500, 1000, 5000)",
    ),
];

/// Whether `name` names a built-in scene: one of [`NAMES`] or a `glass-sphere-N` or
/// `glass-shell-N` (well-formed or not: [`build`] refuses a bad `N` with an error that names
/// the allowed values, rather than the caller treating it as a file).
pub fn is_name(name: &str) -> bool {
    NAMES.contains(&name) || is_sized(name)
}

/// Whether `name` is one of the sized built-ins of [`PATTERNS`] (or its parameterless form).
fn is_sized(name: &str) -> bool {
    glass_sphere::is_name(name) || glass_shell::is_name(name)
}

/// Whether `name` names a built-in scene that never moves ([`STATIC_NAMES`], a
/// `glass-sphere-N` or a `glass-shell-N`), which a manifest may `extends`.
pub fn is_static(name: &str) -> bool {
    STATIC_NAMES.contains(&name) || is_sized(name)
}

/// The manifest of `cornell-mirrors-animated`: the built-in `cornell-mirrors` plus a cube that
/// spins and bounces (rigid: rotation and keyframes), a flag that waves and a column that
/// twists (deforming: every vertex moves relative to the others).
pub const CORNELL_MIRRORS_ANIMATED: &str = include_str!("cornell_mirrors_animated.toml");

/// The builder of the static built-in `name` (one of [`STATIC_NAMES`], `glass-sphere-N` or
/// `glass-shell-N`).
pub fn builder(name: &str) -> Result<SceneBuilder, SceneError> {
    match name {
        "cornell-mirrors" => Ok(cornell_mirrors::builder()),
        "office-boxes" => Ok(office_boxes::builder()),
        _ if glass_sphere::is_name(name) => glass_sphere::builder_named(name),
        _ if glass_shell::is_name(name) => glass_shell::builder_named(name),
        _ => Err(unknown(name)),
    }
}

fn unknown(name: &str) -> SceneError {
    let patterns: Vec<&str> = PATTERNS.iter().map(|(p, _)| *p).collect();
    SceneError::invalid(
        format!("built-in scene '{name}'"),
        format!(
            "unknown (built-ins: {}, {})",
            NAMES.join(", "),
            patterns.join(", ")
        ),
    )
}

/// Builds the built-in scene `name` (one of [`NAMES`] or [`PATTERNS`], see [`is_name`]; an
/// animated one at frame 0).
pub fn build(name: &str) -> Result<Scene, SceneError> {
    build_with_warnings(name).map(|(s, _)| s)
}

/// [`build`], also returning the (normally empty) build warnings.
pub fn build_with_warnings(name: &str) -> Result<(Scene, Vec<String>), SceneError> {
    animated_with_warnings(name).map(|(a, w)| (a.into_scene(), w))
}

/// The built-in scene `name` as an animated scene (one that never moves for the static ones).
pub fn animated_with_warnings(name: &str) -> Result<(AnimatedScene, Vec<String>), SceneError> {
    if name == "cornell-mirrors-animated" {
        let path = Path::new("cornell-mirrors-animated.toml");
        let manifest = Manifest::parse(CORNELL_MIRRORS_ANIMATED, path)?;
        return crate::manifest::build_animated(&manifest, path);
    }
    let (scene, warnings) = builder(name)?.build_with_warnings(name)?;
    Ok((AnimatedScene::fixed(scene), warnings))
}

/// Indexed triangle geometry with per-vertex normals.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct Geometry {
    pub(crate) positions: Vec<Vec3>,
    pub(crate) normals: Vec<Vec3>,
    pub(crate) indices: Vec<[u32; 3]>,
}

impl Geometry {
    /// Appends a planar quad `a, b, c, d` (counter-clockwise seen from the side its normal
    /// points to) with flat normal `(b - a) × (c - a)`.
    pub(crate) fn quad(&mut self, a: Vec3, b: Vec3, c: Vec3, d: Vec3) {
        let n = (b - a).cross(c - a).normalize();
        let base = self.positions.len() as u32;
        self.positions.extend([a, b, c, d]);
        self.normals.extend([n; 4]);
        self.indices
            .extend([[base, base + 1, base + 2], [base, base + 2, base + 3]]);
    }

    /// Appends the planar quad `a, b, c, d` (a cycle around its edge) wound so that its
    /// normal points along `facing`.
    pub(crate) fn quad_facing(&mut self, a: Vec3, b: Vec3, c: Vec3, d: Vec3, facing: Vec3) {
        if (b - a).cross(c - a).dot(facing) >= 0.0 {
            self.quad(a, b, c, d);
        } else {
            self.quad(a, d, c, b);
        }
    }

    /// An axis-aligned box from `min` to `max`, faces outward, flat normals (24 vertices,
    /// 12 triangles).
    pub(crate) fn cuboid(min: Vec3, max: Vec3) -> Geometry {
        let mut g = Geometry::default();
        let (x0, y0, z0) = (min.x, min.y, min.z);
        let (x1, y1, z1) = (max.x, max.y, max.z);
        let v = Vec3::new;
        g.quad(v(x1, y0, z0), v(x1, y1, z0), v(x1, y1, z1), v(x1, y0, z1)); // +x
        g.quad(v(x0, y0, z0), v(x0, y0, z1), v(x0, y1, z1), v(x0, y1, z0)); // -x
        g.quad(v(x0, y1, z0), v(x0, y1, z1), v(x1, y1, z1), v(x1, y1, z0)); // +y
        g.quad(v(x0, y0, z0), v(x1, y0, z0), v(x1, y0, z1), v(x0, y0, z1)); // -y
        g.quad(v(x0, y0, z1), v(x1, y0, z1), v(x1, y1, z1), v(x0, y1, z1)); // +z
        g.quad(v(x0, y0, z0), v(x0, y1, z0), v(x1, y1, z0), v(x1, y0, z0)); // -z
        g
    }

    /// The cube `[-1, 1]³`, each face split into `n × n` quads, faces outward, flat normals.
    pub(crate) fn subdivided_box(n: u32) -> Geometry {
        let mut g = Geometry::default();
        let n = n.max(1);
        let step = 2.0 / n as f32;
        for axis in 0..3 {
            for sign in [-1.0f32, 1.0] {
                let normal =
                    Vec3::from_array(std::array::from_fn(|k| if k == axis { sign } else { 0.0 }));
                let (u, v) = (
                    Vec3::from_array(std::array::from_fn(|k| {
                        f32::from(u8::from(k == (axis + 1) % 3))
                    })),
                    Vec3::from_array(std::array::from_fn(|k| {
                        f32::from(u8::from(k == (axis + 2) % 3))
                    })),
                );
                for i in 0..n {
                    for j in 0..n {
                        let corner = |a: u32, b: u32| {
                            normal + u * (-1.0 + step * a as f32) + v * (-1.0 + step * b as f32)
                        };
                        g.quad_facing(
                            corner(i, j),
                            corner(i + 1, j),
                            corner(i + 1, j + 1),
                            corner(i, j + 1),
                            normal,
                        );
                    }
                }
            }
        }
        g
    }

    /// The square `[-1, 1]²` of the `xz` plane (`y = 0`) facing `+y`, as `n × n` quads with
    /// shared vertices (so a deformation keeps it closed).
    pub(crate) fn grid(n: u32) -> Geometry {
        let n = n.max(1);
        let mut g = Geometry::default();
        let step = 2.0 / n as f32;
        for j in 0..=n {
            for i in 0..=n {
                g.positions.push(Vec3::new(
                    -1.0 + step * i as f32,
                    0.0,
                    -1.0 + step * j as f32,
                ));
                g.normals.push(Vec3::Y);
            }
        }
        let id = |i: u32, j: u32| j * (n + 1) + i;
        for j in 0..n {
            for i in 0..n {
                // Counter-clockwise seen from +y.
                g.indices.push([id(i, j), id(i, j + 1), id(i + 1, j + 1)]);
                g.indices.push([id(i, j), id(i + 1, j + 1), id(i + 1, j)]);
            }
        }
        g
    }

    /// An icosphere: the icosahedron subdivided `levels` times (20·4^levels triangles),
    /// projected on the sphere, with smooth (radial) normals, outward winding.
    pub(crate) fn icosphere(center: Vec3, radius: f32, levels: u32) -> Geometry {
        let t = (1.0 + 5f32.sqrt()) / 2.0;
        let mut verts: Vec<Vec3> = [
            (-1.0, t, 0.0),
            (1.0, t, 0.0),
            (-1.0, -t, 0.0),
            (1.0, -t, 0.0),
            (0.0, -1.0, t),
            (0.0, 1.0, t),
            (0.0, -1.0, -t),
            (0.0, 1.0, -t),
            (t, 0.0, -1.0),
            (t, 0.0, 1.0),
            (-t, 0.0, -1.0),
            (-t, 0.0, 1.0),
        ]
        .iter()
        .map(|&(x, y, z)| Vec3::new(x, y, z).normalize())
        .collect();
        let mut faces: Vec<[u32; 3]> = vec![
            [0, 11, 5],
            [0, 5, 1],
            [0, 1, 7],
            [0, 7, 10],
            [0, 10, 11],
            [1, 5, 9],
            [5, 11, 4],
            [11, 10, 2],
            [10, 7, 6],
            [7, 1, 8],
            [3, 9, 4],
            [3, 4, 2],
            [3, 2, 6],
            [3, 6, 8],
            [3, 8, 9],
            [4, 9, 5],
            [2, 4, 11],
            [6, 2, 10],
            [8, 6, 7],
            [9, 8, 1],
        ];
        for _ in 0..levels {
            // Midpoints keyed by the sorted edge, in a BTreeMap for determinism.
            let mut mid = std::collections::BTreeMap::new();
            let mut midpoint = |a: u32, b: u32, verts: &mut Vec<Vec3>| -> u32 {
                *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                    verts.push(((verts[a as usize] + verts[b as usize]) * 0.5).normalize());
                    verts.len() as u32 - 1
                })
            };
            let mut next = Vec::with_capacity(faces.len() * 4);
            for &[a, b, c] in &faces {
                let ab = midpoint(a, b, &mut verts);
                let bc = midpoint(b, c, &mut verts);
                let ca = midpoint(c, a, &mut verts);
                next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
            }
            faces = next;
        }
        Geometry {
            positions: verts.iter().map(|&n| center + n * radius).collect(),
            normals: verts,
            indices: faces,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cuboid_faces_point_outward() {
        let g = Geometry::cuboid(Vec3::ZERO, Vec3::ONE);
        assert_eq!((g.positions.len(), g.indices.len()), (24, 12));
        for &[a, b, c] in &g.indices {
            let (pa, pb, pc) = (
                g.positions[a as usize],
                g.positions[b as usize],
                g.positions[c as usize],
            );
            let n = (pb - pa).cross(pc - pa);
            let out = (pa + pb + pc) / 3.0 - Vec3::splat(0.5);
            assert!(n.dot(out) > 0.0, "inward face");
            assert!(n.normalize().dot(g.normals[a as usize]) > 0.999);
        }
    }

    #[test]
    fn icosphere_is_closed_and_outward() {
        let g = Geometry::icosphere(Vec3::new(1.0, 2.0, 3.0), 2.0, 2);
        assert_eq!(g.indices.len(), 320);
        assert_eq!(g.positions.len(), 162); // V - E + F = 2
        for &[a, b, c] in &g.indices {
            let (pa, pb, pc) = (
                g.positions[a as usize],
                g.positions[b as usize],
                g.positions[c as usize],
            );
            let n = (pb - pa).cross(pc - pa);
            assert!(n.dot(pa - Vec3::new(1.0, 2.0, 3.0)) > 0.0);
        }
        for p in &g.positions {
            assert!((p.distance(Vec3::new(1.0, 2.0, 3.0)) - 2.0).abs() < 1e-5);
        }
    }

    #[test]
    fn unknown_builtin_lists_the_names() {
        let e = build("nope").unwrap_err().to_string();
        assert!(
            e.contains("cornell-mirrors")
                && e.contains("office-boxes")
                && e.contains("glass-sphere, glass-shell, glass-sphere-N, glass-shell-N"),
            "{e}"
        );
    }
}
