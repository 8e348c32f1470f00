//! # crsh-scene
//!
//! The scene model crsh traces: flat arrays of vertices and triangles, meshes as contiguous
//! triangle ranges with their minimal bounding spheres, materials, point lights and a pinhole
//! camera. No scene graph. Loaders read OBJ + MTL (through `tobj`) and the TOML manifests of
//! `../shared/scenes`; built-in procedural scenes need no files.

#![warn(missing_docs)]

pub mod bounding;
pub mod error;
pub mod model;
mod rng;

pub use error::SceneError;
pub use model::{Camera, Light, Material, Mesh, Scene, SceneBuilder};
