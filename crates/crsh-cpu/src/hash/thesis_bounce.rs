//! The thesis's reflection / refraction hash (seed 000 §3.2.3, fig. 3.9): the ray origin
//! quantized in the scene bounds, then the spherical direction.
//!
//! # Layout
//!
//! With `O = origin_bits` per axis, `T = theta_bits`, `P = phi_bits` (low bit 0 on the right):
//!
//! ```text
//!  bit  3O+T+P-1 … 2O+T+P | … O+T+P | … T+P | T+P-1 … P | P-1 … 0
//!       x cell            | y cell  | z cell | θ cell   | φ cell
//! ```
//!
//! The drawing shows [`FieldOrder::Concatenated`]; with [`FieldOrder::Interleaved`] the three
//! origin cells interleave MSB-first (a Morton code), and so do `θ` and `φ` below them (see
//! [`crate::hash::thesis`]).
//!
//! Each origin coordinate is cut into `2^O` equal cells of the scene's bounding box
//! (coordinates outside it, e.g. after the epsilon offset, clamp to the border cells; a flat
//! axis is a single cell). The direction is `θ = acos(d.z)` over `[0, π]` and `φ = atan2(d.y,
//! d.x)` over `[−π, π]` ([`crsh_core::quantize::spherical_cells`]: exact comparisons against tabulated
//! boundaries, so the wgpu twin computes the same cells bit for bit); `θ` takes the odd bit
//! of the direction budget. In either order the origin stays above the direction, as the
//! thesis lists them: the key groups rays by origin cell first, and by direction within a cell.
//!
//! The thesis fits the whole key in 32 bits; the `thesis` variant's defaults are `O = 6` and a
//! 14-bit direction (`3·6 + 7 + 7 = 32`). The figure's exact split is not given in the text,
//! so this split is our reading: enough origin resolution to separate the objects of a scene
//! and about 1.4° (θ) / 2.8° (φ) per direction cell.
//!
//! # Bit budget
//!
//! `origin_bits ≤ 21` (so `3·O ≤ 63`). When `3·O + direction_bits` asks for more than 64
//! bits, the direction is clamped to the `64 − 3·O` bits that remain; each angle is further
//! limited to 32 bits.

use crsh_core::{Aabb, CoreError, Result};
use glam::Vec3;

use crsh_core::quantize::{quantize, spherical_cells, FieldOrder, UniformCells};

/// Field widths and the quantization box of the bounce hash.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BounceLayout {
    /// Bits per origin axis.
    pub origin_bits: u32,
    /// Bits of the polar angle `θ`.
    pub theta_bits: u32,
    /// Bits of the azimuth `φ`.
    pub phi_bits: u32,
    /// The box the origins are quantized in (the scene bounds).
    pub bounds: Aabb,
    /// How the fields of each group (`x, y, z`; `θ, φ`) are laid out: concatenated as drawn
    /// above, or interleaved within the group (origin still above direction).
    pub order: FieldOrder,
}

/// The most bits per origin axis (`3 · 21 = 63`).
pub const MAX_ORIGIN_BITS: u32 = 21;

impl BounceLayout {
    /// The layout for origins in `bounds` with `origin_bits` per axis and `direction_bits` for
    /// the direction, clamped to 64 bits in all (see the module docs).
    ///
    /// # Errors
    /// [`CoreError::InvalidParam`] when `origin_bits > 21`.
    pub fn new(bounds: Aabb, origin_bits: u32, direction_bits: u32) -> Result<BounceLayout> {
        if origin_bits > MAX_ORIGIN_BITS {
            return Err(CoreError::InvalidParam {
                key: "hash.origin_bits".into(),
                reason: format!("{origin_bits} is more than {MAX_ORIGIN_BITS} bits per axis"),
            });
        }
        let direction = direction_bits.min(64 - 3 * origin_bits);
        Ok(BounceLayout {
            origin_bits,
            theta_bits: direction.div_ceil(2).min(32),
            phi_bits: (direction / 2).min(32),
            bounds,
            order: FieldOrder::Concatenated,
        })
    }

    /// The same layout with each group's fields in `order`.
    pub fn with_order(self, order: FieldOrder) -> BounceLayout {
        BounceLayout { order, ..self }
    }

    /// Significant low bits of the keys.
    pub fn key_bits(&self) -> u32 {
        3 * self.origin_bits + self.theta_bits + self.phi_bits
    }

    /// The origin's cell per axis.
    pub fn origin_cells(&self, origin: Vec3) -> [u64; 3] {
        let (lo, hi) = (self.bounds.min, self.bounds.max);
        [
            quantize(origin.x, lo.x, hi.x, self.origin_bits),
            quantize(origin.y, lo.y, hi.y, self.origin_bits),
            quantize(origin.z, lo.z, hi.z, self.origin_bits),
        ]
    }

    /// The key of a ray with `origin` and direction `dir` (any length).
    pub fn key(&self, origin: Vec3, dir: Vec3) -> u64 {
        let (theta, phi) = spherical_cells(dir, self.theta_bits, self.phi_bits);
        self.key_of_cells(self.origin_cells(origin), theta, phi)
    }

    /// The origin's quantizers, one per axis ([`BounceLayout::origin_cells`] is
    /// `quantizers[i].cell(origin[i])`), for hashing many rays.
    pub fn origin_quantizers(&self) -> [UniformCells; 3] {
        let (lo, hi) = (self.bounds.min, self.bounds.max);
        [0, 1, 2].map(|i| UniformCells::new(lo[i], hi[i], self.origin_bits))
    }

    /// The key of a ray whose origin has the cells `[x, y, z]` and whose direction has the
    /// cells `(theta, phi)` of this layout's widths.
    pub fn key_of_cells(&self, [x, y, z]: [u64; 3], theta: u64, phi: u64) -> u64 {
        let o = self.origin_bits;
        let d = self.theta_bits + self.phi_bits;
        let origin = self.order.combine(&[(x, o), (y, o), (z, o)]);
        let dir = self
            .order
            .combine(&[(theta, self.theta_bits), (phi, self.phi_bits)]);
        // A shift by 64 only happens when the origin field is 0 bits wide; `checked_shl`
        // keeps it defined.
        origin.checked_shl(d).unwrap_or(0) | dir
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit_box() -> Aabb {
        Aabb {
            min: Vec3::ZERO,
            max: Vec3::splat(8.0),
        }
    }

    #[test]
    fn default_layout_is_32_bits_and_budget_clamps() {
        let l = BounceLayout::new(unit_box(), 6, 14).unwrap();
        assert_eq!((l.theta_bits, l.phi_bits, l.key_bits()), (7, 7, 32));
        let l = BounceLayout::new(unit_box(), 20, 30).unwrap();
        assert_eq!((l.theta_bits, l.phi_bits, l.key_bits()), (2, 2, 64));
        let l = BounceLayout::new(unit_box(), 21, 64).unwrap();
        assert_eq!((l.theta_bits, l.phi_bits, l.key_bits()), (1, 0, 64));
        let l = BounceLayout::new(unit_box(), 0, 64).unwrap();
        assert_eq!((l.theta_bits, l.phi_bits, l.key_bits()), (32, 32, 64));
        assert!(BounceLayout::new(unit_box(), 22, 0).is_err());
    }

    #[test]
    fn fields_hold_origin_cells_then_direction() {
        let l = BounceLayout::new(unit_box(), 3, 8).unwrap(); // 3·3 + 4 + 4 = 17 bits
                                                              // Origin (1.5, 3.5, 7.9) → cells (1, 3, 7); +z → θ 0, φ middle (8).
        let k = l.key(Vec3::new(1.5, 3.5, 7.9), Vec3::Z);
        assert_eq!(k >> 14, 1);
        assert_eq!((k >> 11) & 7, 3);
        assert_eq!((k >> 8) & 7, 7);
        assert_eq!((k >> 4) & 15, 0);
        assert_eq!(k & 15, 8);
        assert!(k < 1 << 17);
        // Outside the box clamps to the border cells.
        let k = l.key(Vec3::new(-1.0, 9.0, 4.0), -Vec3::Z);
        assert_eq!(k >> 14, 0);
        assert_eq!((k >> 11) & 7, 7);
        assert_eq!((k >> 8) & 7, 4);
        assert_eq!((k >> 4) & 15, 15);
    }

    #[test]
    fn keys_are_monotone_in_each_field() {
        let l = BounceLayout::new(unit_box(), 6, 14).unwrap();
        let base = Vec3::new(2.0, 2.0, 2.0);
        let d = Vec3::new(0.2, 0.3, 0.9);
        for axis in 0..3 {
            let mut last = 0;
            for i in 0..=80 {
                let mut o = base;
                o[axis] = i as f32 * 0.1;
                let k = l.key(o, d);
                assert!(k >= last, "axis {axis} step {i}");
                last = k;
            }
        }
        // The x cell dominates every lower field.
        let a = l.key(Vec3::new(1.0, 7.9, 7.9), -Vec3::Z);
        let b = l.key(Vec3::new(1.2, 0.0, 0.0), Vec3::Z);
        assert!(b > a);
    }

    #[test]
    fn nearby_rays_get_equal_keys_distant_rays_do_not() {
        let l = BounceLayout::new(unit_box(), 6, 14).unwrap();
        let o = Vec3::new(3.01, 4.02, 5.03);
        let d = Vec3::new(0.3, -0.5, 0.4);
        assert_eq!(l.key(o, d), l.key(o + Vec3::splat(1e-3), d * 2.0 + 1e-4));
        assert_ne!(l.key(o, d), l.key(o + Vec3::X, d));
        assert_ne!(l.key(o, d), l.key(o, -d));
    }

    #[test]
    fn flat_bounds_put_the_thin_axis_in_one_cell() {
        let flat = Aabb {
            min: Vec3::new(0.0, 1.0, 0.0),
            max: Vec3::new(4.0, 1.0, 4.0),
        };
        let l = BounceLayout::new(flat, 4, 8).unwrap();
        assert_eq!(l.origin_cells(Vec3::new(1.0, 1.0, 3.9)), [4, 0, 15]);
    }
}
