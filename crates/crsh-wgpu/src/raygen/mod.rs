//! Secondary ray generation on the device: Whitted's rays, and seed 001's ambient-occlusion
//! and diffuse rays.

pub mod ao;
mod cosine;
pub mod diffuse;
pub mod offsets;
mod slots;
pub mod whitted;
