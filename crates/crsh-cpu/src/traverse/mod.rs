//! Ray-space hierarchy traversers (seed 000 §3.2.8).
//!
//! - [`crsh`]: top-down traversal of the sphere-cone hierarchy against the meshes' and the
//!   triangles' bounding spheres (eq. 3.16), with stream compaction per level and triangle
//!   batches under a memory budget.

pub mod crsh;
