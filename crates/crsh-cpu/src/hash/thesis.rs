//! `thesis`: the per-kind ray hashes of seed 000 §3.2.3 (figs 3.8-3.9).
//!
//! - Shadow rays: [`crate::hash::thesis_shadow`], light index then spherical direction in
//!   `shadow_bits` (32 by default, as in the thesis); the light field is sized to the scene's
//!   light count.
//! - Reflection and refraction rays (and camera rays, should a pipeline hash them):
//!   [`crate::hash::thesis_bounce`], origin quantized in the scene bounds (`origin_bits` per
//!   axis) then spherical direction (`direction_bits`); 32 bits by default.
//!
//! # Field layout (`layout`)
//!
//! Figs 3.8-3.9 are not in the text we have, which only says that the light index takes the
//! highest bits and that the direction goes in spherical coordinates below it (and the
//! origin above the direction for bounce rays). How `θ` and `φ` (and `x`, `y`, `z`) share
//! their bits is our choice, and it decides how good the hierarchy is:
//! - `concat` writes `θ | φ` (and `x | y | z`). Sorting then orders by `θ` first: with more
//!   `θ` cells than rays per node, `subdivision` consecutive rays share a thin band of `θ` but
//!   cover the whole circle of `φ`, so the lowest nodes' cones are wide. Measured (256², 3 bounces,
//!   subdivision 8, depth 2, `crsh render`): more total tests than RAH on the built-in scenes
//!   (cornell-mirrors 2.2×, office-boxes 5.7× RAH's).
//! - `interleave` (the default) interleaves the bits of each group MSB-first, a Z-order curve,
//!   so consecutive keys are close in both angles (and in all three origin axes): 0.51× RAH on
//!   cornell-mirrors, 0.30× on office-boxes, 0.08× on Sponza.
//!
//! Both keep the thesis's field priority (light, then origin, then direction) and bit budgets.
//!
//! A batch holds one kind, which the driver passes to [`Hasher::hash`]; each ray is keyed by
//! its own [`Ray::kind`] all the same, so a mixed batch (the stability suite's, the wgpu
//! twin's tests) is hashed consistently too. [`Hasher::key_bits`] is the wider of the two layouts. Keys depend
//! only on the ray and the scene, so they do not depend on the thread count.
//!
//! # Errors
//! [`CoreError::InvalidInput`] for a ray with an unknown kind, a shadow ray whose light index
//! is not a light of the scene, or a shadow ray with a non-finite segment.

use std::sync::Arc;

use crsh_core::{
    CoreError, Hasher, ParamInfo, Ray, RayKind, Registry, Result, StageKind, StageSpec,
    StageVariantInfo, Stats,
};
use crsh_scene::Scene;
use glam::Vec3;
use rayon::prelude::*;

use crate::backend::Cpu;
use crate::hash::thesis_bounce::{BounceLayout, MAX_ORIGIN_BITS};
use crate::hash::thesis_shadow::{light_to_point_direction, ShadowLayout};
use crsh_core::quantize::{FieldOrder, SphericalCells, UniformCells};

/// Default bits per origin axis of the bounce hash (`3·6 + 14 = 32`).
pub const DEFAULT_ORIGIN_BITS: u32 = 6;
/// Default direction bits of the bounce hash (θ 7, φ 7).
pub const DEFAULT_DIRECTION_BITS: u32 = 14;
/// Default total bits of the shadow hash (the thesis's 32-bit key).
pub const DEFAULT_SHADOW_BITS: u32 = 32;

/// The `thesis` hasher.
#[derive(Clone, Debug)]
pub struct ThesisHasher {
    shadow: ShadowLayout,
    bounce: BounceLayout,
    lights: Vec<Vec3>,
    /// The direction cells of each layout and the origin quantizers, prepared once.
    shadow_cells: SphericalCells,
    bounce_cells: SphericalCells,
    origin_cells: [UniformCells; 3],
}

/// Rays per pass of [`ThesisHasher::keys_of`].
const KEY_PASS: usize = 64;

/// The catalogue entry of the `thesis` hasher.
pub fn info() -> StageVariantInfo {
    StageVariantInfo::new(
        StageKind::Hash,
        "thesis",
        "per-kind ray hash of seed 000 §3.2.3 (figs 3.8-3.9): shadow = light index + \
         spherical direction, reflection/refraction = quantized origin + spherical direction",
    )
    .param(ParamInfo::int(
        "origin_bits",
        DEFAULT_ORIGIN_BITS as i64,
        0,
        MAX_ORIGIN_BITS as i64,
        "bits per origin axis in the scene bounds, reflection/refraction rays",
    ))
    .param(ParamInfo::int(
        "direction_bits",
        DEFAULT_DIRECTION_BITS as i64,
        0,
        64,
        "bits of the spherical direction (θ gets the odd bit), reflection/refraction rays; \
         clamped so the key fits 64 bits",
    ))
    .param(ParamInfo::choice(
        "layout",
        "interleave",
        &["interleave", "concat"],
        "field layout within the origin (x, y, z) and direction (θ, φ) groups: interleaved \
         bits (Morton order) or concatenated (figs 3.8-3.9 read literally); see the module \
         docs",
    ))
    .param(ParamInfo::int(
        "shadow_bits",
        DEFAULT_SHADOW_BITS as i64,
        2,
        64,
        "total bits of a shadow key: light index (sized to the scene's lights) + spherical \
         direction",
    ))
}

/// Registers `thesis` ([`info`], [`ThesisHasher::new`]).
pub fn register(registry: &mut Registry<Cpu>) -> Result<()> {
    registry.add_hasher(info(), |ctx, spec| {
        Ok(Box::new(ThesisHasher::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

impl ThesisHasher {
    /// The hasher for `scene` with the parameters of a resolved `spec`.
    ///
    /// # Errors
    /// [`CoreError::InvalidParam`] for a parameter out of range, or `shadow_bits` too small
    /// for the scene's light count plus 2 direction bits.
    pub fn new(scene: &Arc<Scene>, spec: &StageSpec) -> Result<ThesisHasher, CoreError> {
        let origin_bits = spec.u32_in("origin_bits", 0..=MAX_ORIGIN_BITS)?;
        let direction_bits = spec.u32_in("direction_bits", 0..=64)?;
        let shadow_bits = spec.u32_in("shadow_bits", 2..=64)?;
        let layout = spec.str("layout")?;
        let order = FieldOrder::parse(layout).ok_or_else(|| CoreError::InvalidParam {
            key: "hash.layout".into(),
            reason: format!("`{layout}` is not a layout (interleave, concat)"),
        })?;
        Ok(
            ThesisHasher::from_parts(scene, origin_bits, direction_bits, shadow_bits)?
                .with_order(order),
        )
    }

    /// The same hasher with the fields of every group laid out in `order` (the `layout`
    /// parameter; [`ThesisHasher::from_parts`] starts concatenated).
    pub fn with_order(self, order: FieldOrder) -> ThesisHasher {
        ThesisHasher {
            shadow: self.shadow.with_order(order),
            bounce: self.bounce.with_order(order),
            ..self
        }
    }

    /// The hasher for `scene` with explicit bit budgets (see [`info`]).
    ///
    /// # Errors
    /// As [`ThesisHasher::new`].
    pub fn from_parts(
        scene: &Scene,
        origin_bits: u32,
        direction_bits: u32,
        shadow_bits: u32,
    ) -> Result<ThesisHasher> {
        let shadow = ShadowLayout::new(scene.lights.len(), shadow_bits)?;
        let bounce = BounceLayout::new(scene.bounds, origin_bits, direction_bits)?;
        Ok(ThesisHasher {
            shadow,
            bounce,
            lights: scene.lights.iter().map(|l| l.position).collect(),
            shadow_cells: SphericalCells::new(shadow.theta_bits, shadow.phi_bits),
            bounce_cells: SphericalCells::new(bounce.theta_bits, bounce.phi_bits),
            origin_cells: bounce.origin_quantizers(),
        })
    }

    /// The shadow-ray layout.
    pub fn shadow_layout(&self) -> &ShadowLayout {
        &self.shadow
    }

    /// The reflection / refraction layout.
    pub fn bounce_layout(&self) -> &BounceLayout {
        &self.bounce
    }

    /// The key of one ray.
    ///
    /// # Errors
    /// As the module docs say.
    pub fn key(&self, ray: &Ray) -> Result<u64> {
        let mut key = [0];
        self.keys_of(std::slice::from_ref(ray), &mut key)?;
        Ok(key[0])
    }

    /// The hashed direction of `ray` and whether it is a shadow ray.
    #[inline]
    fn direction(&self, ray: &Ray) -> Result<(Vec3, bool)> {
        match RayKind::from_u32(ray.kind) {
            Some(RayKind::Shadow) => {
                let light = self.lights.get(ray.light as usize).ok_or_else(|| {
                    CoreError::InvalidInput(format!(
                        "shadow ray names light {} but the scene has {} lights",
                        ray.light,
                        self.lights.len()
                    ))
                })?;
                Ok((light_to_point_direction(ray, *light)?, true))
            }
            Some(_) => Ok((ray.dir, false)),
            None => Err(CoreError::InvalidInput(format!(
                "ray with unknown kind {}",
                ray.kind
            ))),
        }
    }

    /// The keys of `rays` into `keys` (the same length), in passes of [`KEY_PASS`] rays: the
    /// direction cells of a pass's rays of each layout are found together
    /// ([`SphericalCells::cells_of`]), which lets their computations overlap; the keys are
    /// those of [`ThesisHasher::key`] one ray at a time.
    fn keys_of(&self, rays: &[Ray], keys: &mut [u64]) -> Result<()> {
        debug_assert_eq!(rays.len(), keys.len());
        let mut dirs = [[Vec3::ZERO; KEY_PASS]; 2];
        let mut slots = [[0u8; KEY_PASS]; 2];
        let mut cells = [[(0u64, 0u64); KEY_PASS]; 2];
        for (rays, keys) in rays.chunks(KEY_PASS).zip(keys.chunks_mut(KEY_PASS)) {
            // Directions sorted into the shadow (0) and bounce (1) layouts' lists.
            let mut len = [0usize; 2];
            for (i, ray) in rays.iter().enumerate() {
                let (d, shadow) = self.direction(ray)?;
                let l = usize::from(!shadow);
                dirs[l][len[l]] = d;
                slots[l][len[l]] = i as u8;
                len[l] += 1;
            }
            self.shadow_cells
                .cells_of(&dirs[0][..len[0]], &mut cells[0][..len[0]]);
            self.bounce_cells
                .cells_of(&dirs[1][..len[1]], &mut cells[1][..len[1]]);
            for (&i, &(t, p)) in slots[0][..len[0]].iter().zip(&cells[0][..len[0]]) {
                let ray = &rays[i as usize];
                keys[i as usize] = self.shadow.key_of_cells(ray.light, t, p);
            }
            for (&i, &(t, p)) in slots[1][..len[1]].iter().zip(&cells[1][..len[1]]) {
                let o = rays[i as usize].origin;
                let q = &self.origin_cells;
                let origin = [q[0].cell(o.x), q[1].cell(o.y), q[2].cell(o.z)];
                keys[i as usize] = self.bounce.key_of_cells(origin, t, p);
            }
        }
        Ok(())
    }
}

impl Hasher<Cpu> for ThesisHasher {
    fn name(&self) -> &str {
        "thesis"
    }

    fn key_bits(&self) -> u32 {
        self.shadow.key_bits().max(self.bounce.key_bits())
    }

    /// Keys each ray by its own [`Ray::kind`] (the driver's batches hold one kind, `_kind`;
    /// the wgpu twin reads the kind per ray too, so mixed batches hash alike on both).
    fn hash(
        &self,
        _backend: &Cpu,
        rays: &Vec<Ray>,
        _kind: RayKind,
        _stats: &mut Stats,
    ) -> Result<Vec<u64>> {
        let mut keys = vec![0u64; rays.len()];
        rays.par_chunks(KEY_PASS * 16)
            .zip(keys.par_chunks_mut(KEY_PASS * 16))
            .try_for_each(|(rays, keys)| self.keys_of(rays, keys))?;
        Ok(keys)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::with_threads;
    use crsh_core::ParamValue;

    fn test_scene(lights: usize) -> Arc<Scene> {
        crate::hash::test_util::scene_with_lights(lights)
    }

    fn spec(origin: i64, direction: i64, shadow: i64) -> StageSpec {
        let mut s = StageSpec::new("thesis");
        s.params
            .insert("origin_bits".into(), ParamValue::Int(origin));
        s.params
            .insert("direction_bits".into(), ParamValue::Int(direction));
        s.params
            .insert("shadow_bits".into(), ParamValue::Int(shadow));
        s.params
            .insert("layout".into(), ParamValue::Str("concat".into()));
        s
    }

    fn ray(kind: RayKind, origin: Vec3, dir: Vec3, light: u32) -> Ray {
        Ray {
            light,
            ..Ray::new(kind, origin, dir, 1e-4, 3.0)
        }
    }

    #[test]
    fn info_defaults_build_a_32_bit_hasher() {
        let scene = test_scene(3);
        let i = info();
        let mut s = StageSpec::new("thesis");
        for p in &i.params {
            s.params.insert(p.name.to_string(), p.default.clone());
        }
        let h = ThesisHasher::new(&scene, &s).unwrap();
        assert_eq!(Hasher::<Cpu>::key_bits(&h), 32);
        assert_eq!(h.shadow_layout().light_bits, 2);
        assert_eq!(h.bounce_layout().key_bits(), 32);
        assert!(ThesisHasher::new(&scene, &spec(22, 14, 32)).is_err());
        assert!(ThesisHasher::new(&scene, &spec(6, 65, 32)).is_err());
        assert!(ThesisHasher::new(&scene, &spec(6, 14, 3)).is_err());
        assert!(ThesisHasher::new(&scene, &StageSpec::new("thesis")).is_err());
        assert_eq!(h.shadow_layout().order, FieldOrder::Interleaved);
        assert_eq!(h.bounce_layout().order, FieldOrder::Interleaved);
        let mut bad = s.clone();
        bad.params
            .insert("layout".into(), ParamValue::Str("zigzag".into()));
        assert!(ThesisHasher::new(&scene, &bad).is_err());
    }

    /// The two layouts hold the same cells: concatenated is `θ | φ` (and `x | y | z | θ | φ`),
    /// interleaved is the MSB-first interleaving of the same cells.
    #[test]
    fn layouts_hold_the_same_cells() {
        use crsh_core::quantize::{interleave, spherical_cells};
        let scene = test_scene(2);
        let concat = ThesisHasher::new(&scene, &spec(6, 14, 32)).unwrap();
        let inter = concat.clone().with_order(FieldOrder::Interleaved);
        let light = scene.lights[1].position;
        let (sl, bl) = (*concat.shadow_layout(), *concat.bounce_layout());
        for (i, d) in [
            Vec3::new(0.3, -0.2, 0.9),
            Vec3::new(-1.0, 0.1, -0.4),
            Vec3::X,
        ]
        .into_iter()
        .enumerate()
        {
            let r = ray(RayKind::Shadow, light, d, 1);
            let (t, p) = spherical_cells(d, sl.theta_bits, sl.phi_bits);
            let top = 1u64 << (sl.theta_bits + sl.phi_bits);
            assert_eq!(concat.key(&r).unwrap(), top | (t << sl.phi_bits) | p, "{i}");
            assert_eq!(
                inter.key(&r).unwrap(),
                top | interleave(&[(t, sl.theta_bits), (p, sl.phi_bits)]),
                "{i}"
            );
            let o = Vec3::new(0.1 * i as f32, -0.3, 0.2);
            let b = ray(RayKind::Reflection, o, d, u32::MAX);
            let [x, y, z] = bl.origin_cells(o);
            let (t, p) = spherical_cells(d, bl.theta_bits, bl.phi_bits);
            let (ob, db) = (bl.origin_bits, bl.theta_bits + bl.phi_bits);
            assert_eq!(
                concat.key(&b).unwrap(),
                (((((x << ob) | y) << ob) | z) << db) | (t << bl.phi_bits) | p
            );
            assert_eq!(
                inter.key(&b).unwrap(),
                (interleave(&[(x, ob), (y, ob), (z, ob)]) << db)
                    | interleave(&[(t, bl.theta_bits), (p, bl.phi_bits)])
            );
        }
    }

    /// Why `interleave` is the default: rays from one light through a regular fan of
    /// directions, sorted by key and cut into nodes of 8, give nodes whose directions spread
    /// far less than with `θ | φ` concatenated, which puts every node across all of `φ`.
    #[test]
    fn interleaved_shadow_keys_group_nearby_directions() {
        let scene = test_scene(1);
        let concat = ThesisHasher::new(&scene, &spec(6, 14, 32)).unwrap();
        let inter = concat.clone().with_order(FieldOrder::Interleaved);
        let light = scene.lights[0].position;
        let rays: Vec<Ray> = (0..64 * 64)
            .map(|i| {
                let (a, b) = ((i % 64) as f32 / 64.0, (i / 64) as f32 / 64.0);
                let d = Vec3::new(a - 0.5, b - 0.5, -1.0).normalize();
                ray(RayKind::Shadow, light, d, 0)
            })
            .collect();
        let spread = |h: &ThesisHasher| {
            let mut idx: Vec<usize> = (0..rays.len()).collect();
            idx.sort_by_key(|&i| (h.key(&rays[i]).unwrap(), i));
            idx.chunks(8)
                .map(|c| {
                    let d0 = rays[c[0]].dir;
                    c.iter()
                        .map(|&i| rays[i].dir.angle_between(d0))
                        .fold(0.0f32, f32::max)
                })
                .sum::<f32>()
                / (rays.len() / 8) as f32
        };
        let (si, sc) = (spread(&inter), spread(&concat));
        assert!(
            si * 4.0 < sc,
            "mean node spread: interleave {si}, concat {sc}"
        );
    }

    #[test]
    fn shadow_rays_use_light_and_direction_bounce_rays_use_origin() {
        let scene = test_scene(2);
        let h = ThesisHasher::new(&scene, &spec(6, 14, 32)).unwrap();
        let l1 = scene.lights[1].position;
        let d = Vec3::new(0.1, -1.0, 0.2).normalize();
        let s = ray(RayKind::Shadow, l1, d, 1);
        assert_eq!(h.key(&s).unwrap(), h.shadow_layout().key(1, d));
        assert_eq!(h.key(&s).unwrap() >> 31, 1, "light 1 in the top bit");
        // The surface convention hashes the same light→point direction.
        let p = l1 + d * 3.0;
        let s2 = ray(RayKind::Shadow, p, -d, 1);
        assert_eq!(h.key(&s2).unwrap(), h.key(&s).unwrap());
        let o = Vec3::new(0.2, 0.3, 0.4);
        for kind in [RayKind::Reflection, RayKind::Refraction, RayKind::Primary] {
            let r = ray(kind, o, d, u32::MAX);
            assert_eq!(h.key(&r).unwrap(), h.bounce_layout().key(o, d));
        }
        let bad_light = ray(RayKind::Shadow, l1, d, 2);
        assert!(h.key(&bad_light).is_err());
        let mut bad_kind = ray(RayKind::Reflection, o, d, 0);
        bad_kind.kind = 9;
        assert!(h.key(&bad_kind).is_err());
        let mut stats = Stats::default();
        assert!(h
            .hash(&Cpu, &vec![s, bad_kind], RayKind::Shadow, &mut stats)
            .is_err());
        // Each ray is keyed by its own kind, whatever the batch's.
        let reflection = ray(RayKind::Reflection, o, d, u32::MAX);
        assert_eq!(
            h.hash(&Cpu, &vec![s, reflection], RayKind::Shadow, &mut stats)
                .unwrap(),
            vec![h.key(&s).unwrap(), h.key(&reflection).unwrap()]
        );
    }

    /// The batched keys (passes of [`KEY_PASS`] rays, each layout's cells found together)
    /// are the layouts' keys of each ray alone, in a batch whose kinds alternate irregularly,
    /// with shadow rays of both origin conventions and bounce origins inside and outside the
    /// scene's bounds.
    #[test]
    fn batched_keys_are_the_layouts_keys() {
        let scene = test_scene(3);
        for (order, origin_bits, direction_bits) in [
            ("interleave", 6, 14),
            ("concat", 5, 30),
            ("interleave", 21, 1),
        ] {
            let mut s = spec(origin_bits, direction_bits, 32);
            s.params
                .insert("layout".into(), ParamValue::Str(order.into()));
            let h = ThesisHasher::new(&scene, &s).unwrap();
            let rays: Vec<Ray> = (0..1000u32)
                .map(|i| {
                    let a = i as f32 * 0.731;
                    let dir = Vec3::new(a.sin(), (a * 1.3).cos(), (a * 0.7).sin() - 0.2);
                    if (i * 7 + i / 5) % 3 != 0 {
                        let light = i % 3;
                        let l = scene.lights[light as usize].position;
                        if i % 2 == 0 {
                            ray(RayKind::Shadow, l, dir, light)
                        } else {
                            ray(RayKind::Shadow, l + dir * 3.0, -dir, light)
                        }
                    } else {
                        let o = Vec3::new(a.cos() * 3.0, (a * 0.2).sin(), (a * 0.1).cos() * 2.0);
                        ray(RayKind::Reflection, o, dir, u32::MAX)
                    }
                })
                .collect();
            let want: Vec<u64> = rays
                .iter()
                .map(|r| {
                    if r.kind == RayKind::Shadow as u32 {
                        let l = scene.lights[r.light as usize].position;
                        let d = light_to_point_direction(r, l).unwrap();
                        h.shadow_layout().key(r.light, d)
                    } else {
                        h.bounce_layout().key(r.origin, r.dir)
                    }
                })
                .collect();
            let got = h
                .hash(&Cpu, &rays, RayKind::Shadow, &mut Stats::default())
                .unwrap();
            assert_eq!(got, want, "{order} {origin_bits}/{direction_bits}");
        }
    }

    #[test]
    fn hash_is_deterministic_across_thread_counts() {
        let scene = test_scene(2);
        let h = ThesisHasher::new(&scene, &spec(6, 14, 32)).unwrap();
        let rays: Vec<Ray> = (0..5000)
            .map(|i| {
                let a = i as f32 * 0.37;
                let dir = Vec3::new(a.sin(), a.cos(), (a * 0.3).sin()).normalize();
                if i % 2 == 0 {
                    let light = (i / 2 % 2) as u32;
                    ray(
                        RayKind::Shadow,
                        scene.lights[light as usize].position,
                        dir,
                        light,
                    )
                } else {
                    let o = Vec3::new((a * 0.1).sin(), (a * 0.2).cos(), (a * 0.05).sin());
                    ray(RayKind::Reflection, o, dir, u32::MAX)
                }
            })
            .collect();
        for kind in [RayKind::Shadow, RayKind::Reflection] {
            let batch: Vec<Ray> = rays
                .iter()
                .filter(|r| r.kind == kind as u32)
                .copied()
                .collect();
            let one = with_threads(1, || h.hash(&Cpu, &batch, kind, &mut Stats::default()))
                .unwrap()
                .unwrap();
            let three = with_threads(3, || h.hash(&Cpu, &batch, kind, &mut Stats::default()))
                .unwrap()
                .unwrap();
            assert_eq!(one, three);
            assert_eq!(one.len(), batch.len());
            let serial: Vec<u64> = batch.iter().map(|r| h.key(r).unwrap()).collect();
            assert_eq!(one, serial);
            assert!(one.iter().all(|&k| k < 1 << 32));
        }
    }
}
