//! The TOML scene manifest of `../shared/scenes/README.md`: an OBJ (+ MTL) plus what it lacks
//! (camera, point lights, material overrides by name).
//!
//! ```toml
//! name = "sponza"            # optional; defaults to the file stem
//! mesh = "sponza.obj"        # relative to the manifest
//!
//! [camera]
//! eye = [110.0, 18.0, -3.0]
//! target = [0.0, 35.0, 0.0]
//! up = [0.0, 1.0, 0.0]       # optional, default +y
//! vfov_deg = 60.0
//! aspect = 1.7777778         # optional
//!
//! [[lights]]                 # any number
//! position = [0.0, 100.0, 0.0]
//! color = [1.0, 1.0, 1.0]    # optional, default white
//! intensity = 1.0            # optional, default 1
//! attenuation = [1.0, 0.0, 0.0]   # optional, default [1, 0, 0] (eq. 3.19c)
//! radius = 0.0               # optional, default 0 (a point light); soft shadows (seed 003 §5)
//!
//! [materials.leftSphere]     # overrides of MTL values, by material name
//! reflectivity = 0.95        # also diffuse, specular, shininess, transparency, ior, emission
//! ```
//!
//!
//! # Instances and animation
//!
//! A manifest may also extend another scene and place meshes in it, moving or not
//! ([`crate::animation`]):
//!
//! ```toml
//! extends = "../sponza/sponza.toml"   # a manifest (relative to this one) or a built-in name:
//!                                     # its mesh, camera, lights and overrides come first
//! [animation]
//! fps = 24.0                          # frame f is the scene at t = f / fps seconds
//!
//! [[instances]]
//! name = "bunny"
//! mesh = "../bunny/stanford-bunny.obj"   # an OBJ, or a built-in shape:
//! # shape = "icosphere" | "box" | "grid", subdivisions = 2
//! translate = [0.0, 10.0, 0.0]        # placement: scale, then rotate, then translate
//! rotate = [0.0, 1.0, 0.0, 90.0]      # axis and degrees
//! scale = 100.0                       # or [x, y, z]
//! material = { diffuse = [0.8, 0.7, 0.6], reflectivity = 0.2 }   # onto all its materials
//!
//! [[instances.motion]]                # any number, applied in order
//! kind = "rotate"                     # also translate, scale, keyframes, wave, twist
//! axis = [0.0, 1.0, 0.0]
//! degrees_per_second = 45.0
//! ```
//!
//! Unknown keys are rejected (with the line), and an override naming a material that the
//! scene does not define is an error naming it. A manifest needs a `mesh`, an `extends` or an
//! instance, and a camera of its own or from what it extends.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::de::{self, Deserializer, SeqAccess, Visitor};
use serde::{Deserialize, Serialize};

use glam::{Affine3A, Quat, Vec3};

use crate::animation::{AnimatedScene, Instance, Motion, DEFAULT_FPS, FPS_RANGE};
use crate::builtin::Geometry;
use crate::error::SceneError;
use crate::model::{Camera, Light, Material, Scene, SceneBuilder};

/// Deepest chain of `extends` followed (a cycle is an error, not a hang).
pub const MAX_EXTENDS_DEPTH: usize = 8;

/// Largest `subdivisions` of a built-in shape (icosphere levels; box and grid divisions).
pub const MAX_SUBDIVISIONS: [u32; 3] = [7, 512, 2048];

/// Deserializes an array of exactly `N` numbers: `serde` alone fills an `[f32; N]` from the
/// first `N` elements and drops the rest without a word (`eye = [0, 2, 3, "x"]`).
pub(crate) fn exact<'de, D, const N: usize>(d: D) -> Result<[f32; N], D::Error>
where
    D: Deserializer<'de>,
{
    d.deserialize_seq(Exact::<N>)
}

/// [`exact`] for an optional field (which also needs `#[serde(default)]`).
pub(crate) fn exact_opt<'de, D, const N: usize>(d: D) -> Result<Option<[f32; N]>, D::Error>
where
    D: Deserializer<'de>,
{
    exact(d).map(Some)
}

struct Exact<const N: usize>;

impl<'de, const N: usize> Visitor<'de> for Exact<N> {
    type Value = [f32; N];

    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        write!(f, "an array of {N} numbers")
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<[f32; N], A::Error> {
        let mut out = [0.0; N];
        for (i, slot) in out.iter_mut().enumerate() {
            *slot = seq
                .next_element()?
                .ok_or_else(|| de::Error::invalid_length(i, &self))?;
        }
        let mut n = N;
        while seq.next_element::<de::IgnoredAny>()?.is_some() {
            n += 1;
        }
        if n > N {
            return Err(de::Error::invalid_length(n, &self));
        }
        Ok(out)
    }
}

/// Smallest placement scale of an instance (per axis); the largest is its inverse. Beyond,
/// the normals of a placed mesh cannot be transformed in `f32`.
pub const MIN_SCALE: f32 = 1e-12;

/// A parsed manifest.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// Scene name used in reports (default: the manifest's file stem).
    #[serde(default)]
    pub name: Option<String>,
    /// A scene this one adds to: a manifest path (relative to this manifest) or the name of a
    /// built-in scene that never moves ([`crate::builtin::is_static`], e.g. `office-boxes` or
    /// `glass-sphere-500`).
    #[serde(default)]
    pub extends: Option<String>,
    /// The OBJ file, relative to the manifest (or absolute).
    #[serde(default)]
    pub mesh: Option<PathBuf>,
    /// The camera (required unless `extends` gives one).
    #[serde(default)]
    pub camera: Option<CameraSpec>,
    /// Point lights.
    #[serde(default)]
    pub lights: Vec<LightSpec>,
    /// Material overrides by MTL material name.
    #[serde(default)]
    pub materials: BTreeMap<String, MaterialOverride>,
    /// Scene time (`[animation]`).
    #[serde(default)]
    pub animation: Option<AnimationSpec>,
    /// Placed meshes, moving or not (`[[instances]]`).
    #[serde(default)]
    pub instances: Vec<InstanceSpec>,
}

/// The `[animation]` table.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AnimationSpec {
    /// Frames per second of scene time (default [`DEFAULT_FPS`]).
    #[serde(default = "default_fps")]
    pub fps: f32,
}

fn default_fps() -> f32 {
    DEFAULT_FPS
}

/// A built-in shape of an instance, in object space.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Shape {
    /// Unit icosphere at the origin (`subdivisions` levels, default 2: 320 triangles).
    Icosphere,
    /// The cube `[-1, 1]³`, each face `subdivisions²` quads (default 1), faces outward.
    Box,
    /// The square `[-1, 1]²` in the `xz` plane facing `+y`, `subdivisions²` quads (default 16).
    Grid,
}

/// A uniform or per-axis scale.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum ScaleSpec {
    /// The same on every axis.
    Uniform(f32),
    /// Per axis.
    Axes(#[serde(deserialize_with = "exact")] [f32; 3]),
}

impl ScaleSpec {
    fn vec(self) -> Vec3 {
        match self {
            ScaleSpec::Uniform(s) => Vec3::splat(s),
            ScaleSpec::Axes(a) => Vec3::from_array(a),
        }
    }
}

/// One `[[instances]]` entry: a mesh placed in the scene, and how it moves.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InstanceSpec {
    /// Name in reports (default: the OBJ's stem or the shape's name, numbered).
    #[serde(default)]
    pub name: Option<String>,
    /// An OBJ file, relative to the manifest.
    #[serde(default)]
    pub mesh: Option<PathBuf>,
    /// Or a built-in shape.
    #[serde(default)]
    pub shape: Option<Shape>,
    /// Detail of the shape (see [`Shape`]).
    #[serde(default)]
    pub subdivisions: Option<u32>,
    /// Values set on every material of the instance (a shape starts from the default
    /// material).
    #[serde(default)]
    pub material: Option<MaterialOverride>,
    /// Placement translation.
    #[serde(default, deserialize_with = "exact")]
    pub translate: [f32; 3],
    /// Placement rotation: axis and degrees.
    #[serde(default, deserialize_with = "exact_opt")]
    pub rotate: Option<[f32; 4]>,
    /// Placement scale.
    #[serde(default)]
    pub scale: Option<ScaleSpec>,
    /// Motions, applied in order ([`Motion`]).
    #[serde(default)]
    pub motion: Vec<Motion>,
}

impl InstanceSpec {
    /// Object to world at rest: scale, then rotation, then translation.
    pub fn placement(&self) -> Result<Affine3A, String> {
        let scale = self.scale.map(ScaleSpec::vec).unwrap_or(Vec3::ONE);
        if !(scale.min_element() >= MIN_SCALE && scale.max_element() <= 1.0 / MIN_SCALE) {
            return Err(format!(
                "scale {scale} must lie in {MIN_SCALE:e}..={:e}",
                1.0 / MIN_SCALE
            ));
        }
        let translate = Vec3::from_array(self.translate);
        if !translate.is_finite() {
            return Err(format!("translate {translate} is not finite"));
        }
        let rotation = match self.rotate {
            None => Quat::IDENTITY,
            Some([x, y, z, deg]) => {
                let axis = Vec3::new(x, y, z);
                if !axis.is_finite() || axis.length_squared() < 1e-12 || !deg.is_finite() {
                    return Err(format!(
                        "rotate {:?} needs a finite non-zero axis and a finite angle",
                        [x, y, z, deg]
                    ));
                }
                Quat::from_axis_angle(axis.normalize(), deg.to_radians())
            }
        };
        Ok(Affine3A::from_scale_rotation_translation(
            scale, rotation, translate,
        ))
    }
}

/// The `[camera]` table.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSpec {
    /// Eye position.
    #[serde(deserialize_with = "exact")]
    pub eye: [f32; 3],
    /// Point looked at.
    #[serde(deserialize_with = "exact")]
    pub target: [f32; 3],
    /// Up hint (default `+y`).
    #[serde(default = "default_up", deserialize_with = "exact")]
    pub up: [f32; 3],
    /// Vertical field of view in degrees, [`crate::MIN_VFOV_DEG`]`..=`[`crate::MAX_VFOV_DEG`]
    /// (outside, no usable image: [`crate::Camera::validate`]).
    pub vfov_deg: f32,
    /// Width / height the camera was framed for, `1/16384..=16384` (the image side limit).
    #[serde(default)]
    pub aspect: Option<f32>,
}

fn default_up() -> [f32; 3] {
    [0.0, 1.0, 0.0]
}

fn default_white() -> [f32; 3] {
    [1.0, 1.0, 1.0]
}

fn default_one() -> f32 {
    1.0
}

fn default_attenuation() -> [f32; 3] {
    [1.0, 0.0, 0.0]
}

/// One `[[lights]]` entry.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightSpec {
    /// Position.
    #[serde(deserialize_with = "exact")]
    pub position: [f32; 3],
    /// Colour (default white).
    #[serde(default = "default_white", deserialize_with = "exact")]
    pub color: [f32; 3],
    /// Scalar intensity (default 1).
    #[serde(default = "default_one")]
    pub intensity: f32,
    /// Constant, linear, quadratic attenuation (seed 000 eq. 3.19c; default `[1, 0, 0]`).
    #[serde(default = "default_attenuation", deserialize_with = "exact")]
    pub attenuation: [f32; 3],
    /// Radius for soft shadows (seed 003 §5; default 0, a point light): finite and `≥ 0`.
    #[serde(default)]
    pub radius: f32,
}

/// A `[materials.NAME]` table: every field present replaces the MTL's value.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialOverride {
    /// Diffuse colour.
    #[serde(default, deserialize_with = "exact_opt")]
    pub diffuse: Option<[f32; 3]>,
    /// Specular colour.
    #[serde(default, deserialize_with = "exact_opt")]
    pub specular: Option<[f32; 3]>,
    /// Phong exponent.
    pub shininess: Option<f32>,
    /// Mirror weight in `[0, 1]`.
    pub reflectivity: Option<f32>,
    /// Refraction weight in `[0, 1]`.
    pub transparency: Option<f32>,
    /// Index of refraction.
    pub ior: Option<f32>,
    /// Emitted radiance (marks an emitter's surface).
    #[serde(default, deserialize_with = "exact_opt")]
    pub emission: Option<[f32; 3]>,
}

impl MaterialOverride {
    /// Applies the fields that are set to `m`.
    pub fn apply(&self, m: &mut Material) {
        if let Some(v) = self.diffuse {
            m.diffuse = Vec3::from_array(v);
        }
        if let Some(v) = self.specular {
            m.specular = Vec3::from_array(v);
        }
        if let Some(v) = self.shininess {
            m.shininess = v;
        }
        if let Some(v) = self.reflectivity {
            m.reflectivity = v;
        }
        if let Some(v) = self.transparency {
            m.transparency = v;
        }
        if let Some(v) = self.ior {
            m.ior = v;
        }
        if let Some(v) = self.emission {
            m.emission = Vec3::from_array(v);
        }
    }
}

/// The 1-based line of byte offset `at` in `text`.
fn line_of(text: &str, at: usize) -> usize {
    text.as_bytes()[..at.min(text.len())]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
        + 1
}

impl Manifest {
    /// Parses manifest text; `path` names the file in errors (`file:line: message`).
    pub fn parse(text: &str, path: &Path) -> Result<Manifest, SceneError> {
        toml::from_str(text).map_err(|e| {
            let context = match e.span() {
                Some(span) => format!("{}:{}", path.display(), line_of(text, span.start)),
                None => path.display().to_string(),
            };
            SceneError::invalid(context, e.message().trim().to_string())
        })
    }

    /// Reads and parses the manifest at `path`.
    pub fn read(path: &Path) -> Result<Manifest, SceneError> {
        let text = std::fs::read_to_string(path).map_err(|e| SceneError::Io {
            path: path.to_path_buf(),
            source: e,
        })?;
        Manifest::parse(&text, path)
    }

    /// The scene name: `name`, else the manifest's file stem.
    pub fn scene_name(&self, path: &Path) -> String {
        self.name.clone().unwrap_or_else(|| {
            path.file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| "scene".into())
        })
    }

    /// The OBJ path, resolved against the manifest's directory.
    pub fn mesh_path(&self, manifest_path: &Path) -> Option<PathBuf> {
        self.mesh.as_ref().map(|m| relative_to(manifest_path, m))
    }
}

/// `path` resolved against the directory of `manifest_path`.
fn relative_to(manifest_path: &Path, path: &Path) -> PathBuf {
    manifest_path.parent().unwrap_or(Path::new(".")).join(path)
}

/// Loads the scene a manifest describes (at frame 0 when it is animated), with the load
/// report's warnings.
pub fn load(path: &Path) -> Result<(Scene, Vec<String>), SceneError> {
    load_animated(path).map(|(a, w)| (a.into_scene(), w))
}

/// Loads the animated scene a manifest describes (a manifest without moving instances gives
/// one that never moves), with the load report's warnings.
pub fn load_animated(path: &Path) -> Result<(AnimatedScene, Vec<String>), SceneError> {
    let manifest = Manifest::read(path)?;
    build_animated(&manifest, path)
}

/// The animated scene of an already parsed manifest; `path` resolves its relative paths and
/// names it in errors.
pub fn build_animated(
    manifest: &Manifest,
    path: &Path,
) -> Result<(AnimatedScene, Vec<String>), SceneError> {
    let mut builder = SceneBuilder::new(manifest.scene_name(path));
    let mut instances = Vec::new();
    add_manifest(manifest, path, &mut builder, &mut instances, 0)?;
    if !builder.has_camera() {
        return Err(SceneError::invalid(
            path.display().to_string(),
            "no [camera]: give one, or extend a scene that has one",
        ));
    }
    let fps = manifest.animation.as_ref().map_or(DEFAULT_FPS, |a| a.fps);
    if !FPS_RANGE.contains(&fps) {
        return Err(SceneError::invalid(
            format!("{}: [animation]", path.display()),
            format!(
                "fps {fps:?} is outside {}..={}",
                FPS_RANGE.start(),
                FPS_RANGE.end()
            ),
        ));
    }
    let here = path.display().to_string();
    let (scene, warnings) = builder.build_with_warnings(&here)?;
    // Its errors name the scene and the instance; add the file.
    let anim = AnimatedScene::new(scene, instances, fps)
        .map_err(|e| SceneError::invalid(&here, e.to_string()))?;
    Ok((anim, warnings))
}

/// Adds what `manifest` (at `path`) describes to `builder`: what it extends, its mesh and
/// material overrides, its instances, camera and lights.
fn add_manifest(
    manifest: &Manifest,
    path: &Path,
    builder: &mut SceneBuilder,
    instances: &mut Vec<Instance>,
    depth: usize,
) -> Result<(), SceneError> {
    let here = path.display().to_string();
    if let Some(base) = &manifest.extends {
        if depth >= MAX_EXTENDS_DEPTH {
            return Err(SceneError::invalid(
                here,
                format!("extends `{base}`: more than {MAX_EXTENDS_DEPTH} levels (a cycle?)"),
            ));
        }
        if crate::builtin::is_static(base) {
            let name = builder.name().to_string();
            *builder = crate::builtin::builder(base)?;
            builder.rename(name);
        } else {
            let base_path = relative_to(path, Path::new(base));
            let parent = Manifest::read(&base_path).map_err(|e| {
                SceneError::invalid(format!("{here}: extends `{base}`"), e.to_string())
            })?;
            add_manifest(&parent, &base_path, builder, instances, depth + 1)?;
        }
    }
    if let Some(mesh) = manifest.mesh_path(path) {
        check_obj(&mesh, &here)?;
        crate::obj::read(&mesh, builder)?;
    }
    for (name, ov) in &manifest.materials {
        let ids: Vec<usize> = builder
            .materials()
            .iter()
            .enumerate()
            .filter(|(_, m)| &m.name == name)
            .map(|(i, _)| i)
            .collect();
        if ids.is_empty() {
            let mut known: Vec<&str> = builder
                .materials()
                .iter()
                .map(|m| m.name.as_str())
                .collect();
            known.sort_unstable();
            known.dedup();
            return Err(SceneError::invalid(
                format!("{here}: [materials.{name}]"),
                format!(
                    "the override names material '{name}', which the scene does not define (it has: {})",
                    if known.is_empty() {
                        "none".to_string()
                    } else {
                        known.join(", ")
                    }
                ),
            ));
        }
        for id in ids {
            ov.apply(&mut builder.materials_mut()[id]);
        }
    }
    for (i, spec) in manifest.instances.iter().enumerate() {
        instances.push(add_instance(spec, i, path, builder)?);
    }
    if let Some(c) = &manifest.camera {
        builder.camera(Camera {
            eye: Vec3::from_array(c.eye),
            target: Vec3::from_array(c.target),
            up: Vec3::from_array(c.up),
            vfov_deg: c.vfov_deg,
            aspect: c.aspect,
        });
    }
    for (i, l) in manifest.lights.iter().enumerate() {
        if !l.radius.is_finite() || l.radius < 0.0 {
            return Err(SceneError::invalid(
                format!("{here}: [[lights]] #{i}"),
                format!(
                    "radius {} must be a finite distance >= 0 (0: a point light)",
                    l.radius
                ),
            ));
        }
        builder.light(Light {
            position: Vec3::from_array(l.position),
            color: Vec3::from_array(l.color),
            intensity: l.intensity,
            attenuation: l.attenuation,
            radius: l.radius,
        });
    }
    if manifest.mesh.is_none() && manifest.extends.is_none() && manifest.instances.is_empty() {
        return Err(SceneError::invalid(
            here,
            "nothing to load: give a mesh, an extends or [[instances]]",
        ));
    }
    Ok(())
}

fn check_obj(mesh: &Path, context: &str) -> Result<(), SceneError> {
    let ok = mesh
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("obj"));
    if ok {
        Ok(())
    } else {
        Err(SceneError::UnsupportedFormat {
            context: context.to_string(),
            path: mesh.to_path_buf(),
            format: mesh
                .extension()
                .map_or_else(String::new, |e| e.to_string_lossy().to_lowercase()),
        })
    }
}

/// Adds instance `index` of the manifest at `path` to `builder` (in object space; the
/// [`AnimatedScene`] places it).
fn add_instance(
    spec: &InstanceSpec,
    index: usize,
    path: &Path,
    builder: &mut SceneBuilder,
) -> Result<Instance, SceneError> {
    let label = format!(
        "{}: instance #{index}{}",
        path.display(),
        spec.name
            .as_deref()
            .map(|n| format!(" '{n}'"))
            .unwrap_or_default()
    );
    let bad = |m: String| SceneError::invalid(&label, m);
    let placement = spec.placement().map_err(bad)?;
    for m in &spec.motion {
        m.validate().map_err(bad)?;
    }
    let (v0, m0, t0, mat0) = (
        builder.positions().len(),
        builder.mesh_count(),
        builder.triangle_count(),
        builder.materials().len(),
    );
    let name = match (&spec.mesh, spec.shape) {
        (Some(mesh), None) => {
            let file = relative_to(path, mesh);
            check_obj(&file, &label)?;
            crate::obj::read(&file, builder)?;
            spec.name.clone().unwrap_or_else(|| {
                file.file_stem()
                    .map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_else(|| format!("instance-{index}"))
            })
        }
        (None, Some(shape)) => {
            let name = spec
                .name
                .clone()
                .unwrap_or_else(|| format!("{shape:?}-{index}").to_lowercase());
            let (max, default) = match shape {
                Shape::Icosphere => (MAX_SUBDIVISIONS[0], 2),
                Shape::Box => (MAX_SUBDIVISIONS[1], 1),
                Shape::Grid => (MAX_SUBDIVISIONS[2], 16),
            };
            let n = spec.subdivisions.unwrap_or(default);
            if n > max || (n == 0 && shape != Shape::Icosphere) {
                return Err(bad(format!(
                    "subdivisions {n} of a {shape:?} must be in {}..={max}",
                    u32::from(shape != Shape::Icosphere)
                )));
            }
            let g = match shape {
                Shape::Icosphere => Geometry::icosphere(Vec3::ZERO, 1.0, n),
                Shape::Box => Geometry::subdivided_box(n),
                Shape::Grid => Geometry::grid(n),
            };
            let mat = builder.material(Material {
                name: name.clone(),
                ..Material::default()
            });
            builder.mesh(
                name.clone(),
                &g.positions,
                Some(&g.normals),
                &g.indices,
                mat,
            );
            name
        }
        _ => return Err(bad("give exactly one of mesh and shape".into())),
    };
    if let Some(ov) = &spec.material {
        for m in &mut builder.materials_mut()[mat0..] {
            ov.apply(m);
        }
    }
    Ok(Instance::new(
        name,
        v0..builder.positions().len(),
        m0..builder.mesh_count(),
        t0..builder.triangle_count(),
        placement,
        spec.motion.clone(),
    ))
}

/// A manifest found by [`list`].
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ManifestEntry {
    /// Scene name (the manifest's `name`, else its file stem).
    pub name: String,
    /// Path of the manifest.
    pub path: PathBuf,
    /// Why the manifest cannot be used, when it does not parse (the entry is still listed).
    pub problem: Option<String>,
}

fn toml_files(
    dir: &Path,
    out: &mut Vec<PathBuf>,
    subdirs: &mut Vec<PathBuf>,
) -> Result<(), SceneError> {
    let rd = std::fs::read_dir(dir).map_err(|e| SceneError::Io {
        path: dir.to_path_buf(),
        source: e,
    })?;
    for entry in rd {
        let entry = entry.map_err(|e| SceneError::Io {
            path: dir.to_path_buf(),
            source: e,
        })?;
        let p = entry.path();
        if p.is_dir() {
            subdirs.push(p);
        } else if p
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("toml"))
        {
            out.push(p);
        }
    }
    Ok(())
}

/// Every `*.toml` manifest in `dir` and its direct subfolders, sorted by path, with its scene
/// name (for `crsh scenes`). A manifest that does not parse is listed with its problem.
pub fn list(dir: &Path) -> Result<Vec<ManifestEntry>, SceneError> {
    let mut files = Vec::new();
    let mut subdirs = Vec::new();
    toml_files(dir, &mut files, &mut subdirs)?;
    subdirs.sort();
    for sub in subdirs {
        let mut ignored = Vec::new();
        toml_files(&sub, &mut files, &mut ignored)?;
    }
    files.sort();
    Ok(files
        .into_iter()
        .map(|path| match Manifest::read(&path) {
            Ok(m) => ManifestEntry {
                name: m.scene_name(&path),
                path,
                problem: None,
            },
            Err(e) => ManifestEntry {
                name: path
                    .file_stem()
                    .map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_default(),
                problem: Some(e.to_string()),
                path,
            },
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    const CAMERA: &str = "[camera]\neye = [0, 2, 3]\ntarget = [0, 0, 0]\nvfov_deg = 40\n";

    fn parse_err(text: &str) -> String {
        Manifest::parse(text, Path::new("m.toml"))
            .expect_err(text)
            .to_string()
    }

    #[test]
    fn arrays_of_three_parse() {
        let m = Manifest::parse(
            &format!("mesh = \"a.obj\"\n{CAMERA}[[lights]]\nposition = [1, 2, 3]\n"),
            Path::new("m.toml"),
        )
        .unwrap();
        let c = m.camera.unwrap();
        assert_eq!((c.eye, c.up), ([0.0, 2.0, 3.0], [0.0, 1.0, 0.0]));
        assert_eq!(m.lights[0].color, [1.0; 3]);
    }

    #[test]
    fn arrays_of_another_length_name_the_line() {
        for (text, line, got) in [
            (
                "mesh = \"a.obj\"\n[camera]\neye = [0, 2, 3, \"x\"]\ntarget = [0, 0, 0]\nvfov_deg = 40\n",
                3,
                "invalid length 4",
            ),
            (
                "mesh = \"a.obj\"\n[camera]\neye = [0, 2, 3]\ntarget = [0, 0]\nvfov_deg = 40\n",
                4,
                "invalid length 2",
            ),
            (
                &format!("mesh = \"a.obj\"\n{CAMERA}up = []\n"),
                6,
                "invalid length 0",
            ),
            (
                &format!("mesh = \"a.obj\"\n{CAMERA}[[lights]]\nposition = [1, 2, 3, 4]\n"),
                7,
                "invalid length 4",
            ),
            (
                &format!("mesh = \"a.obj\"\n{CAMERA}[[lights]]\nposition = [1, 2, 3]\ncolor = [1, 1, 1, 1]\n"),
                8,
                "invalid length 4",
            ),
            (
                &format!("mesh = \"a.obj\"\n{CAMERA}[materials.m]\ndiffuse = [1, 1]\n"),
                7,
                "invalid length 2",
            ),
            (
                &format!("{CAMERA}[[instances]]\nshape = \"box\"\ntranslate = [1, 2, 3, 4]\n"),
                7,
                "invalid length 4",
            ),
            (
                &format!("{CAMERA}[[instances]]\nshape = \"box\"\nrotate = [0, 1, 0, 90, 5]\n"),
                7,
                "invalid length 5",
            ),
        ] {
            let e = parse_err(text);
            assert!(
                e.starts_with(&format!("m.toml:{line}: ")) && e.contains(got),
                "{text}\n=> {e}"
            );
            assert!(e.contains("expected an array of"), "{e}");
        }
    }

    #[test]
    fn arrays_inside_untagged_and_tagged_tables_are_exact_too() {
        let e = parse_err(&format!(
            "{CAMERA}[[instances]]\nshape = \"box\"\nscale = [1, 2, 3, 4]\n"
        ));
        assert!(e.starts_with("m.toml:7: "), "{e}");
        let e = parse_err(&format!(
            "{CAMERA}[[instances]]\nshape = \"box\"\n[[instances.motion]]\nkind = \"rotate\"\n\
             degrees_per_second = 1\npivot = [0, 0, 0, 0]\n"
        ));
        assert!(
            e.contains("m.toml:") && e.contains("invalid length 4"),
            "{e}"
        );
        let e = parse_err(&format!(
            "{CAMERA}[[instances]]\nshape = \"box\"\n[[instances.motion]]\nkind = \"translate\"\n\
             velocity = [1, 2]\n"
        ));
        assert!(
            e.contains("m.toml:") && e.contains("invalid length 2"),
            "{e}"
        );
    }
}
