//! Ray-space hierarchy builders (seed 000 §3.2.7).
//!
//! - [`sphere_cone`]: the bottom-up sphere-cone hierarchy of seed 000 §3.2.7 (eq. 3.8-3.15,
//!   with the cone-union erratum), incremental leaf cones after seed 004 §4.

pub mod sphere_cone;
