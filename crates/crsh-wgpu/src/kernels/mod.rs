//! Compute kernels. Each kernel module holds the WGSL (included with `include_str!`), the
//! host-side driver, and a CPU twin with identical semantics that the tests compare against.
//!
//! WGSL has no `#include`: a kernel's source is its own file after the shared pieces it
//! needs, joined by [`compose`] (and [`crate::Kernel::new`] puts `common.wgsl`, the records
//! every kernel shares, in front of everything). The pieces, each naming what must precede it:
//! [`GLAM_WGSL`] (glam's vector helpers), [`SURFACE_WGSL`] (hit → surface record),
//! [`TRIG_WGSL`] (accurate trigonometry), [`RNG_WGSL`] (counter-based random numbers,
//! [`rng`]) and [`SEGMENT_WGSL`] (the offset policies of rays leaving a surface).

pub mod accumulate;
pub mod rng;
pub mod scan;

/// glam's `Vec3` helpers (`g_dot`, `g_length`, `g_normalize_or_zero`, ...), in glam's order
/// of operations.
pub const GLAM_WGSL: &str = include_str!("glam.wgsl");

/// `surface_from_hit`, the twin of `crsh_cpu::surface::surface_from_hit`; after
/// [`GLAM_WGSL`].
pub const SURFACE_WGSL: &str = include_str!("surface.wgsl");

/// Sine, cosine and arc tangents accurate to about 1e-7 from `+ − × ÷ √` only; the including
/// kernel defines `PI`.
pub const TRIG_WGSL: &str = include_str!("trig.wgsl");

/// `pcg4d`, uniforms and cosine-weighted directions, the twin of [`crsh_core::rng`]; after
/// [`GLAM_WGSL`] and [`TRIG_WGSL`] ([`rng`]).
pub const RNG_WGSL: &str = include_str!("rng.wgsl");

/// `offset_segment` and Wächter & Binder's `offset_ray`, the twins of
/// `crsh_cpu::raygen::whitted::{offset_segment, offset_ray}`, and the throughput threshold of
/// ray generation; after [`GLAM_WGSL`].
pub const SEGMENT_WGSL: &str = include_str!("segment.wgsl");

/// The WGSL pieces `parts` joined in order into one kernel source.
pub fn compose(parts: &[&str]) -> String {
    parts.join("\n")
}
