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
    /// Emitted radiance (MTL `Ke`): marks the surface of an emitter (e.g. the Cornell box's
    /// ceiling lamp). It is not a light source: lights are the scene's point [`Light`]s, and a
    /// shader may add this term to what the surface shows. Zero for ordinary materials.
    #[serde(default)]
    pub emission: Vec3,
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
            emission: Vec3::ZERO,
        }
    }
}

impl Material {
    /// Whether the material reflects mirror rays (reflectivity > 0).
    pub fn is_mirror(&self) -> bool {
        self.reflectivity > 0.0
    }

    /// Whether the material refracts rays (transparency > 0).
    pub fn is_transparent(&self) -> bool {
        self.transparency > 0.0
    }

    /// Whether the surface emits (`emission` not zero).
    pub fn is_emitter(&self) -> bool {
        self.emission.max_element() > 0.0
    }

    /// Checks that every value is finite and in range: colours ≥ 0, shininess ≥ 0,
    /// reflectivity and transparency in `[0, 1]`, ior > 0. The error message names the
    /// material and the offending value.
    pub fn validate(&self) -> Result<(), String> {
        let name = &self.name;
        for (what, v) in [
            ("diffuse", self.diffuse),
            ("specular", self.specular),
            ("emission", self.emission),
        ] {
            if !v.is_finite() || v.min_element() < 0.0 {
                return Err(format!(
                    "material '{name}': {what} {v} must be finite and non-negative"
                ));
            }
        }
        if !self.shininess.is_finite() || self.shininess < 0.0 {
            return Err(format!(
                "material '{name}': shininess {} must be finite and non-negative",
                self.shininess
            ));
        }
        for (what, v) in [
            ("reflectivity", self.reflectivity),
            ("transparency", self.transparency),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return Err(format!("material '{name}': {what} {v} is outside [0, 1]"));
            }
        }
        if !self.ior.is_finite() || self.ior <= 0.0 {
            return Err(format!(
                "material '{name}': index of refraction {} must be finite and positive",
                self.ior
            ));
        }
        Ok(())
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
    /// Radius of the light's sphere, for soft shadows (seed 003 §5): the disc that
    /// `shadow = samples` rays sample and the `R` of the edge-width occlusion (eq. 5.1).
    /// 0 (the default) is a point light: every shadow variant gives hard shadows.
    #[serde(default)]
    pub radius: f32,
}

impl Light {
    /// The attenuation factor at `distance` (eq. 3.19c): `1 / (c + l·d + q·d²)`.
    pub fn attenuation_at(&self, distance: f32) -> f32 {
        let [c, l, q] = self.attenuation;
        1.0 / (c + l * distance + q * distance * distance)
    }

    /// Checks that the light is usable: finite position, non-negative finite colour and
    /// intensity, non-negative attenuation coefficients with a positive constant term (so the
    /// factor of eq. 3.19c stays finite at every distance).
    pub fn validate(&self) -> Result<(), String> {
        if !self.position.is_finite() {
            return Err(format!("light position {} is not finite", self.position));
        }
        if !self.color.is_finite() || self.color.min_element() < 0.0 {
            return Err(format!(
                "light color {} must be finite and non-negative",
                self.color
            ));
        }
        if !self.intensity.is_finite() || self.intensity < 0.0 {
            return Err(format!(
                "light intensity {} must be finite and non-negative",
                self.intensity
            ));
        }
        if !self.radius.is_finite() || self.radius < 0.0 {
            return Err(format!(
                "light radius {} must be finite and non-negative (0: a point light)",
                self.radius
            ));
        }
        let [c, l, q] = self.attenuation;
        if ![c, l, q].iter().all(|v| v.is_finite() && *v >= 0.0) || c <= 0.0 {
            return Err(format!(
                "light attenuation {:?} needs finite non-negative coefficients and a positive \
                 constant term",
                self.attenuation
            ));
        }
        Ok(())
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

/// The narrowest vertical field of view a camera may have, in degrees: at
/// [`crsh_core::pipeline::MAX_IMAGE_SIDE`] pixels the rays of neighbouring pixels then still
/// differ by about one unit in the last place of a single-precision direction.
pub const MIN_VFOV_DEG: f32 = 0.1;

/// The widest vertical field of view a camera may have, in degrees (a pinhole camera's image
/// plane grows as `tan(vfov / 2)`, infinite at 180°).
pub const MAX_VFOV_DEG: f32 = 179.0;

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
    /// pixel centres are at `+0.5`). Pixels are square: the horizontal extent follows from the
    /// vertical field of view and `width / height`; [`Camera::aspect`] does not stretch the
    /// image, it only suggests the image shape ([`Camera::height_for`]).
    pub fn direction(&self, sx: f32, sy: f32, width: u32, height: u32) -> Vec3 {
        let (r, u, f) = self.basis();
        let aspect = width as f32 / height as f32;
        let tan_half = (self.vfov_deg.to_radians() * 0.5).tan();
        let ndc_x = (2.0 * sx / width as f32 - 1.0) * tan_half * aspect;
        let ndc_y = (1.0 - 2.0 * sy / height as f32) * tan_half;
        (f + r * ndc_x + u * ndc_y).normalize()
    }

    /// The image height that matches the framing aspect for an image `width` pixels wide, if
    /// the camera has one (at least 1 pixel).
    /// The height saturates at `u32::MAX`; [`Camera::height_for_f64`] gives the exact figure.
    pub fn height_for(&self, width: u32) -> Option<u32> {
        self.height_for_f64(width).map(|h| h as u32)
    }

    /// [`Camera::height_for`] before conversion to an integer (rounded, at least 1), for
    /// messages about heights out of range.
    pub fn height_for_f64(&self, width: u32) -> Option<f64> {
        self.aspect
            .map(|a| (width as f64 / a as f64).round().max(1.0))
    }

    /// Checks that the camera defines a view: finite vectors, eye ≠ target, `up` not parallel
    /// to the viewing direction, field of view in `(0°, 180°)`, positive finite aspect.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.eye.is_finite() && self.target.is_finite() && self.up.is_finite()) {
            return Err(format!(
                "camera eye {}, target {} and up {} must be finite",
                self.eye, self.target, self.up
            ));
        }
        let f = self.target - self.eye;
        if f.length_squared() == 0.0 {
            return Err(format!("camera eye and target coincide at {}", self.eye));
        }
        if f.normalize().cross(self.up).length_squared() < 1e-12 {
            return Err(format!(
                "camera up {} is zero or parallel to the viewing direction {}",
                self.up,
                f.normalize()
            ));
        }
        if !(self.vfov_deg > 0.0 && self.vfov_deg < 180.0) {
            return Err(format!(
                "camera vfov_deg {} must lie strictly between 0 and 180",
                self.vfov_deg
            ));
        }
        if !(MIN_VFOV_DEG..=MAX_VFOV_DEG).contains(&self.vfov_deg) {
            return Err(format!(
                "camera vfov_deg {} gives no usable image: it must lie in {MIN_VFOV_DEG}..={MAX_VFOV_DEG} \
                 (narrower, neighbouring pixels' rays coincide in single precision; wider, the \
                 image plane stretches to infinity)",
                self.vfov_deg
            ));
        }
        if let Some(a) = self.aspect {
            if !(a.is_finite() && a > 0.0) {
                return Err(format!("camera aspect {a} must be finite and positive"));
            }
            let side = crsh_core::pipeline::MAX_IMAGE_SIDE as f32;
            if !(1.0 / side..=side).contains(&a) {
                return Err(format!(
                    "camera aspect {a} gives no usable image: it must lie in 1/{side}..={side} \
                     (images are 1..={side} pixels per side)"
                ));
            }
        }
        Ok(())
    }

    /// A camera looking at the centre of `sphere` from the `+z` side, at the distance where
    /// the sphere just fits the vertical field of view `vfov_deg` (`r / sin(fov / 2)`), up `+y`.
    /// Used for bare OBJ files, which carry no camera.
    pub fn framing(sphere: Sphere, vfov_deg: f32) -> Camera {
        let r = if sphere.radius > 0.0 {
            sphere.radius
        } else {
            1.0
        };
        let d = r / (vfov_deg.to_radians() * 0.5).sin();
        Camera {
            eye: sphere.center + Vec3::Z * d,
            target: sphere.center,
            up: Vec3::Y,
            vfov_deg,
            aspect: None,
        }
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
#[derive(Clone, Debug, PartialEq)]
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
    /// Bounds of all triangle vertices (the union of the meshes' boxes).
    pub bounds: Aabb,
    /// Number of zero-area triangles (kept, never hit).
    pub degenerate_triangles: usize,
}

impl crsh_core::StageScene for Scene {
    fn triangle_count(&self) -> usize {
        Scene::triangle_count(self)
    }
}

impl Scene {
    /// Sets every light's radius to `radius` (soft shadows, seed 003 §5): a run-wide override
    /// for scenes whose manifests give none (`crsh render --light-radius`, the ablate plan's
    /// `light_radius`).
    ///
    /// # Errors
    /// [`SceneError::Invalid`] when `radius` is not a finite distance `≥ 0`; the scene is then
    /// unchanged.
    pub fn set_light_radius(&mut self, radius: f32) -> Result<(), SceneError> {
        if !radius.is_finite() || radius < 0.0 {
            return Err(SceneError::invalid(
                &self.name,
                format!("light radius {radius} must be a finite distance >= 0 (0: point lights)"),
            ));
        }
        for l in &mut self.lights {
            l.radius = radius;
        }
        Ok(())
    }

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

    /// Whether triangle `t` has zero area (see [`is_degenerate_triangle`]); such triangles are
    /// counted in [`Scene::degenerate_triangles`] and must never be reported as hit.
    pub fn is_degenerate(&self, t: usize) -> bool {
        let [a, b, c] = self.triangle(t);
        is_degenerate_triangle(a, b, c)
    }

    /// A one-line description for listings: name, triangles, meshes, lights, degenerates.
    pub fn summary(&self) -> SceneSummary {
        SceneSummary {
            name: self.name.clone(),
            triangles: self.indices.len(),
            vertices: self.positions.len(),
            meshes: self.meshes.len(),
            materials: self.materials.len(),
            lights: self.lights.len(),
            degenerate_triangles: self.degenerate_triangles,
        }
    }
}

/// The counts that describe a scene in listings (`crsh scenes`) and reports.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct SceneSummary {
    /// Scene name.
    pub name: String,
    /// Number of triangles.
    pub triangles: usize,
    /// Number of vertices.
    pub vertices: usize,
    /// Number of meshes.
    pub meshes: usize,
    /// Number of materials.
    pub materials: usize,
    /// Number of point lights.
    pub lights: usize,
    /// Number of zero-area triangles.
    pub degenerate_triangles: usize,
}

impl std::fmt::Display for SceneSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}: {} triangles, {} meshes, {} materials, {} lights",
            self.name, self.triangles, self.meshes, self.materials, self.lights
        )?;
        if self.degenerate_triangles > 0 {
            write!(f, ", {} degenerate triangles", self.degenerate_triangles)?;
        }
        Ok(())
    }
}

/// Whether the triangle `a, b, c` has exactly zero area. The cross product of the edges is
/// evaluated in `f64`, where products of `f32` coordinates differences are (almost always)
/// exact, so only truly collinear or coincident vertices count, not merely small triangles.
pub fn is_degenerate_triangle(a: Vec3, b: Vec3, c: Vec3) -> bool {
    let (a, b, c) = (a.as_dvec3(), b.as_dvec3(), c.as_dvec3());
    (b - a).cross(c - a) == glam::DVec3::ZERO
}

/// Largest number of triangles a scene may hold (64 Mi); larger inputs are rejected before
/// anything is allocated for them.
pub const MAX_TRIANGLES: usize = 64 << 20;

/// Largest number of vertices a scene may hold (64 Mi).
pub const MAX_VERTICES: usize = 64 << 20;

/// Largest magnitude of a vertex coordinate (`1e15`). Tracing squares coordinate differences
/// (edge cross products, bounding-box diagonals, sphere radii), and `f32` overflows to
/// infinity above about `1.8e19`; below this bound such squares stay finite with a wide
/// margin. Real scenes are many orders of magnitude smaller.
pub const MAX_COORDINATE: f32 = 1e15;

/// A mesh as added to the builder, before validation.
#[derive(Clone, Debug)]
struct PendingMesh {
    name: String,
    first_tri: u32,
    tri_count: u32,
}

/// Collects meshes one at a time and builds a validated [`Scene`].
///
/// Problems found while adding a mesh (index out of range, non-finite coordinate, size limit)
/// are remembered and returned by [`SceneBuilder::build`], which names the mesh.
#[derive(Clone, Debug, Default)]
pub struct SceneBuilder {
    name: String,
    positions: Vec<Vec3>,
    normals: Vec<Option<Vec3>>,
    indices: Vec<[u32; 3]>,
    tri_material: Vec<u32>,
    meshes: Vec<PendingMesh>,
    materials: Vec<Material>,
    lights: Vec<Light>,
    camera: Option<Camera>,
    error: Option<(String, String)>,
    warnings: Vec<String>,
    /// Lower limits `(triangles, vertices)` than the global ones (tests).
    limits: Option<(usize, usize)>,
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

    /// Whether a camera has been set.
    pub fn has_camera(&self) -> bool {
        self.camera.is_some()
    }

    /// The materials added so far (loaders apply overrides through [`Self::materials_mut`]).
    pub fn materials(&self) -> &[Material] {
        &self.materials
    }

    /// Mutable access to the materials added so far.
    pub fn materials_mut(&mut self) -> &mut [Material] {
        &mut self.materials
    }

    /// The vertex positions added so far (all meshes).
    pub fn positions(&self) -> &[Vec3] {
        &self.positions
    }

    /// Number of triangles added so far.
    pub fn triangle_count(&self) -> usize {
        self.indices.len()
    }

    /// The scene's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Renames the scene.
    pub fn rename(&mut self, name: impl Into<String>) -> &mut Self {
        self.name = name.into();
        self
    }

    /// Number of meshes added so far.
    pub fn mesh_count(&self) -> usize {
        self.meshes.len()
    }

    /// Records a non-fatal problem (e.g. a missing MTL file) for the load report.
    pub fn warn(&mut self, message: impl Into<String>) -> &mut Self {
        self.warnings.push(message.into());
        self
    }

    /// The warnings recorded so far.
    pub fn warnings(&self) -> &[String] {
        &self.warnings
    }

    fn fail(&mut self, mesh: String, message: String) {
        if self.error.is_none() {
            self.error = Some((mesh, message));
        }
    }

    /// Adds a mesh: `positions` and optional per-vertex `normals` (same length), `indices`
    /// into them, and one material id for all of its triangles.
    ///
    /// The mesh is checked at once (indices in range, finite positions no larger than
    /// [`MAX_COORDINATE`], normals count, size
    /// limits [`MAX_TRIANGLES`] / [`MAX_VERTICES`] before anything is copied); the first
    /// problem is returned by [`SceneBuilder::build`] and the offending mesh is not added.
    pub fn mesh(
        &mut self,
        name: impl Into<String>,
        positions: &[Vec3],
        normals: Option<&[Vec3]>,
        indices: &[[u32; 3]],
        material: u32,
    ) -> &mut Self {
        let name = name.into();
        let label = format!("mesh '{}' (#{})", name, self.meshes.len());
        let (max_tris, max_verts) = self.limits.unwrap_or((MAX_TRIANGLES, MAX_VERTICES));
        if self.positions.len().saturating_add(positions.len()) > max_verts {
            self.fail(
                label,
                format!(
                    "too many vertices: {} + {} exceeds the limit of {max_verts}",
                    self.positions.len(),
                    positions.len()
                ),
            );
            return self;
        }
        if self.indices.len().saturating_add(indices.len()) > max_tris {
            self.fail(
                label,
                format!(
                    "too many triangles: {} + {} exceeds the limit of {max_tris}",
                    self.indices.len(),
                    indices.len()
                ),
            );
            return self;
        }
        if let Some(n) = normals {
            if n.len() != positions.len() {
                self.fail(
                    label,
                    format!(
                        "{} normals given for {} positions",
                        n.len(),
                        positions.len()
                    ),
                );
                return self;
            }
        }
        if let Some((i, p)) = positions.iter().enumerate().find(|(_, p)| !p.is_finite()) {
            self.fail(label, format!("vertex {i} has a non-finite coordinate {p}"));
            return self;
        }
        if let Some((i, p)) = positions
            .iter()
            .enumerate()
            .find(|(_, p)| p.abs().max_element() > MAX_COORDINATE)
        {
            self.fail(
                label,
                format!(
                    "vertex {i} has a coordinate beyond the supported magnitude \
                     {MAX_COORDINATE:e}: {p}"
                ),
            );
            return self;
        }
        let nv = positions.len() as u32;
        if let Some((t, tri)) = indices
            .iter()
            .enumerate()
            .find(|(_, t)| t.iter().any(|&i| i >= nv))
        {
            self.fail(
                label,
                format!(
                    "triangle {t} references vertex {} but the mesh has {nv} vertices",
                    tri.iter().copied().find(|&i| i >= nv).unwrap_or(nv)
                ),
            );
            return self;
        }
        let base = self.positions.len() as u32;
        self.positions.extend_from_slice(positions);
        match normals {
            Some(n) => self.normals.extend(n.iter().map(|&v| Some(v))),
            None => self.normals.extend(positions.iter().map(|_| None)),
        }
        let first = self.indices.len() as u32;
        self.indices.extend(
            indices
                .iter()
                .map(|t| [t[0] + base, t[1] + base, t[2] + base]),
        );
        self.tri_material.extend(indices.iter().map(|_| material));
        self.meshes.push(PendingMesh {
            name,
            first_tri: first,
            tri_count: indices.len() as u32,
        });
        self
    }

    /// Validates everything and builds the scene: indices in range, finite coordinates, at
    /// least one triangle, material ids valid; computes missing normals, bounding volumes and
    /// the degenerate-triangle count. `context` names the source (file) in errors.
    pub fn build(self, context: &str) -> Result<Scene, SceneError> {
        self.build_with_warnings(context).map(|(scene, _)| scene)
    }

    /// [`SceneBuilder::build`], also returning the warnings recorded with
    /// [`SceneBuilder::warn`] and those found while building (e.g. vertices whose normal had
    /// to be invented).
    ///
    /// What is computed:
    /// - per-vertex unit normals: a supplied normal is kept (normalized) when finite and
    ///   non-zero; otherwise the area-weighted average of the incident triangles' normals (the
    ///   sum of their unnormalized edge cross products); where those cancel out, the normal
    ///   of the largest incident triangle; a vertex only in zero-area triangles gets `+z`;
    /// - the minimal sphere of every triangle ([`bounding::triangle_sphere`]);
    /// - per mesh, the exact minimal sphere of the vertices its triangles use
    ///   ([`bounding::min_sphere`]) and their AABB; the scene bounds are the union;
    /// - the number of zero-area triangles ([`is_degenerate_triangle`]).
    pub fn build_with_warnings(
        mut self,
        context: &str,
    ) -> Result<(Scene, Vec<String>), SceneError> {
        if let Some((mesh, message)) = self.error.take() {
            return Err(SceneError::invalid(format!("{context}: {mesh}"), message));
        }
        if self.meshes.is_empty() {
            return Err(SceneError::invalid(context, "empty scene: no meshes"));
        }
        if self.indices.is_empty() {
            return Err(SceneError::invalid(
                context,
                format!("empty scene: {} meshes but no triangles", self.meshes.len()),
            ));
        }
        if let Some((k, m)) = self
            .meshes
            .iter()
            .enumerate()
            .find(|(_, m)| m.tri_count == 0)
        {
            return Err(SceneError::invalid(
                format!("{context}: mesh '{}' (#{k})", m.name),
                "mesh has no triangles",
            ));
        }
        let camera = match self.camera.take() {
            Some(c) => c,
            None => return Err(SceneError::invalid(context, "no camera set")),
        };
        camera
            .validate()
            .map_err(|m| SceneError::invalid(context, m))?;
        for (i, l) in self.lights.iter().enumerate() {
            l.validate()
                .map_err(|m| SceneError::invalid(format!("{context}: light #{i}"), m))?;
        }
        for m in &self.materials {
            m.validate().map_err(|e| SceneError::invalid(context, e))?;
        }
        let n_mat = self.materials.len() as u32;
        for (k, m) in self.meshes.iter().enumerate() {
            let mat = self.tri_material[m.first_tri as usize];
            if mat >= n_mat {
                return Err(SceneError::invalid(
                    format!("{context}: mesh '{}' (#{k})", m.name),
                    format!("material id {mat} is out of range ({n_mat} materials)"),
                ));
            }
        }

        let mut warnings = std::mem::take(&mut self.warnings);
        let normals = compute_normals(&self.positions, &self.normals, &self.indices, &mut warnings);

        let mut degenerate = 0usize;
        let mut tri_spheres = Vec::with_capacity(self.indices.len());
        let mut tri_mesh = Vec::with_capacity(self.indices.len());
        for &[a, b, c] in &self.indices {
            let (a, b, c) = (
                self.positions[a as usize],
                self.positions[b as usize],
                self.positions[c as usize],
            );
            if is_degenerate_triangle(a, b, c) {
                degenerate += 1;
            }
            tri_spheres.push(bounding::triangle_sphere(a, b, c));
        }

        // Vertices used by each mesh (a mesh may carry unreferenced vertices).
        let mut seen = vec![u32::MAX; self.positions.len()];
        let mut used = Vec::new();
        let mut meshes = Vec::with_capacity(self.meshes.len());
        let mut bounds = Aabb::EMPTY;
        for (k, m) in self.meshes.iter().enumerate() {
            used.clear();
            // Stray vertices (left by some exporters) do not enlarge the bounds.
            let tris = &self.indices[m.first_tri as usize..(m.first_tri + m.tri_count) as usize];
            for tri in tris {
                for &v in tri {
                    if seen[v as usize] != k as u32 {
                        seen[v as usize] = k as u32;
                        used.push(self.positions[v as usize]);
                    }
                }
            }
            tri_mesh.extend(std::iter::repeat_n(k as u32, tris.len()));
            let aabb = Aabb::from_points(used.iter().copied());
            bounds = bounds.union(aabb);
            meshes.push(Mesh {
                name: m.name.clone(),
                first_tri: m.first_tri,
                tri_count: m.tri_count,
                sphere: bounding::min_sphere(&used),
                aabb,
            });
        }
        if self.lights.is_empty() {
            warnings.push(format!("{context}: the scene has no lights"));
        }

        let scene = Scene {
            name: self.name,
            positions: self.positions,
            normals,
            indices: self.indices,
            tri_mesh,
            tri_material: self.tri_material,
            tri_spheres,
            meshes,
            materials: self.materials,
            lights: self.lights,
            camera,
            bounds,
            degenerate_triangles: degenerate,
        };
        Ok((scene, warnings))
    }
}

/// Per-vertex unit normals: supplied ones where usable, else area-weighted face normals.
fn compute_normals(
    positions: &[Vec3],
    supplied: &[Option<Vec3>],
    indices: &[[u32; 3]],
    warnings: &mut Vec<String>,
) -> Vec<Vec3> {
    // A huge (`1e30`) or tiny (`1e-30`) finite normal, whose squared length overflows or
    // underflows, is scaled by its largest component first so that it is not lost; every
    // other normal is normalised as it is (scaling would move it by an ulp).
    let usable = |n: Option<Vec3>| {
        n.filter(|n| n.is_finite() && n.abs().max_element() > 0.0)
            .map(|n| {
                if n.length_squared().is_normal() {
                    n.normalize()
                } else {
                    (n / n.abs().max_element()).normalize()
                }
            })
    };
    let mut out: Vec<Vec3> = Vec::with_capacity(positions.len());
    let mut need = false;
    for &n in supplied {
        match usable(n) {
            Some(n) => out.push(n),
            None => {
                out.push(Vec3::ZERO);
                need = true;
            }
        }
    }
    if !need {
        return out;
    }
    let missing: Vec<bool> = out.iter().map(|n| *n == Vec3::ZERO).collect();
    let replaced = supplied
        .iter()
        .filter(|n| n.is_some() && usable(**n).is_none())
        .count();
    if replaced > 0 {
        warnings.push(format!(
            "{replaced} supplied normals were zero or not finite and were recomputed"
        ));
    }
    // Sum of unnormalized cross products: |(b-a)×(c-a)| = 2·area, so the sum weights each
    // face normal by its area.
    let mut acc = vec![glam::DVec3::ZERO; positions.len()];
    // Largest incident face (by area), for vertices whose face normals cancel out (the same
    // triangle present twice with opposite winding, as in some scanned meshes).
    let mut largest = vec![glam::DVec3::ZERO; positions.len()];
    for &[a, b, c] in indices {
        let (pa, pb, pc) = (
            positions[a as usize].as_dvec3(),
            positions[b as usize].as_dvec3(),
            positions[c as usize].as_dvec3(),
        );
        let n = (pb - pa).cross(pc - pa);
        for v in [a, b, c] {
            let v = v as usize;
            if missing[v] {
                acc[v] += n;
                if n.length_squared() > largest[v].length_squared() {
                    largest[v] = n;
                }
            }
        }
    }
    let (mut cancelled, mut invented) = (0usize, 0usize);
    for (i, o) in out.iter_mut().enumerate() {
        if !missing[i] {
            continue;
        }
        let sum = acc[i].normalize_or_zero().as_vec3();
        *o = if sum != Vec3::ZERO {
            sum
        } else if largest[i] != glam::DVec3::ZERO {
            cancelled += 1;
            largest[i].normalize().as_vec3()
        } else {
            invented += 1;
            Vec3::Z
        };
    }
    if cancelled > 0 {
        warnings.push(format!(
            "{cancelled} vertices have incident face normals that cancel out (faces repeated \
             with opposite winding?); they take the normal of their largest face"
        ));
    }
    if invented > 0 {
        warnings.push(format!(
            "{invented} vertices touch only zero-area triangles (or none); their normal is +z"
        ));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn camera_pixels_are_square_whatever_the_framing_aspect() {
        let cam = Camera {
            eye: Vec3::ZERO,
            target: Vec3::new(0.0, 0.0, -1.0),
            up: Vec3::Y,
            vfov_deg: 90.0,
            aspect: Some(16.0 / 9.0),
        };
        // A 200x100 image: the right edge centre is 2 units right of the axis at depth 1
        // (tan 45° × width / height), the top edge centre 1 unit up.
        let right = cam.direction(200.0, 50.0, 200, 100);
        assert!((right - Vec3::new(2.0, 0.0, -1.0).normalize()).length() < 1e-6);
        let top = cam.direction(100.0, 0.0, 200, 100);
        assert!((top - Vec3::new(0.0, 1.0, -1.0).normalize()).length() < 1e-6);
        assert_eq!(cam.height_for(512), Some(288));
        assert_eq!(
            Camera {
                aspect: None,
                ..cam.clone()
            }
            .height_for(512),
            None
        );
        assert_eq!(
            Camera {
                aspect: Some(1e6),
                ..cam
            }
            .height_for(10),
            Some(1)
        );
    }

    #[test]
    fn cameras_that_give_no_usable_image_are_refused() {
        let ok = camera();
        assert!(ok.validate().is_ok());
        for (vfov, aspect, says) in [
            (
                1e-30,
                None,
                "vfov_deg 0.000000000000000000000000000001 gives no usable image",
            ),
            (0.09, None, "vfov_deg 0.09 gives no usable image"),
            (179.5, None, "vfov_deg 179.5 gives no usable image"),
            (45.0, Some(1e9), "aspect 1000000000 gives no usable image"),
            (45.0, Some(1e-9), "aspect 0.000000001 gives no usable image"),
        ] {
            let c = Camera {
                vfov_deg: vfov,
                aspect,
                ..ok.clone()
            };
            let e = c.validate().unwrap_err();
            assert!(e.contains(says), "{e}");
        }
        for (vfov, aspect) in [
            (MIN_VFOV_DEG, Some(16384.0)),
            (MAX_VFOV_DEG, Some(1.0 / 16384.0)),
        ] {
            let c = Camera {
                vfov_deg: vfov,
                aspect,
                ..ok.clone()
            };
            assert!(c.validate().is_ok(), "{vfov} {aspect:?}");
        }
        let thin = Camera {
            aspect: Some(1.0 / 16384.0),
            ..ok
        };
        assert_eq!(thin.height_for_f64(16384), Some(268_435_456.0));
    }

    fn camera() -> Camera {
        Camera {
            eye: Vec3::new(0.0, 0.0, 5.0),
            target: Vec3::ZERO,
            up: Vec3::Y,
            vfov_deg: 45.0,
            aspect: None,
        }
    }

    const TRI: [Vec3; 3] = [Vec3::ZERO, Vec3::X, Vec3::Y];

    fn builder() -> SceneBuilder {
        let mut b = SceneBuilder::new("t");
        b.material(Material::default());
        b.camera(camera());
        b
    }

    fn err(b: SceneBuilder) -> String {
        b.build("src.obj").unwrap_err().to_string()
    }

    #[test]
    fn builds_a_valid_scene() {
        let mut b = builder();
        b.mesh("a", &TRI, None, &[[0, 1, 2]], 0);
        b.mesh("b", &TRI.map(|p| p + Vec3::Z), None, &[[0, 2, 1]], 0);
        let s = b.build("src.obj").unwrap();
        assert_eq!(s.indices, vec![[0, 1, 2], [3, 5, 4]]);
        assert_eq!(s.tri_mesh, vec![0, 1]);
        assert_eq!(s.normals[0], Vec3::Z);
        assert_eq!(s.normals[3], -Vec3::Z);
        assert_eq!(s.bounds.max, Vec3::ONE);
        assert_eq!(s.summary().triangles, 2);
    }

    #[test]
    fn index_out_of_range_names_the_mesh() {
        let mut b = builder();
        b.mesh("ok", &TRI, None, &[[0, 1, 2]], 0);
        b.mesh("broken", &TRI, None, &[[0, 1, 2], [0, 3, 1]], 0);
        let e = err(b);
        assert!(e.contains("src.obj") && e.contains("'broken' (#1)"), "{e}");
        assert!(e.contains("triangle 1") && e.contains("vertex 3"), "{e}");
    }

    #[test]
    fn non_finite_coordinates_name_the_mesh() {
        let mut b = builder();
        b.mesh(
            "nan",
            &[Vec3::ZERO, Vec3::new(f32::NAN, 0.0, 0.0), Vec3::Y],
            None,
            &[[0, 1, 2]],
            0,
        );
        let e = err(b);
        assert!(
            e.contains("'nan'") && e.contains("vertex 1") && e.contains("non-finite"),
            "{e}"
        );
        let mut b = builder();
        b.mesh(
            "inf",
            &[Vec3::ZERO, Vec3::X, Vec3::splat(f32::INFINITY)],
            None,
            &[[0, 1, 2]],
            0,
        );
        assert!(err(b).contains("vertex 2"));
    }

    #[test]
    fn empty_scenes_and_missing_camera_are_errors() {
        let e = err(builder());
        assert!(e.contains("src.obj") && e.contains("no meshes"), "{e}");
        let mut b = builder();
        b.mesh("nothing", &TRI, None, &[], 0);
        assert!(err(b).contains("no triangles"));
        let mut b = SceneBuilder::new("t");
        b.material(Material::default());
        b.mesh("a", &TRI, None, &[[0, 1, 2]], 0);
        assert!(err(b).contains("no camera"));
    }

    #[test]
    fn material_ids_and_values_are_checked() {
        let mut b = builder();
        b.mesh("a", &TRI, None, &[[0, 1, 2]], 3);
        let e = err(b);
        assert!(e.contains("'a'") && e.contains("material id 3"), "{e}");
        let mut b = builder();
        b.material(Material {
            name: "weird".into(),
            reflectivity: f32::NAN,
            ..Material::default()
        });
        b.mesh("a", &TRI, None, &[[0, 1, 2]], 0);
        let e = err(b);
        assert!(e.contains("'weird'") && e.contains("reflectivity"), "{e}");
    }

    #[test]
    fn bad_camera_and_lights_are_errors() {
        let mut b = builder();
        b.mesh("a", &TRI, None, &[[0, 1, 2]], 0);
        b.camera(Camera {
            up: Vec3::Z,
            ..camera()
        });
        assert!(err(b).contains("parallel"));
        let mut b = builder();
        b.mesh("a", &TRI, None, &[[0, 1, 2]], 0);
        b.light(Light {
            position: Vec3::ONE,
            color: Vec3::ONE,
            intensity: 1.0,
            attenuation: [0.0, 0.0, 0.0],
            radius: 0.0,
        });
        let e = err(b);
        assert!(e.contains("light #0") && e.contains("attenuation"), "{e}");
    }

    #[test]
    fn light_radius_is_validated_and_overridden() {
        let mut b = builder();
        b.mesh("a", &TRI, None, &[[0, 1, 2]], 0);
        b.light(Light {
            position: Vec3::ONE,
            color: Vec3::ONE,
            intensity: 1.0,
            attenuation: [1.0, 0.0, 0.0],
            radius: -0.5,
        });
        let e = err(b);
        assert!(e.contains("light #0") && e.contains("radius"), "{e}");
        let mut b = builder();
        b.mesh("a", &TRI, None, &[[0, 1, 2]], 0);
        b.light(Light {
            position: Vec3::ONE,
            color: Vec3::ONE,
            intensity: 1.0,
            attenuation: [1.0, 0.0, 0.0],
            radius: 0.0,
        });
        let mut s = b.build("x").unwrap();
        s.set_light_radius(0.25).unwrap();
        assert_eq!(s.lights[0].radius, 0.25);
        for bad in [-1.0, f32::NAN, f32::INFINITY] {
            assert!(s.set_light_radius(bad).is_err(), "{bad}");
            assert_eq!(s.lights[0].radius, 0.25, "unchanged after {bad}");
        }
    }

    #[test]
    fn normals_count_mismatch_is_an_error() {
        let mut b = builder();
        b.mesh("n", &TRI, Some(&[Vec3::Z]), &[[0, 1, 2]], 0);
        let e = err(b);
        assert!(
            e.contains("'n'") && e.contains("1 normals given for 3 positions"),
            "{e}"
        );
    }

    #[test]
    fn absurd_sizes_are_rejected_without_copying() {
        let mut b = builder();
        b.limits = Some((4, 6));
        b.mesh("a", &TRI, None, &[[0, 1, 2]; 3], 0);
        b.mesh("b", &TRI, None, &[[0, 1, 2]; 2], 0);
        assert_eq!(b.indices.len(), 3, "the oversized mesh was not copied");
        let e = err(b);
        assert!(
            e.contains("'b' (#1)") && e.contains("too many triangles"),
            "{e}"
        );
        let mut b = builder();
        b.limits = Some((100, 4));
        b.mesh("a", &TRI, None, &[[0, 1, 2]], 0);
        b.mesh("b", &TRI, None, &[[0, 1, 2]], 0);
        assert_eq!(b.positions.len(), 3);
        assert!(err(b).contains("too many vertices"));
    }

    #[test]
    fn camera_framing_fits_the_sphere() {
        let c = Camera::framing(Sphere::new(Vec3::new(1.0, 2.0, 3.0), 2.0), 45.0);
        let d = c.eye.distance(c.target);
        // The sphere's silhouette touches the edge of the vertical field of view.
        assert!(((2.0 / d).asin().to_degrees() - 22.5).abs() < 1e-3);
        assert_eq!(c.target, Vec3::new(1.0, 2.0, 3.0));
        assert!(c.eye.z > c.target.z);
        c.validate().unwrap();
    }

    #[test]
    fn degenerate_predicate_is_exact() {
        assert!(is_degenerate_triangle(Vec3::ZERO, Vec3::X, Vec3::X * 2.0));
        assert!(is_degenerate_triangle(Vec3::ONE, Vec3::ONE, Vec3::Y));
        // Tiny but not zero area.
        assert!(!is_degenerate_triangle(
            Vec3::ZERO,
            Vec3::X * 1e-6,
            Vec3::Y * 1e-6
        ));
    }
}
