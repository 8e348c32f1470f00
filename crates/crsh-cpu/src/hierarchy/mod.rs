//! Ray-space hierarchy builders (seed 000 §3.2.7).
//!
//! - [`sphere_cone`]: the bottom-up sphere-cone hierarchy of seed 000 §3.2.7 (eq. 3.8-3.15,
//!   with the cone-union erratum), incremental leaf cones after seed 004 §4.
//! - [`auto_shape`]: the sphere-cone hierarchy with its subdivision and depth chosen per ray
//!   kind by a sampled pre-pass (issue 17's auto-configuration).
//! - [`tile_cone`]: seed 004's hierarchical ray engine: one apex cone per screen tile of
//!   consecutive rays (§4, with errata), one level of variable-size nodes.

pub mod auto_shape;
pub mod sphere_cone;
pub mod tile_cone;
