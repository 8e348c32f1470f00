//! Quantizers shared by the ray hashers of every backend and by third-party hashers: uniform
//! cells over an interval, spherical and octahedral direction parameterizations, and
//! MSB-first bit interleaving (seed 000 §3.2.3 quantizes origins and directions before
//! hashing; figs 3.8-3.9 lay the fields out).
//!
//! Backend-neutral: the CPU hashers call these functions directly and the wgpu hashers size
//! their fields with them (their WGSL twin quantizes in `f32`, see `crsh-wgpu`'s
//! `hash/quantize.wgsl`).

use glam::{Vec2, Vec3};

/// Cell index of `x` among `2^bits` equal cells of `[lo, hi]`:
/// `floor((x − lo) / (hi − lo) · 2^bits)`, clamped to `0 ..= 2^bits − 1`.
///
/// Values outside the interval land in the first or last cell; NaN, `bits == 0` and an empty
/// or degenerate interval (`hi <= lo`, e.g. a flat scene's thin axis) give 0. `bits` must be
/// at most 32. Monotone non-decreasing in `x`.
pub fn quantize(x: f32, lo: f32, hi: f32, bits: u32) -> u64 {
    debug_assert!(bits <= 32);
    if bits == 0 {
        return 0;
    }
    let cells = (1u64 << bits) as f64;
    let span = hi as f64 - lo as f64;
    if !(span > 0.0 && span.is_finite()) {
        return 0;
    }
    let f = ((x as f64 - lo as f64) / span * cells).floor();
    if f.is_nan() || f < 0.0 {
        0
    } else if f >= cells {
        cells as u64 - 1
    } else {
        f as u64
    }
}

/// Spherical coordinates `(θ, φ)` of direction `d` (need not be unit length): the polar angle
/// `θ = acos(d̂.z) ∈ [0, π]` from +z and the azimuth `φ = atan2(d.y, d.x) ∈ [−π, π]` (the
/// conversion the thesis applies before hashing, §3.2.3). A zero or non-finite direction
/// gives `(0, 0)`.
pub fn spherical(d: Vec3) -> (f32, f32) {
    let n = d.normalize_or_zero();
    if n == Vec3::ZERO {
        return (0.0, 0.0);
    }
    (n.z.clamp(-1.0, 1.0).acos(), n.y.atan2(n.x))
}

/// Quantized spherical direction: `θ` in `theta_bits` over `[0, π]` and `φ` in `phi_bits`
/// over `[−π, π]`.
pub fn spherical_cells(d: Vec3, theta_bits: u32, phi_bits: u32) -> (u64, u64) {
    let (theta, phi) = spherical(d);
    (
        quantize(theta, 0.0, std::f32::consts::PI, theta_bits),
        quantize(phi, -std::f32::consts::PI, std::f32::consts::PI, phi_bits),
    )
}

/// Octahedral encoding of direction `d` into `[−1, 1]²` (Cigolle et al. 2014, "A survey of
/// efficient representations for independent unit vectors"): project onto the octahedron
/// `|x| + |y| + |z| = 1` and fold the lower hemisphere over the diagonals. Cells of a uniform
/// grid on the square have nearly equal solid angle, unlike spherical coordinates, whose
/// cells shrink to slivers at the poles, and neighbouring directions stay neighbours except
/// across the fold. A zero or non-finite direction gives `(0, 0)`.
pub fn octahedral(d: Vec3) -> Vec2 {
    let l1 = d.x.abs() + d.y.abs() + d.z.abs();
    if !(l1 > 0.0 && l1.is_finite()) {
        return Vec2::ZERO;
    }
    let p = d / l1;
    if p.z >= 0.0 {
        Vec2::new(p.x, p.y)
    } else {
        let sign = |v: f32| if v >= 0.0 { 1.0 } else { -1.0 };
        Vec2::new((1.0 - p.y.abs()) * sign(p.x), (1.0 - p.x.abs()) * sign(p.y))
    }
}

/// How a hash lays out the fields of a group (the three origin cells, or `θ` and `φ`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum FieldOrder {
    /// One field after the other (`x | y | z`, `θ | φ`): a sort orders by the first field and
    /// only breaks its ties with the next, so a run of consecutive keys can cover a thin
    /// slice of the first field and the whole range of the last.
    #[default]
    Concatenated,
    /// Bits interleaved MSB-first ([`interleave`]): a Morton (Z-order) curve over the
    /// fields, so consecutive keys stay close in every field at once.
    Interleaved,
}

impl FieldOrder {
    /// Parses the `hash.layout` parameter value (`concat`, `interleave`).
    pub fn parse(s: &str) -> Option<FieldOrder> {
        match s {
            "concat" => Some(FieldOrder::Concatenated),
            "interleave" => Some(FieldOrder::Interleaved),
            _ => None,
        }
    }

    /// Combines `fields` (each `(value, width)`, first field most significant) in this order.
    pub fn combine(self, fields: &[(u64, u32)]) -> u64 {
        match self {
            FieldOrder::Concatenated => fields.iter().fold(0u64, |acc, &(v, w)| {
                let v = if w >= 64 { v } else { v & ((1u64 << w) - 1) };
                acc.checked_shl(w).unwrap_or(0) | v
            }),
            FieldOrder::Interleaved => interleave(fields),
        }
    }
}

/// Interleaves bit fields MSB-first, round robin: the output's top bit is the top bit of
/// `fields[0]`, then the top bit of `fields[1]`, …, then the second bit of `fields[0]`, and
/// so on; a field whose bits run out drops out of the rotation. Each field is `(value,
/// width)`; bits of `value` above `width` are ignored. The result has `Σ width` significant
/// low bits (at most 64; wider totals lose their top bits).
pub fn interleave(fields: &[(u64, u32)]) -> u64 {
    // Fast paths (bit spreading) for the shapes the hashers use; same result as the loop.
    let mask = |v: u64, w: u32| if w >= 64 { v } else { v & ((1u64 << w) - 1) };
    match *fields {
        [(a, wa), (b, wb)] if wb <= 32 && (wa == wb || wa == wb + 1) => {
            // Equal widths: `a` takes the odd positions; one bit more: the even ones.
            let (sa, sb) = if wa == wb { (1, 0) } else { (0, 1) };
            return (spread2(mask(a, wa)) << sa) | (spread2(mask(b, wb)) << sb);
        }
        [(x, w), (y, wy), (z, wz)] if w == wy && w == wz && w <= 21 => {
            return (spread3(mask(x, w)) << 2) | (spread3(mask(y, w)) << 1) | spread3(mask(z, w));
        }
        _ => {}
    }
    interleave_bits(fields)
}

/// Bit `i` of `v` (below 2³²) moves to bit `2i`.
fn spread2(v: u64) -> u64 {
    let mut x = v & 0xFFFF_FFFF;
    x = (x | (x << 16)) & 0x0000_FFFF_0000_FFFF;
    x = (x | (x << 8)) & 0x00FF_00FF_00FF_00FF;
    x = (x | (x << 4)) & 0x0F0F_0F0F_0F0F_0F0F;
    x = (x | (x << 2)) & 0x3333_3333_3333_3333;
    (x | (x << 1)) & 0x5555_5555_5555_5555
}

/// Bit `i` of `v` (below 2²¹) moves to bit `3i`.
fn spread3(v: u64) -> u64 {
    let mut x = v & 0x1F_FFFF;
    x = (x | (x << 32)) & 0x001F_0000_0000_FFFF;
    x = (x | (x << 16)) & 0x001F_0000_FF00_00FF;
    x = (x | (x << 8)) & 0x100F_00F0_0F00_F00F;
    x = (x | (x << 4)) & 0x10C3_0C30_C30C_30C3;
    (x | (x << 2)) & 0x1249_2492_4924_9249
}

/// The general interleaving, one bit at a time.
fn interleave_bits(fields: &[(u64, u32)]) -> u64 {
    let max_width = fields.iter().map(|f| f.1).max().unwrap_or(0);
    let mut out = 0u64;
    for level in 0..max_width {
        for &(value, width) in fields {
            if level < width {
                let bit = (value >> (width - 1 - level)) & 1;
                out = (out << 1) | bit;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantize_cells_clamp_and_degenerate_inputs() {
        assert_eq!(quantize(0.0, 0.0, 1.0, 2), 0);
        assert_eq!(quantize(0.24, 0.0, 1.0, 2), 0);
        assert_eq!(quantize(0.26, 0.0, 1.0, 2), 1);
        assert_eq!(quantize(0.99, 0.0, 1.0, 2), 3);
        assert_eq!(quantize(1.0, 0.0, 1.0, 2), 3);
        assert_eq!(quantize(5.0, 0.0, 1.0, 2), 3);
        assert_eq!(quantize(-5.0, 0.0, 1.0, 2), 0);
        assert_eq!(quantize(f32::NAN, 0.0, 1.0, 8), 0);
        assert_eq!(quantize(0.5, 1.0, 1.0, 8), 0);
        assert_eq!(quantize(0.5, 0.0, 1.0, 0), 0);
        assert_eq!(quantize(1.0, 0.0, 1.0, 32), u32::MAX as u64);
        let mut last = 0;
        for i in 0..=1000 {
            let q = quantize(i as f32 / 1000.0, 0.0, 1.0, 7);
            assert!(q >= last);
            last = q;
        }
        assert_eq!(last, 127);
    }

    #[test]
    fn spherical_known_directions() {
        let (t, p) = spherical(Vec3::Z);
        assert!(t.abs() < 1e-6 && p.abs() < 1e-6);
        let (t, _) = spherical(-Vec3::Z * 3.0);
        assert!((t - std::f32::consts::PI).abs() < 1e-6);
        let (t, p) = spherical(Vec3::Y);
        assert!((t - std::f32::consts::FRAC_PI_2).abs() < 1e-6);
        assert!((p - std::f32::consts::FRAC_PI_2).abs() < 1e-6);
        assert_eq!(spherical(Vec3::ZERO), (0.0, 0.0));
        assert_eq!(spherical(Vec3::NAN), (0.0, 0.0));
    }

    #[test]
    fn octahedral_corners_and_range() {
        assert_eq!(octahedral(Vec3::Z), Vec2::ZERO);
        assert_eq!(octahedral(Vec3::X), Vec2::new(1.0, 0.0));
        assert_eq!(octahedral(-Vec3::Y), Vec2::new(0.0, -1.0));
        let down = octahedral(-Vec3::Z);
        assert_eq!(down.abs(), Vec2::ONE);
        for i in 0..200 {
            let a = i as f32 * 0.7;
            let d = Vec3::new(a.sin() * (a * 1.3).cos(), a.cos(), (a * 2.1).sin());
            let e = octahedral(d);
            assert!(e.x.abs() <= 1.0 + 1e-6 && e.y.abs() <= 1.0 + 1e-6);
        }
    }

    #[test]
    fn interleave_round_robin_msb_first() {
        // Two 2-bit fields a = 0b10, b = 0b01 → a1 b1 a0 b0 = 1 0 0 1.
        assert_eq!(interleave(&[(0b10, 2), (0b01, 2)]), 0b1001);
        // Unequal widths: a = 0b111 (3), b = 0b0 (1) → a2 b0 a1 a0 = 1 0 1 1.
        assert_eq!(interleave(&[(0b111, 3), (0, 1)]), 0b1011);
        // Bits above the width are ignored.
        assert_eq!(interleave(&[(0xFF, 1)]), 1);
        assert_eq!(interleave(&[]), 0);
        // The fast paths give what the bit loop gives.
        let mut seed = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        };
        for _ in 0..2000 {
            let (a, b, c) = (next(), next(), next());
            for w in [0u32, 1, 2, 7, 15, 16, 21, 31, 32] {
                let two = [(a, w + 1), (b, w)];
                assert_eq!(interleave(&two), interleave_bits(&two), "{two:?}");
                let eq = [(a, w), (b, w)];
                assert_eq!(interleave(&eq), interleave_bits(&eq), "{eq:?}");
                if w <= 21 {
                    let three = [(a, w), (b, w), (c, w)];
                    assert_eq!(interleave(&three), interleave_bits(&three), "{three:?}");
                }
            }
        }
        assert_eq!(
            interleave(&[(u32::MAX as u64, 32), (u32::MAX as u64, 32)]),
            u64::MAX
        );
    }
}
