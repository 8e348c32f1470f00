//! Compute kernels. Each kernel module holds the WGSL (included with `include_str!`), the
//! host-side driver, and a CPU twin with identical semantics that the tests compare against.
//!
//! WGSL has no `#include`: a kernel's source is its own file after the shared pieces it
//! needs, joined by [`compose`] (and [`crate::Kernel::new`] puts `common.wgsl`, the records
//! every kernel shares, in front of everything). The pieces, each naming what must precede it:
//! [`GLAM_WGSL`] (glam's vector helpers), [`SURFACE_WGSL`] (hit → surface record),
//! [`TRIG_WGSL`] (accurate trigonometry), [`RNG_WGSL`] (counter-based random numbers,
//! [`rng`]), [`SEGMENT_WGSL`] (the offset policies of rays leaving a surface) and
//! [`origin_offset_wgsl`] (seed 001's hemisphere query, constants generated from Rust's).

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

/// `round_up` and `reach_guard`: the rounding guard of a node's reach computed in `f32`,
/// shared by the hierarchy builders (`sphere_cone`, `tile_cone`) so their reaches are guarded
/// alike; after `common.wgsl` only.
pub const REACH_WGSL: &str = include_str!("reach.wgsl");

/// `origin_offset.wgsl` without its constants: see [`origin_offset_wgsl`].
const ORIGIN_OFFSET_BODY: &str = include_str!("origin_offset.wgsl");

/// The WGSL constant declaration `const NAME: f32 = x;` with `x` written so that it reads back
/// as the same `f32` (Rust's shortest round-trip form).
pub(crate) fn f32_const(name: &str, x: f32) -> String {
    format!("const {name}: f32 = {x:?}f;\n")
}

/// Seed 001's origin-offset query, the twin of `crsh_cpu::raygen::origin_offset`'s
/// `hemisphere_interval`, `offset_t_min` and `cut_t_max` and of
/// `crsh_cpu::raygen::offsets::Offsets::{apply, cut_end}`; after [`GLAM_WGSL`]. Its constants
/// (`QUERY_REL`, `T_REL`, `INFINITE_RADIUS`) are generated from the Rust ones, so the two
/// cannot drift apart. The including kernel declares the table's bindings (see the file).
pub fn origin_offset_wgsl() -> String {
    use crsh_cpu::raygen::origin_offset::{INFINITE_RADIUS, QUERY_REL, T_REL};
    let mut s = String::from("// Generated from crsh_cpu::raygen::origin_offset.\n");
    s += &f32_const("QUERY_REL", QUERY_REL);
    s += &f32_const("T_REL", T_REL);
    s += &f32_const("INFINITE_RADIUS", INFINITE_RADIUS);
    s + ORIGIN_OFFSET_BODY
}

/// The WGSL pieces `parts` joined in order into one kernel source.
pub fn compose(parts: &[&str]) -> String {
    parts.join("\n")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crsh_cpu::raygen::origin_offset::{INFINITE_RADIUS, QUERY_REL, T_REL};

    /// The generated constants read back as the Rust ones, bit for bit.
    #[test]
    fn origin_offset_constants_are_the_rust_ones() {
        let src = origin_offset_wgsl();
        for (name, want) in [
            ("QUERY_REL", QUERY_REL),
            ("T_REL", T_REL),
            ("INFINITE_RADIUS", INFINITE_RADIUS),
        ] {
            let decl = format!("const {name}: f32 = ");
            let at = src.find(&decl).expect(name) + decl.len();
            let lit = &src[at..at + src[at..].find("f;").expect(name)];
            let got: f32 = lit.parse().expect(lit);
            assert_eq!(got.to_bits(), want.to_bits(), "{name} = {lit}");
        }
        assert!(src.contains("fn hemisphere_interval("));
    }
}
