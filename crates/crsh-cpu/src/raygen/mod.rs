//! Secondary ray generation variants (§3.2.3), seed 001's AO and diffuse rays, and its
//! origin offsets.

pub mod ao;
pub mod cosine;
pub mod diffuse;
pub mod offsets;
pub mod origin_offset;
pub mod whitted;
