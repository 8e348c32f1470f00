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
//!
//! [materials.leftSphere]     # overrides of MTL values, by material name
//! reflectivity = 0.95        # also diffuse, specular, shininess, transparency, ior, emission
//! ```
//!
//! Unknown keys are rejected (with the line), and an override naming a material that the MTL
//! does not define is an error naming it.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use glam::Vec3;
use serde::{Deserialize, Serialize};

use crate::error::SceneError;
use crate::model::{Camera, Light, Material, Scene, SceneBuilder};

/// A parsed manifest.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// Scene name used in reports (default: the manifest's file stem).
    #[serde(default)]
    pub name: Option<String>,
    /// The OBJ file, relative to the manifest (or absolute).
    pub mesh: PathBuf,
    /// The camera.
    pub camera: CameraSpec,
    /// Point lights.
    #[serde(default)]
    pub lights: Vec<LightSpec>,
    /// Material overrides by MTL material name.
    #[serde(default)]
    pub materials: BTreeMap<String, MaterialOverride>,
}

/// The `[camera]` table.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSpec {
    /// Eye position.
    pub eye: [f32; 3],
    /// Point looked at.
    pub target: [f32; 3],
    /// Up hint (default `+y`).
    #[serde(default = "default_up")]
    pub up: [f32; 3],
    /// Vertical field of view in degrees.
    pub vfov_deg: f32,
    /// Width / height the camera was framed for.
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
    pub position: [f32; 3],
    /// Colour (default white).
    #[serde(default = "default_white")]
    pub color: [f32; 3],
    /// Scalar intensity (default 1).
    #[serde(default = "default_one")]
    pub intensity: f32,
    /// Constant, linear, quadratic attenuation (seed 000 eq. 3.19c; default `[1, 0, 0]`).
    #[serde(default = "default_attenuation")]
    pub attenuation: [f32; 3],
}

/// A `[materials.NAME]` table: every field present replaces the MTL's value.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialOverride {
    /// Diffuse colour.
    pub diffuse: Option<[f32; 3]>,
    /// Specular colour.
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
    pub fn mesh_path(&self, manifest_path: &Path) -> PathBuf {
        manifest_path
            .parent()
            .unwrap_or(Path::new("."))
            .join(&self.mesh)
    }
}

/// Loads the scene a manifest describes, with the load report's warnings.
pub fn load(path: &Path) -> Result<(Scene, Vec<String>), SceneError> {
    let manifest = Manifest::read(path)?;
    let mesh = manifest.mesh_path(path);
    let ext_ok = mesh
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("obj"));
    if !ext_ok {
        return Err(SceneError::invalid(
            path.display().to_string(),
            format!("mesh '{}' is not an .obj file", manifest.mesh.display()),
        ));
    }
    let mut builder = SceneBuilder::new(manifest.scene_name(path));
    let info = crate::obj::read(&mesh, &mut builder)?;
    for (name, ov) in &manifest.materials {
        let Some(ids) = info.materials_by_name.get(name) else {
            let known: Vec<&str> = info.materials_by_name.keys().map(String::as_str).collect();
            return Err(SceneError::invalid(
                format!("{}: [materials.{name}]", path.display()),
                format!(
                    "the override names material '{name}', which {} does not define (it has: {})",
                    mesh.display(),
                    if known.is_empty() {
                        "none".to_string()
                    } else {
                        known.join(", ")
                    }
                ),
            ));
        };
        for &id in ids {
            ov.apply(&mut builder.materials_mut()[id as usize]);
        }
    }
    let c = &manifest.camera;
    builder.camera(Camera {
        eye: Vec3::from_array(c.eye),
        target: Vec3::from_array(c.target),
        up: Vec3::from_array(c.up),
        vfov_deg: c.vfov_deg,
        aspect: c.aspect,
    });
    for l in &manifest.lights {
        builder.light(Light {
            position: Vec3::from_array(l.position),
            color: Vec3::from_array(l.color),
            intensity: l.intensity,
            attenuation: l.attenuation,
        });
    }
    builder.build_with_warnings(&path.display().to_string())
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
