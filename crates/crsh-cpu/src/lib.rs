//! # crsh-cpu
//!
//! The CPU backend of crsh ([`Cpu`]): every stage variant as a rayon implementation of the
//! `crsh-core` stage traits, and [`build_stages`], which turns a [`crsh_core::PipelineConfig`]
//! and a scene into runnable [`crsh_core::Stages`].
//!
//! Stage variants, one module each:
//! - [`primary::raster`]: z-buffer rasterizer writing the G-buffer (seed 000 §3.1);
//!   [`primary::raycast`]: the same G-buffer by casting camera rays.
//! - [`triangle`]: the ray-triangle test and its epsilon policy.
//! - [`intersect::brute`]: every ray against every triangle (the exact reference);
//!   [`intersect::bvh`]: the obvhs CWBVH (closest and any hit).
//! - [`raygen::whitted`]: shadow, reflection and refraction rays (eq. 3.1-3.7).
//! - [`shade::phong`]: barycentric normals and Phong with attenuation (eq. 3.17-3.19).
//! - [`hash`], [`sort`], [`hierarchy`], [`traverse`]: the ray-space hierarchy stages
//!   (seed 000 §3.2.3-3.2.8); [`trim`]: head-flag scan compaction (fig. 3.10).
//! - [`stress`]: runs the stability suite of `crsh_scene::stress` against pipelines.

#![warn(missing_docs)]

pub mod backend;
pub mod catalogue;
pub mod hash;
pub mod hierarchy;
pub mod intersect;
pub mod primary;
pub mod raygen;
pub mod shade;
pub mod sort;
pub mod stress;
pub mod surface;
pub mod traverse;
pub mod triangle;
pub mod trim;

pub use backend::Cpu;
pub use catalogue::{
    build_intersector, build_stages, catalogue, preset, render, with_threads, PRESETS,
};
