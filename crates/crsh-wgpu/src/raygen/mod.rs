//! Secondary ray generation on the device: Whitted's rays, and seed 001's ambient-occlusion
//! and diffuse rays.

pub mod ao;
mod cosine;
pub mod diffuse;
mod slots;
pub mod whitted;
