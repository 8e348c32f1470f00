//! # crsh-scene
//!
//! The scene model crsh traces: flat arrays of vertices and triangles, meshes as contiguous
//! triangle ranges with their minimal bounding spheres, materials, point lights and a pinhole
//! camera. No scene graph. Loaders read OBJ + MTL (through `tobj`) and the TOML manifests of
//! `../shared/scenes`; built-in procedural scenes need no files.
//!
//! Entry points:
//! - [`load`] / [`load_with_report`]: a built-in name ([`builtin::NAMES`], or a sized one
//!   such as `glass-sphere-500`: [`builtin::PATTERNS`]), a `.toml` manifest ([`manifest`]) or
//!   a bare `.obj` ([`obj`]); the report carries non-fatal warnings such as a missing MTL
//!   file.
//! - [`load_path`] / [`load_path_with_report`]: a file, by extension.
//! - [`manifest::list`]: the manifests of a scenes directory, for `crsh scenes`.
//! - [`input_files`]: the files loading a scene reads (so that no output overwrites them).
//! - [`SceneBuilder`]: builds and validates a [`Scene`] from meshes, computing normals,
//!   per-triangle and per-mesh minimal bounding spheres ([`bounding`]) and bounds.
//!
//! - [`stress`]: the procedural cases of the stability suite (`crsh stress`).
//! - [`random`]: the random triangle soups of seed 002 §5.1 (grid build time, `crsh
//!   grid-build`).
//!
//! Every error names the file and line, or the mesh, where the problem is.
//!
//! ```
//! use crsh_scene::{Camera, Light, Material, SceneBuilder};
//! use glam::Vec3;
//!
//! // A built-in scene, by name (manifests and OBJ files load the same way).
//! let cornell = crsh_scene::load("cornell-mirrors").unwrap();
//! assert!(cornell.triangle_count() > 0 && !cornell.lights.is_empty());
//!
//! // A scene from code: one lit quad.
//! let mut b = SceneBuilder::new("quad");
//! b.material(Material::default());
//! b.light(Light {
//!     position: Vec3::new(0.0, 2.0, 0.0),
//!     color: Vec3::ONE,
//!     intensity: 1.0,
//!     attenuation: [1.0, 0.0, 0.0],
//!     radius: 0.0,
//! });
//! b.camera(Camera {
//!     eye: Vec3::new(0.0, 1.0, 3.0),
//!     target: Vec3::ZERO,
//!     up: Vec3::Y,
//!     vfov_deg: 45.0,
//!     aspect: None,
//! });
//! let corners = [[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]].map(|[x, z]| Vec3::new(x, 0.0, z));
//! b.mesh("floor", &corners, None, &[[0, 2, 1], [0, 3, 2]], 0);
//! let quad = b.build("from code").unwrap();
//! assert_eq!((quad.triangle_count(), quad.meshes.len()), (2, 1));
//! // Bad input is an error, never a panic.
//! assert!(crsh_scene::load("no/such/scene.toml").is_err());
//! ```

#![warn(missing_docs)]

pub mod animation;
pub mod bounding;
pub mod builtin;
pub mod error;
pub mod inputs;
pub mod manifest;
pub mod model;
pub mod mtl;
pub mod obj;
pub mod random;
mod rng;
pub mod stress;

use std::path::Path;

pub use animation::{AnimatedScene, Instance, Motion, UpdateTimes};
pub use error::SceneError;
pub use inputs::input_files;
pub use model::{
    is_degenerate_triangle, Camera, Light, Material, Mesh, Scene, SceneBuilder, SceneSummary,
    MAX_COORDINATE, MAX_TRIANGLES, MAX_VERTICES, MAX_VFOV_DEG, MIN_VFOV_DEG,
};

/// What a load produced besides the scene: where it came from and the non-fatal problems
/// found (missing MTL, meshes without material, recomputed normals, ...).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct LoadReport {
    /// The spec or path that was loaded.
    pub source: String,
    /// Warnings, one per problem, each naming its file or mesh.
    pub warnings: Vec<String>,
}

fn accepted() -> String {
    format!(
        "expected a built-in scene name ({}, {}), a .toml manifest or an .obj file",
        builtin::NAMES.join(", "),
        builtin::PATTERNS
            .iter()
            .map(|(p, _)| *p)
            .collect::<Vec<_>>()
            .join(", ")
    )
}

/// Loads a scene from `spec`: a built-in name ([`builtin::NAMES`], or a sized one such as
/// `glass-sphere-500`: [`builtin::is_name`]), or a path to a `.toml` manifest or an `.obj`
/// file.
pub fn load(spec: &str) -> Result<Scene, SceneError> {
    load_with_report(spec).map(|(s, _)| s)
}

/// [`load`], also returning the [`LoadReport`] (warnings such as a missing MTL file).
pub fn load_with_report(spec: &str) -> Result<(Scene, LoadReport), SceneError> {
    if builtin::is_name(spec) {
        let (scene, warnings) = builtin::build_with_warnings(spec)?;
        return Ok((
            scene,
            LoadReport {
                source: spec.to_string(),
                warnings,
            },
        ));
    }
    let path = Path::new(spec);
    if extension(path).is_none() && !path.exists() {
        return Err(SceneError::invalid(
            format!("scene '{spec}'"),
            format!("not a built-in scene nor a file: {}", accepted()),
        ));
    }
    load_path_with_report(path)
}

/// Loads `spec` as an animated scene: a built-in name, a `.toml` manifest (moving when it has
/// `[[instances]]` with motions) or an `.obj` file (never moves), with the load report.
pub fn load_animated(spec: &str) -> Result<(AnimatedScene, LoadReport), SceneError> {
    let report = |warnings| LoadReport {
        source: spec.to_string(),
        warnings,
    };
    if builtin::is_name(spec) {
        let (anim, warnings) = builtin::animated_with_warnings(spec)?;
        return Ok((anim, report(warnings)));
    }
    let path = Path::new(spec);
    match extension(path) {
        Some("toml") => {
            let (anim, warnings) = manifest::load_animated(path)?;
            Ok((anim, report(warnings)))
        }
        _ => {
            let (scene, r) = load_with_report(spec)?;
            Ok((AnimatedScene::fixed(scene), r))
        }
    }
}

fn extension(path: &Path) -> Option<&'static str> {
    let ext = path.extension()?.to_str()?;
    ["toml", "obj"]
        .into_iter()
        .find(|known| ext.eq_ignore_ascii_case(known))
}

/// Loads the scene at `path`: a `.toml` manifest or an `.obj` file (chosen by extension).
pub fn load_path(path: &Path) -> Result<Scene, SceneError> {
    load_path_with_report(path).map(|(s, _)| s)
}

/// [`load_path`], also returning the [`LoadReport`].
pub fn load_path_with_report(path: &Path) -> Result<(Scene, LoadReport), SceneError> {
    let (scene, warnings) = match extension(path) {
        Some("toml") => manifest::load(path)?,
        Some("obj") => obj::load(path)?,
        _ => {
            return Err(SceneError::invalid(
                path.display().to_string(),
                format!("unsupported file type: {}", accepted()),
            ))
        }
    };
    Ok((
        scene,
        LoadReport {
            source: path.display().to_string(),
            warnings,
        },
    ))
}
