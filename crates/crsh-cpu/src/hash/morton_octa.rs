//! `morton`: a 5-D Morton key of the quantized ray origin and its octahedral direction (our
//! variant; compare the thesis's concatenated keys of seed 000 §3.2.3, figs 3.8-3.9).
//!
//! # Layout
//!
//! The origin is quantized in the scene bounds to `O = origin_bits` per axis (cells
//! `x, y, z`); the direction is mapped to the octahedral square `[−1, 1]²`
//! ([`crsh_core::quantize::octahedral`]) and quantized to `U = ⌈D/2⌉` and `V = ⌊D/2⌋` bits
//! for `D = direction_bits` (cells `u, v`, by [`crsh_core::quantize::octahedral_cells`], which
//! compares instead of dividing: the wgpu twin computes the same cells bit for bit). The five fields are interleaved MSB-first, round
//! robin ([`crsh_core::quantize::interleave`]):
//!
//! ```text
//!  high → low:  x₁ y₁ z₁ u₁ v₁ | x₂ y₂ z₂ u₂ v₂ | …   (k: k-th most significant bit)
//! ```
//!
//! so a field that is narrower than the others drops out once its bits are spent. The
//! defaults (`O = 10`, `D = 20`) give 50-bit keys in which every field has 10 bits. When
//! `3·O + D` asks for more than 64 bits, `D` is clamped to `64 − 3·O`.
//!
//! # Why it should group rays better than the thesis's keys
//!
//! The thesis's bounce key concatenates `x | y | z | θ | φ`: two rays with the same origin
//! cell but opposite directions are adjacent in the sort, while two rays with the same
//! direction one x-cell apart can be far apart (every y and z cell lies between them).
//! Interleaving makes every key prefix a 5-D cell — a box of origins times a patch of
//! directions, both halved at each step — so a run of sorted rays, and thus each hierarchy
//! node (§3.2.7), covers a small region *and* a narrow cone whichever is the more coherent.
//! The octahedral square also has nearly equal-area cells and no pole, whereas the spherical
//! `θ, φ` cells shrink to slivers near ±z and `φ` jumps at ±π.
//!
//! Every ray, shadow rays included, is hashed by its own origin and direction: those are what
//! the hierarchy bounds. With `shadow_origin = light` all shadow rays of a light share one
//! origin cell, so they group by light and then by direction.
//!
//! Keys depend only on the ray and the scene, so they do not depend on the thread count.

use std::sync::Arc;

use crsh_core::{
    Aabb, CoreError, Hasher, ParamInfo, Ray, RayKind, Registry, Result, StageKind, StageSpec,
    StageVariantInfo, Stats,
};
use crsh_scene::Scene;
use glam::Vec3;
use rayon::prelude::*;

use crate::backend::Cpu;
use crate::hash::thesis_bounce::MAX_ORIGIN_BITS;
use crsh_core::quantize::{interleave, octahedral_cells, quantize};

/// Default bits per origin axis.
pub const DEFAULT_ORIGIN_BITS: u32 = 10;
/// Default bits of the octahedral direction (10 per coordinate).
pub const DEFAULT_DIRECTION_BITS: u32 = 20;

/// The `morton` hasher.
#[derive(Clone, Debug)]
pub struct MortonOcta {
    bounds: Aabb,
    origin_bits: u32,
    u_bits: u32,
    v_bits: u32,
}

/// The catalogue entry of the `morton` hasher.
pub fn info() -> StageVariantInfo {
    StageVariantInfo::new(
        StageKind::Hash,
        "morton",
        "5-D Morton key interleaving the quantized origin and the octahedral direction, \
         coarse position and direction bits leading (ours; cf. seed 000 §3.2.3)",
    )
    .param(ParamInfo::int(
        "origin_bits",
        DEFAULT_ORIGIN_BITS as i64,
        0,
        MAX_ORIGIN_BITS as i64,
        "bits per origin axis in the scene bounds",
    ))
    .param(ParamInfo::int(
        "direction_bits",
        DEFAULT_DIRECTION_BITS as i64,
        0,
        64,
        "bits of the octahedral direction (u gets the odd bit); clamped so the key fits \
         64 bits",
    ))
}

/// Registers `morton` ([`info`], [`MortonOcta::new`]).
pub fn register(registry: &mut Registry<Cpu>) -> Result<()> {
    registry.add_hasher(info(), |ctx, spec| {
        Ok(Box::new(MortonOcta::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

impl MortonOcta {
    /// The hasher for `scene` with the parameters of a resolved `spec`.
    ///
    /// # Errors
    /// [`CoreError::InvalidParam`] for a parameter out of range.
    pub fn new(scene: &Arc<Scene>, spec: &StageSpec) -> Result<MortonOcta, CoreError> {
        let origin_bits = spec.u32_in("origin_bits", 0..=MAX_ORIGIN_BITS)?;
        let direction_bits = spec.u32_in("direction_bits", 0..=64)?;
        Ok(MortonOcta::with_bounds(
            scene.bounds,
            origin_bits,
            direction_bits,
        ))
    }

    /// The hasher for origins in `bounds`; `origin_bits` must be at most 21 (larger values
    /// are clamped to 21), `direction_bits` is clamped as the module docs say.
    pub fn with_bounds(bounds: Aabb, origin_bits: u32, direction_bits: u32) -> MortonOcta {
        let origin_bits = origin_bits.min(MAX_ORIGIN_BITS);
        let d = direction_bits.min(64 - 3 * origin_bits);
        MortonOcta {
            bounds,
            origin_bits,
            u_bits: d.div_ceil(2),
            v_bits: d / 2,
        }
    }

    /// Field widths `[x, y, z, u, v]`.
    pub fn widths(&self) -> [u32; 5] {
        let o = self.origin_bits;
        [o, o, o, self.u_bits, self.v_bits]
    }

    /// The quantized fields `[x, y, z, u, v]` of a ray with `origin` and `dir`.
    pub fn cells(&self, origin: Vec3, dir: Vec3) -> [u64; 5] {
        let (lo, hi) = (self.bounds.min, self.bounds.max);
        let o = self.origin_bits;
        let (u, v) = octahedral_cells(dir, self.u_bits, self.v_bits);
        [
            quantize(origin.x, lo.x, hi.x, o),
            quantize(origin.y, lo.y, hi.y, o),
            quantize(origin.z, lo.z, hi.z, o),
            u,
            v,
        ]
    }

    /// The key of a ray with `origin` and direction `dir` (any length).
    pub fn key(&self, origin: Vec3, dir: Vec3) -> u64 {
        let c = self.cells(origin, dir);
        let w = self.widths();
        interleave(&[
            (c[0], w[0]),
            (c[1], w[1]),
            (c[2], w[2]),
            (c[3], w[3]),
            (c[4], w[4]),
        ])
    }
}

impl Hasher<Cpu> for MortonOcta {
    fn name(&self) -> &str {
        "morton"
    }

    fn key_bits(&self) -> u32 {
        self.widths().iter().sum()
    }

    fn hash(
        &self,
        _backend: &Cpu,
        rays: &Vec<Ray>,
        _kind: RayKind,
        _stats: &mut Stats,
    ) -> Result<Vec<u64>> {
        Ok(rays.par_iter().map(|r| self.key(r.origin, r.dir)).collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hash::test_util::scene_with_lights;
    use crate::with_threads;
    use crsh_core::ParamValue;
    use crsh_core::RayKind;

    fn cube() -> Aabb {
        Aabb {
            min: Vec3::splat(-2.0),
            max: Vec3::splat(2.0),
        }
    }

    #[test]
    fn params_and_clamping() {
        let scene = scene_with_lights(1);
        let mut s = StageSpec::new("morton");
        for p in info().params {
            s.params.insert(p.name.to_string(), p.default);
        }
        let h = MortonOcta::new(&scene, &s).unwrap();
        assert_eq!(h.widths(), [10, 10, 10, 10, 10]);
        assert_eq!(Hasher::<Cpu>::key_bits(&h), 50);
        s.params.insert("origin_bits".into(), ParamValue::Int(22));
        assert!(MortonOcta::new(&scene, &s).is_err());
        s.params.insert("origin_bits".into(), ParamValue::Int(20));
        s.params
            .insert("direction_bits".into(), ParamValue::Int(64));
        let h = MortonOcta::new(&scene, &s).unwrap();
        assert_eq!(h.widths(), [20, 20, 20, 2, 2]);
        assert_eq!(Hasher::<Cpu>::key_bits(&h), 64);
        assert_eq!(
            MortonOcta::with_bounds(cube(), 3, 7).widths(),
            [3, 3, 3, 4, 3]
        );
    }

    #[test]
    fn layout_interleaves_origin_and_direction() {
        // 1 bit per field: key = x y z u v.
        let h = MortonOcta::with_bounds(cube(), 1, 2);
        // Origin in the high half of x only; +z maps to octahedral (0, 0) → cells (1, 1).
        assert_eq!(h.key(Vec3::new(1.0, -1.0, -1.0), Vec3::Z), 0b10011);
        assert_eq!(h.key(Vec3::new(-1.0, 1.0, -1.0), Vec3::Z), 0b01011);
        assert_eq!(h.key(Vec3::new(-1.0, -1.0, 1.0), Vec3::Z), 0b00111);
        // −x: octahedral (−1, 0) → u cell 0, v cell 1.
        assert_eq!(h.key(Vec3::splat(-1.0), -Vec3::X), 0b00001);
        // −y: octahedral (0, −1) → u cell 1, v cell 0.
        assert_eq!(h.key(Vec3::splat(-1.0), -Vec3::Y), 0b00010);
        // 2 bits per field: the coarse bit of every field precedes any fine bit.
        let h = MortonOcta::with_bounds(cube(), 2, 4);
        // (−0.45, −0.45, −0.1) folds to octahedral (−0.55, −0.55) → u, v cells 0.
        let coarse_x = h.key(Vec3::new(0.5, -2.0, -2.0), Vec3::new(-0.45, -0.45, -0.1));
        assert_eq!(coarse_x, 1 << 9);
        let coarse_u = h.key(Vec3::splat(-2.0), Vec3::new(1.0, -1.0, -0.01));
        assert_eq!(
            h.cells(Vec3::splat(-2.0), Vec3::new(1.0, -1.0, -0.01))[3],
            3
        );
        assert_eq!(coarse_u >> 5, 0b00010, "u's coarse bit in the first round");
    }

    #[test]
    fn keys_are_monotone_in_each_origin_axis() {
        let h = MortonOcta::with_bounds(cube(), 10, 20);
        let d = Vec3::new(0.3, 0.2, 0.9);
        for axis in 0..3 {
            let mut last = 0;
            for i in 0..=100 {
                let mut o = Vec3::splat(0.3);
                o[axis] = -2.0 + i as f32 * 0.04;
                let k = h.key(o, d);
                assert!(k >= last, "axis {axis} step {i}");
                last = k;
            }
        }
    }

    #[test]
    fn nearby_rays_share_a_long_prefix() {
        let h = MortonOcta::with_bounds(cube(), 10, 20);
        let o = Vec3::new(0.31, -0.72, 1.13);
        let d = Vec3::new(0.31, -0.5, 0.4);
        let a = h.key(o, d);
        let b = h.key(o + Vec3::splat(1e-4), d + Vec3::splat(1e-4));
        assert!((a ^ b).leading_zeros() >= 64 - 50 + 35, "{a:x} {b:x}");
        let far = h.key(-o, -d);
        assert!((a ^ far).leading_zeros() <= 64 - 50 + 5);
    }

    #[test]
    fn hash_is_deterministic_across_thread_counts() {
        let scene = scene_with_lights(2);
        let h = MortonOcta::with_bounds(scene.bounds, 10, 20);
        let rays: Vec<Ray> = (0..5000)
            .map(|i| {
                let a = i as f32 * 0.21;
                Ray {
                    origin: Vec3::new(a.sin(), (a * 0.5).cos(), (a * 0.1).sin()) * 2.0,
                    t_min: 0.0,
                    dir: Vec3::new(a.cos(), (a * 1.7).sin(), 0.3),
                    t_max: 10.0,
                    throughput: Vec3::ONE,
                    kind: RayKind::Reflection as u32,
                    pixel: i,
                    light: u32::MAX,
                    depth: 1,
                    source: i,
                }
            })
            .collect();
        let one = with_threads(1, || {
            h.hash(&Cpu, &rays, RayKind::Reflection, &mut Stats::default())
        })
        .unwrap()
        .unwrap();
        let three = with_threads(3, || {
            h.hash(&Cpu, &rays, RayKind::Reflection, &mut Stats::default())
        })
        .unwrap()
        .unwrap();
        assert_eq!(one, three);
        assert!(one.iter().all(|&k| k < 1 << 50));
    }
}
