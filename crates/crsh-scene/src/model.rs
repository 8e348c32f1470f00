//! The compact scene model.

use crsh_core::{Aabb, Sphere};
use glam::Vec3;
use serde::{Deserialize, Serialize};

use crate::bounding;
use crate::error::SceneError;

/// A Phong material with Whitted reflection / refraction weights.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Material {
    /// Name (from the MTL, or the built-in scene).
    pub name: String,
    /// Diffuse colour (Kd).
    pub diffuse: Vec3,
    /// Specular colour (Ks).
    pub specular: Vec3,
    /// Phong exponent (Ns).
    pub shininess: f32,
    /// Mirror weight in `[0, 1]`.
    pub reflectivity: f32,
    /// Refraction weight in `[0, 1]`.
    pub transparency: f32,
    /// Index of refraction (Ni), ≥ 1 for transparent materials.
    pub ior: f32,
}

impl Default for Material {
    fn default() -> Material {
        Material {
            name: "default".into(),
            diffuse: Vec3::splat(0.8),
            specular: Vec3::ZERO,
            shininess: 1.0,
            reflectivity: 0.0,
            transparency: 0.0,
            ior: 1.0,
        }
    }
}

/// A point light (seed 000 eq. 3.19).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Light {
    /// Position.
    pub position: Vec3,
    /// Colour.
    pub color: Vec3,
    /// Scalar intensity.
    pub intensity: f32,
    /// Constant, linear and quadratic attenuation coefficients (eq. 3.19c).
    pub attenuation: [f32; 3],
}

impl Light {
    /// The attenuation factor at `distance` (eq. 3.19c): `1 / (c + l·d + q·d²)`.
    pub fn attenuation_at(&self, distance: f32) -> f32 {
        let [c, l, q] = self.attenuation;
        1.0 / (c + l * distance + q * distance * distance)
    }
}

/// A pinhole camera.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    /// Eye position.
    pub eye: Vec3,
    /// Point looked at.
    pub target: Vec3,
    /// Up hint.
    pub up: Vec3,
    /// Vertical field of view in degrees.
    pub vfov_deg: f32,
    /// Width / height the camera was framed for; `None`: use the image's.
    pub aspect: Option<f32>,
}

impl Camera {
    /// Orthonormal basis `(right, up, forward)`; forward points from eye to target.
    pub fn basis(&self) -> (Vec3, Vec3, Vec3) {
        let f = (self.target - self.eye).normalize();
        let r = f.cross(self.up).normalize();
        let u = r.cross(f);
        (r, u, f)
    }

    /// The unit direction through the point `(sx, sy)` of the image plane, in pixel units of a
    /// `width × height` image (`(0, 0)` is the top-left corner, `(width, height)` bottom-right;
    /// pixel centres are at `+0.5`). Uses `aspect` when set, else `width / height`.
    pub fn direction(&self, sx: f32, sy: f32, width: u32, height: u32) -> Vec3 {
        let (r, u, f) = self.basis();
        let aspect = self.aspect.unwrap_or(width as f32 / height as f32);
        let tan_half = (self.vfov_deg.to_radians() * 0.5).tan();
        let ndc_x = (2.0 * sx / width as f32 - 1.0) * tan_half * aspect;
        let ndc_y = (1.0 - 2.0 * sy / height as f32) * tan_half;
        (f + r * ndc_x + u * ndc_y).normalize()
    }
}

/// A mesh: a contiguous range of triangles (the thesis's per-mesh bounding spheres cull
/// whole meshes, §3.2.8).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Mesh {
    /// Name (OBJ object/group name, or the built-in part).
    pub name: String,
    /// First triangle id.
    pub first_tri: u32,
    /// Number of triangles.
    pub tri_count: u32,
    /// Exact minimal bounding sphere of the mesh's vertices.
    pub sphere: Sphere,
    /// Axis-aligned bounds.
    pub aabb: Aabb,
}

/// A scene: flat arrays, no graph.
#[derive(Clone, Debug)]
pub struct Scene {
    /// Name used in reports.
    pub name: String,
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Per-vertex unit normals (computed, area-weighted, when the source has none).
    pub normals: Vec<Vec3>,
    /// Vertex indices per triangle.
    pub indices: Vec<[u32; 3]>,
    /// Mesh id per triangle.
    pub tri_mesh: Vec<u32>,
    /// Material id per triangle.
    pub tri_material: Vec<u32>,
    /// Bounding sphere per triangle (minimal).
    pub tri_spheres: Vec<Sphere>,
    /// Meshes; their triangle ranges tile `0..indices.len()` in order.
    pub meshes: Vec<Mesh>,
    /// Materials.
    pub materials: Vec<Material>,
    /// Point lights.
    pub lights: Vec<Light>,
    /// Camera.
    pub camera: Camera,
    /// Bounds of all vertices.
    pub bounds: Aabb,
    /// Number of zero-area triangles (kept, never hit).
    pub degenerate_triangles: usize,
}

impl Scene {
    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.indices.len()
    }

    /// The three vertices of triangle `t`.
    pub fn triangle(&self, t: usize) -> [Vec3; 3] {
        let [a, b, c] = self.indices[t];
        [
            self.positions[a as usize],
            self.positions[b as usize],
            self.positions[c as usize],
        ]
    }

    /// The material of triangle `t`.
    pub fn material_of(&self, t: usize) -> &Material {
        &self.materials[self.tri_material[t] as usize]
    }
}

/// Collects meshes one at a time and builds a validated [`Scene`].
#[derive(Clone, Debug, Default)]
pub struct SceneBuilder {
    name: String,
    positions: Vec<Vec3>,
    normals: Vec<Option<Vec3>>,
    indices: Vec<[u32; 3]>,
    tri_material: Vec<u32>,
    mesh_ranges: Vec<(String, u32, u32)>,
    materials: Vec<Material>,
    lights: Vec<Light>,
    camera: Option<Camera>,
}

impl SceneBuilder {
    /// An empty builder for a scene called `name`.
    pub fn new(name: impl Into<String>) -> SceneBuilder {
        SceneBuilder {
            name: name.into(),
            ..Default::default()
        }
    }

    /// Adds a material and returns its id.
    pub fn material(&mut self, m: Material) -> u32 {
        self.materials.push(m);
        (self.materials.len() - 1) as u32
    }

    /// Adds a light.
    pub fn light(&mut self, l: Light) -> &mut Self {
        self.lights.push(l);
        self
    }

    /// Sets the camera.
    pub fn camera(&mut self, c: Camera) -> &mut Self {
        self.camera = Some(c);
        self
    }

    /// Adds a mesh: `positions` and optional per-vertex `normals` (same length), `indices`
    /// into them, and one material id for all of its triangles.
    pub fn mesh(
        &mut self,
        name: impl Into<String>,
        positions: &[Vec3],
        normals: Option<&[Vec3]>,
        indices: &[[u32; 3]],
        material: u32,
    ) -> &mut Self {
        let base = self.positions.len() as u32;
        self.positions.extend_from_slice(positions);
        match normals {
            Some(n) => self.normals.extend(n.iter().map(|&v| Some(v))),
            None => self.normals.extend(positions.iter().map(|_| None)),
        }
        let first = self.indices.len() as u32;
        self.indices
            .extend(indices.iter().map(|t| [t[0] + base, t[1] + base, t[2] + base]));
        self.tri_material.extend(indices.iter().map(|_| material));
        self.mesh_ranges
            .push((name.into(), first, indices.len() as u32));
        self
    }

    /// Validates everything and builds the scene: indices in range, finite coordinates, at
    /// least one triangle, material ids valid; computes missing normals, bounding volumes and
    /// the degenerate-triangle count. `context` names the source (file) in errors.
    pub fn build(self, context: &str) -> Result<Scene, SceneError> {
        let _ = (&bounding::min_sphere, context);
        unimplemented!("SceneBuilder::build: being written")
    }
}
