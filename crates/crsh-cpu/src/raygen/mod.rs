//! Secondary ray generation variants (§3.2.3), and the origin offsets of seed 001
//! ([`origin_offset`]) that ray generators may apply to the rays they make.

pub mod origin_offset;
pub mod whitted;
