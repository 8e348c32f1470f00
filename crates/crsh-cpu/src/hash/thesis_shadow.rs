//! The thesis's shadow-ray hash (seed 000 §3.2.3, fig. 3.8): light index, then the spherical
//! direction of the ray as seen from the light.
//!
//! # Layout
//!
//! With `L = light_bits`, `T = theta_bits`, `P = phi_bits` (low bit 0 on the right):
//!
//! ```text
//!  bit  L+T+P-1 … T+P | T+P-1 … P | P-1 … 0
//!       light index   | θ cell    | φ cell
//! ```
//!
//! The drawing shows [`FieldOrder::Concatenated`]; with [`FieldOrder::Interleaved`] the
//! `T + P` direction bits interleave `θ` and `φ` MSB-first instead (see [`crate::hash::thesis`]).
//!
//! The light index holds the highest bits, so a sort groups the shadow rays by light first
//! ("sorted according to the light source a priori", §3.2.3); below it the direction in
//! spherical coordinates, `θ = acos(d.z) ∈ [0, π]` over `T` bits and `φ = atan2(d.y, d.x) ∈
//! [−π, π]` over `P` bits ([`crsh_core::quantize::spherical_cells`]: exact comparisons against tabulated
//! boundaries, so the wgpu twin computes the same cells bit for bit). The ray origin is not
//! hashed: in the thesis's convention (eq. 3.1) every shadow ray of a light starts at the light.
//! [`ShadowLayout::new`] sizes `L` to the scene's light count and splits the rest of a total
//! budget (32 bits in the thesis) between `θ` (the odd bit) and `φ`.
//!
//! # Origin convention
//!
//! The hashed direction is always the light→point direction. With `raygen.shadow_origin =
//! light` that is the ray's own direction; with `raygen.shadow_origin = surface` the ray runs
//! from the surface to the light, so [`light_to_point_direction`] uses `−dir`. The convention
//! is recognised per ray, from which end of the ray's segment lies nearer to its light.

use crsh_core::{CoreError, Ray, Result};
use glam::Vec3;

use crsh_core::quantize::{product, spherical_cells, FieldOrder};

/// Field widths of the shadow hash.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ShadowLayout {
    /// Bits of the light index (highest field).
    pub light_bits: u32,
    /// Bits of the polar angle `θ` (middle field).
    pub theta_bits: u32,
    /// Bits of the azimuth `φ` (lowest field).
    pub phi_bits: u32,
    /// How `θ` and `φ` share the direction bits (concatenated as drawn above, or
    /// interleaved).
    pub order: FieldOrder,
}

/// Bits needed to store the indices `0 .. count` (0 for one or no item).
pub fn index_bits(count: usize) -> u32 {
    if count <= 1 {
        0
    } else {
        usize::BITS - (count - 1).leading_zeros()
    }
}

impl ShadowLayout {
    /// The layout for `lights` lights in `total_bits` bits: the light field gets
    /// [`index_bits`]`(lights)`, the direction the rest, `θ` taking the odd bit.
    ///
    /// # Errors
    /// [`CoreError::InvalidParam`] when `total_bits > 64` or fewer than 2 bits remain for the
    /// direction.
    pub fn new(lights: usize, total_bits: u32) -> Result<ShadowLayout> {
        let light_bits = index_bits(lights);
        if total_bits > 64 || total_bits < light_bits + 2 {
            return Err(CoreError::InvalidParam {
                key: "hash.shadow_bits".into(),
                reason: format!(
                    "{total_bits} bits cannot hold {light_bits} light-index bits and at least 2 \
                     direction bits (at most 64)"
                ),
            });
        }
        let direction = total_bits - light_bits;
        Ok(ShadowLayout {
            light_bits,
            theta_bits: direction.div_ceil(2).min(32),
            phi_bits: (direction / 2).min(32),
            order: FieldOrder::Concatenated,
        })
    }

    /// The same layout with the direction fields in `order`.
    pub fn with_order(self, order: FieldOrder) -> ShadowLayout {
        ShadowLayout { order, ..self }
    }

    /// Significant low bits of the keys.
    pub fn key_bits(&self) -> u32 {
        self.light_bits + self.theta_bits + self.phi_bits
    }

    /// The key of a shadow ray of light `light` whose light→point direction is `dir` (any
    /// length). A light index that does not fit `light_bits` saturates to the largest one.
    pub fn key(&self, light: u32, dir: Vec3) -> u64 {
        let (theta, phi) = spherical_cells(dir, self.theta_bits, self.phi_bits);
        self.key_of_cells(light, theta, phi)
    }

    /// The key of a shadow ray of light `light` whose light→point direction has the cells
    /// `(theta, phi)` of this layout's widths ([`crsh_core::quantize::SphericalCells`]).
    pub fn key_of_cells(&self, light: u32, theta: u64, phi: u64) -> u64 {
        let max_light = (1u64 << self.light_bits) - 1;
        let light = (light as u64).min(max_light);
        let dir = self
            .order
            .combine(&[(theta, self.theta_bits), (phi, self.phi_bits)]);
        (light << (self.theta_bits + self.phi_bits)) | dir
    }
}

/// The light→point direction of shadow ray `ray` whose light sits at `light`: `ray.dir` when
/// the ray starts at (nearer) the light (`shadow_origin = light`, eq. 3.1-3.2), `−ray.dir`
/// when its far end `origin + t_max·dir` is nearer the light (`shadow_origin = surface`).
///
/// The end point and the squared distances use [`crsh_core::quantize::product`] for every
/// product, so the wgpu twin, whose compiler may fuse products into sums, decides alike.
///
/// # Errors
/// [`CoreError::InvalidInput`] when the ray's segment end is not finite.
pub fn light_to_point_direction(ray: &Ray, light: Vec3) -> Result<Vec3> {
    if ray.origin == light && surely_finite_end(ray) {
        // The thesis's convention (`shadow_origin = light`), with an end point that cannot
        // overflow: the outcome of the checks below, without their products.
        return Ok(ray.dir);
    }
    let end = Vec3::from_array(std::array::from_fn(|i| {
        ray.origin[i] + product(ray.dir[i], ray.t_max)
    }));
    if !end.is_finite() {
        return Err(CoreError::InvalidInput(format!(
            "shadow ray with non-finite segment (origin {}, dir {}, t_max {})",
            ray.origin, ray.dir, ray.t_max
        )));
    }
    if ray.origin == light {
        // The distance from the origin is 0 (every product and sum below is 0), never more
        // than the end's (a sum of non-negative products): the comparison's outcome, without
        // computing it.
        return Ok(ray.dir);
    }
    let dist2 = |p: Vec3| {
        let v = p - light;
        (product(v.x, v.x) + product(v.y, v.y)) + product(v.z, v.z)
    };
    if dist2(ray.origin) <= dist2(end) {
        Ok(ray.dir)
    } else {
        Ok(-ray.dir)
    }
}

/// Whether `ray`'s end point `origin + product(dir, t_max)` is finite without computing it:
/// finite inputs with `|t_max| < 2⁹⁹`, `|dir| < 2²⁰` and `|origin| < 2¹²⁰` per component keep
/// every product near or below `2¹¹⁹` and every sum below `2¹²¹`, far from `f32`'s overflow
/// at `2¹²⁸`. `false` says nothing (the end may still be finite).
#[inline]
fn surely_finite_end(ray: &Ray) -> bool {
    const T: f32 = (1u128 << 99) as f32;
    const D: f32 = (1u32 << 20) as f32;
    const O: f32 = (1u128 << 120) as f32;
    // Comparisons with NaN are false, so a NaN fails them too.
    ray.t_max.abs() < T
        && ray.dir.abs().cmplt(Vec3::splat(D)).all()
        && ray.origin.abs().cmplt(Vec3::splat(O)).all()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crsh_core::RayKind;

    #[test]
    fn layout_sizes_light_field_to_the_scene() {
        assert_eq!(index_bits(0), 0);
        assert_eq!(index_bits(1), 0);
        assert_eq!(index_bits(2), 1);
        assert_eq!(index_bits(5), 3);
        assert_eq!(index_bits(8), 3);
        assert_eq!(index_bits(9), 4);
        let l = ShadowLayout::new(3, 32).unwrap();
        assert_eq!((l.light_bits, l.theta_bits, l.phi_bits), (2, 15, 15));
        assert_eq!(l.key_bits(), 32);
        let l = ShadowLayout::new(1, 32).unwrap();
        assert_eq!((l.light_bits, l.theta_bits, l.phi_bits), (0, 16, 16));
        let l = ShadowLayout::new(4, 13).unwrap();
        assert_eq!((l.light_bits, l.theta_bits, l.phi_bits), (2, 6, 5));
        assert!(ShadowLayout::new(4, 3).is_err());
        assert!(ShadowLayout::new(4, 65).is_err());
        let l = ShadowLayout::new(1, 64).unwrap();
        assert_eq!(l.key_bits(), 64);
    }

    #[test]
    fn fields_hold_light_theta_phi() {
        let l = ShadowLayout::new(4, 32).unwrap(); // 2 + 15 + 15
                                                   // +z: θ = 0; φ = atan2(0, 0) = 0 → middle cell of [−π, π].
        let k = l.key(3, Vec3::Z);
        assert_eq!(k >> 30, 3);
        assert_eq!((k >> 15) & 0x7FFF, 0);
        assert_eq!(k & 0x7FFF, 1 << 14);
        // −z: θ = π → last θ cell.
        let k = l.key(0, -Vec3::Z);
        assert_eq!(k >> 30, 0);
        assert_eq!((k >> 15) & 0x7FFF, 0x7FFF);
        // +y: θ = π/2 → middle θ cell, φ = π/2 → three quarters of the φ range.
        let k = l.key(1, Vec3::Y * 2.0);
        assert_eq!(k >> 30, 1);
        assert_eq!((k >> 15) & 0x7FFF, 1 << 14);
        assert_eq!(k & 0x7FFF, 3 << 13);
        assert!(k < 1 << 32);
        // Out-of-range light saturates.
        assert_eq!(l.key(17, Vec3::Z) >> 30, 3);
    }

    #[test]
    fn light_index_sorts_first_and_fields_are_monotone() {
        let l = ShadowLayout::new(4, 32).unwrap();
        // Any direction of light 1 sorts after every direction of light 0.
        let worst0 = l.key(0, Vec3::new(-1e-3, -1.0, -1.0));
        let best1 = l.key(1, Vec3::Z);
        assert!(best1 > worst0);
        // θ grows from +z to −z at fixed φ.
        let mut last = 0;
        for i in 0..=64 {
            let t = std::f32::consts::PI * i as f32 / 64.0;
            let k = l.key(2, Vec3::new(t.sin(), 0.0, t.cos()));
            assert!(k >= last, "θ step {i}");
            last = k;
        }
        // φ grows with the azimuth at fixed θ.
        let mut last = 0;
        for i in 1..64 {
            let p = -std::f32::consts::PI + 2.0 * std::f32::consts::PI * i as f32 / 64.0;
            let k = l.key(2, Vec3::new(p.cos(), p.sin(), 0.0));
            assert!(k > last, "φ step {i}");
            last = k;
        }
    }

    #[test]
    fn nearby_directions_share_or_neighbour_keys() {
        let l = ShadowLayout::new(2, 32).unwrap();
        let d = Vec3::new(0.3, -0.4, 0.8).normalize();
        let e = (d + Vec3::new(1e-4, 0.0, 0.0)).normalize();
        let (a, b) = (l.key(1, d), l.key(1, e));
        let theta = |k: u64| (k >> 15) & 0x7FFF;
        let phi = |k: u64| k & 0x7FFF;
        assert!(theta(a).abs_diff(theta(b)) <= 1 && phi(a).abs_diff(phi(b)) <= 2);
        assert_eq!(l.key(1, d), l.key(1, d * 7.0));
    }

    fn shadow(origin: Vec3, dir: Vec3, t_max: f32) -> Ray {
        Ray {
            origin,
            t_min: 1e-4,
            dir,
            t_max,
            throughput: Vec3::ONE,
            kind: RayKind::Shadow as u32,
            pixel: 0,
            light: 0,
            depth: 1,
            source: 0,
        }
    }

    /// A ray from the light takes the shortcut unless its end might overflow, and errs exactly
    /// when its end point, computed as the slow path computes it, is not finite.
    #[test]
    fn light_origin_shortcut_decides_as_the_end_point_does() {
        let big = [
            0.0,
            1.0,
            3.5,
            1e6,
            1e20,
            6e29,
            1e30,
            1e37,
            3e38,
            f32::MAX,
            f32::INFINITY,
            f32::NAN,
        ];
        let mut cases = 0;
        for &o in &big {
            for &d in &big {
                for &t in &big {
                    for sign in [1.0f32, -1.0] {
                        let light = Vec3::new(o * sign, -0.5, o);
                        let dir = Vec3::new(0.25, d * sign, -1.0);
                        let r = shadow(light, dir, t);
                        let end = Vec3::from_array(std::array::from_fn(|i| {
                            r.origin[i] + product(r.dir[i], r.t_max)
                        }));
                        let got = light_to_point_direction(&r, light);
                        assert_eq!(got.is_ok(), end.is_finite(), "o {o} d {d} t {t}");
                        if let Ok(v) = got {
                            assert_eq!(
                                v.to_array().map(f32::to_bits),
                                dir.to_array().map(f32::to_bits)
                            );
                        }
                        if surely_finite_end(&r) {
                            assert!(end.is_finite(), "shortcut for o {o} d {d} t {t}");
                            cases += 1;
                        }
                    }
                }
            }
        }
        assert!(cases > 100, "the shortcut is taken ({cases})");
    }

    #[test]
    fn both_origin_conventions_hash_the_light_to_point_direction() {
        let light = Vec3::new(0.0, 5.0, 0.0);
        let p = Vec3::new(1.0, 0.0, 2.0);
        let d = (p - light).normalize();
        let len = (p - light).length();
        let from_light = shadow(light, d, len * 0.999);
        let from_surface = shadow(p, -d, len * 0.999);
        assert_eq!(light_to_point_direction(&from_light, light).unwrap(), d);
        assert_eq!(light_to_point_direction(&from_surface, light).unwrap(), d);
        let bad = shadow(p, -d, f32::INFINITY);
        assert!(light_to_point_direction(&bad, light).is_err());
    }
}
