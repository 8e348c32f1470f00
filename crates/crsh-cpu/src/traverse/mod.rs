//! Ray-space hierarchy traversers (seed 000 §3.2.8).
//!
//! - [`crsh`]: top-down traversal of the sphere-cone hierarchy against the meshes' and the
//!   triangles' bounding spheres (eq. 3.16), with stream compaction per level and triangle
//!   batches under a memory budget.
//! - [`dual`]: simultaneous top-down traversal of the ray hierarchy and an object hierarchy
//!   over the triangles (a per-frame LBVH of bounding spheres; seed 000 §5.1's "deeper object
//!   hierarchy"), with the same conservative node test and candidate budget; `objects =
//!   meshes` runs [`crsh`]'s mesh-sphere traversal instead.

pub mod crsh;
pub mod dual;
