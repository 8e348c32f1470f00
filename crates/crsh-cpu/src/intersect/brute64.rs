//! `brute64`: every ray against every triangle in double precision, the reference accuracy
//! figures are measured against.
//!
//! The `f32` intersectors ([`crate::triangle`]) all compute the same Möller-Trumbore test with
//! the same operations, so they agree with each other bit for bit, but they share its
//! rounding: a ray that passes within `f32` rounding distance of an edge can slip between two
//! triangles, a far-away or tiny triangle loses its shape, and the determinant bound rejects
//! slivers. `brute64` is the yardstick for those errors: the `f32` scene and rays are widened
//! exactly to `f64` and tested with Möller-Trumbore in `f64` (rounding `2⁻⁵³` instead of
//! `2⁻²⁴`), with no tolerance of its own:
//!
//! - a triangle is skipped only when its edge vectors are exactly parallel in `f64` (zero
//!   area: repeated or collinear vertices); the `f32` test also skips slivers within its
//!   relative determinant bound, which this reference still hits;
//! - a ray parallel to a triangle's plane (`det = 0` exactly) does not hit it;
//! - barycentrics are tested inclusively (`u ≥ 0`, `v ≥ 0`, `u + v ≤ 1`) and `t` strictly
//!   inside `(t_min, t_max)`, as in the `f32` test;
//! - closest hit: the smallest `t` in `f64`, then the lowest triangle id; any hit: the
//!   lowest-id triangle hit. The stored [`Hit`] rounds `t`, `u`, `v` to `f32`, and merging
//!   with earlier hits uses [`Hit::closer_than`] like every intersector.
//!
//! It is not exact arithmetic, so it can itself be wrong for rays within about `2⁻⁵³` of an
//! edge (relative to the coordinates), some nine orders of magnitude closer than the `f32`
//! tests' blind spot. It answers whole-scene queries only; a candidate query (a ray-space
//! hierarchy's final tests) is [`CoreError::Unsupported`](crsh_core::CoreError::Unsupported).
//!
//! Cost: `N × M` tests like [`crate::intersect::brute`], scalar and in `f64`, so several times
//! slower; parallel over rays with rayon, deterministic.

use std::sync::Arc;

use crsh_core::glam::DVec3;
use crsh_core::{
    Hit, HitMode, Intersector, Query, Ray, Registry, Result, StageKind, StageSpec,
    StageVariantInfo, Stats,
};
use crsh_scene::Scene;
use rayon::prelude::*;

use crate::backend::Cpu;
use crate::intersect::brute::check_batch;

/// One triangle widened to `f64`: `v0`, `e1 = v1 − v0`, `e2 = v2 − v0`.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Tri64 {
    v0: DVec3,
    e1: DVec3,
    e2: DVec3,
    /// `false` for zero-area triangles (exactly parallel edges in `f64`), never hit.
    live: bool,
}

impl Tri64 {
    fn new([a, b, c]: [crsh_core::glam::Vec3; 3]) -> Tri64 {
        let v0 = a.as_dvec3();
        let (e1, e2) = (b.as_dvec3() - v0, c.as_dvec3() - v0);
        let live = e1.cross(e2) != DVec3::ZERO && (v0 + e1 + e2).is_finite();
        Tri64 { v0, e1, e2, live }
    }

    /// Möller-Trumbore in `f64`: `(t, u, v)` when the ray hits inside `(t_min, t_max)`.
    #[inline]
    fn intersect(&self, o: DVec3, d: DVec3, t_min: f64, t_max: f64) -> Option<(f64, f64, f64)> {
        if !self.live {
            return None;
        }
        let p = d.cross(self.e2);
        let det = self.e1.dot(p);
        if det == 0.0 || !det.is_finite() {
            return None;
        }
        let inv = 1.0 / det;
        let s = o - self.v0;
        let u = s.dot(p) * inv;
        if !(0.0..=1.0).contains(&u) {
            return None;
        }
        let q = s.cross(self.e1);
        let v = d.dot(q) * inv;
        if v < 0.0 || u + v > 1.0 {
            return None;
        }
        let t = self.e2.dot(q) * inv;
        (t > t_min && t < t_max).then_some((t, u, v))
    }
}

/// The `f64` brute-force reference (variant `brute64`, no parameters).
#[derive(Clone, Debug)]
pub struct BruteForce64 {
    tris: Vec<Tri64>,
}

/// The catalogue entry of `brute64`.
pub fn info() -> StageVariantInfo {
    StageVariantInfo::new(
        StageKind::Intersect,
        "brute64",
        "every ray against every triangle in f64 (Möller-Trumbore, no tolerance): the \
         reference accuracy is measured against; whole-scene queries only",
    )
    .scene_only()
}

/// Registers `brute64` ([`info`], [`BruteForce64::new`]).
pub fn register(registry: &mut Registry<Cpu>) -> Result<()> {
    registry.add_intersector(info(), |ctx, spec| {
        Ok(Box::new(BruteForce64::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

impl BruteForce64 {
    /// Prepares the triangles of `scene`; `spec` has no parameters.
    pub fn new(scene: &Arc<Scene>, spec: &StageSpec) -> Result<BruteForce64> {
        let _ = spec;
        Ok(BruteForce64::from_scene(scene))
    }

    /// Prepares the triangles of `scene`.
    pub fn from_scene(scene: &Scene) -> BruteForce64 {
        BruteForce64 {
            tris: (0..scene.triangle_count())
                .map(|i| Tri64::new(scene.triangle(i)))
                .collect(),
        }
    }

    /// The hit of one ray against every triangle, starting from `stored`; returns it and the
    /// tests performed.
    fn trace(&self, ray: &Ray, stored: Hit, mode: HitMode) -> (Hit, u64) {
        if mode == HitMode::Any && stored.is_hit() {
            return (stored, 0);
        }
        let (o, d) = (ray.origin.as_dvec3(), ray.dir.as_dvec3());
        let (t_min, t_max) = (ray.t_min as f64, ray.t_max as f64);
        let mut best: Option<(f64, usize, f64, f64)> = None;
        let mut tests = 0u64;
        for (i, tri) in self.tris.iter().enumerate() {
            tests += 1;
            if let Some((t, u, v)) = tri.intersect(o, d, t_min, t_max) {
                // Ids ascend, so a strictly smaller `t` wins and ties keep the lower id.
                if best.is_none_or(|b| t < b.0) {
                    best = Some((t, i, u, v));
                }
                if mode == HitMode::Any {
                    break;
                }
            }
        }
        let Some((t, i, u, v)) = best else {
            return (stored, tests);
        };
        let hit = Hit {
            t: t as f32,
            tri: i as u32,
            u: u as f32,
            v: v as f32,
        };
        let keep_new = match mode {
            HitMode::Any | HitMode::EdgeWidth(_) => true,
            HitMode::Closest => hit.closer_than(&stored),
        };
        (if keep_new { hit } else { stored }, tests)
    }
}

impl Intersector<Cpu> for BruteForce64 {
    fn name(&self) -> &str {
        "brute64"
    }

    fn supports_candidates(&self) -> bool {
        false
    }

    fn intersect(
        &self,
        _backend: &Cpu,
        rays: &Vec<Ray>,
        query: Query<'_, Cpu>,
        mode: HitMode,
        hits: &mut Vec<Hit>,
        stats: &mut Stats,
    ) -> Result<()> {
        if mode.is_edge_width() {
            return Err(mode.unsupported("brute64"));
        }
        query.whole_scene_only("brute64")?;
        check_batch(rays, hits)?;
        let tests: u64 = rays
            .par_iter()
            .zip(hits.par_iter_mut())
            .map(|(ray, hit)| {
                let (h, n) = self.trace(ray, *hit, mode);
                *hit = h;
                n
            })
            .sum();
        stats.add_ray_triangle(tests);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::intersect::brute::tests::{random_rays, soup, test_ray};
    use crate::intersect::brute::BruteForce;
    use crate::surface::tests::raw_scene;
    use crate::with_threads;
    use crsh_core::glam::Vec3;

    fn run(i: &dyn Intersector<Cpu>, rays: &Vec<Ray>, mode: HitMode) -> Vec<Hit> {
        let mut hits = vec![Hit::MISS; rays.len()];
        i.intersect(
            &Cpu,
            rays,
            Query::Scene,
            mode,
            &mut hits,
            &mut Stats::default(),
        )
        .unwrap();
        hits
    }

    /// The `f64` reference and the `f32` test agree except where `f32` rounding decides:
    /// every ray on which they differ is explained by a hit within `1e-4` (barycentric) of
    /// an edge, a triangle the `f32` test treats as degenerate, a ray within `1e-5` of
    /// parallel to the triangle (the `f32` determinant bound rejects it), two hits at nearly
    /// the same `t`, or a hit right at `t_min` (rays leaving a surface).
    #[test]
    fn differs_from_f32_brute_force_only_where_rounding_decides() {
        use crate::triangle::is_degenerate;
        let scene = soup(41, 200);
        let b64 = BruteForce64::from_scene(&scene);
        let b32 = BruteForce::from_scene(&scene);
        let rays = random_rays(&scene, 42, 2000);
        // (t, u, v) of the ray's line through triangle `k`'s plane, in f64, no bounds.
        let line = |r: &Ray, k: u32| {
            let t = &b64.tris[k as usize];
            let (o, d) = (r.origin.as_dvec3(), r.dir.as_dvec3());
            let p = d.cross(t.e2);
            let det = t.e1.dot(p);
            let s = o - t.v0;
            let q = s.cross(t.e1);
            (t.e2.dot(q) / det, s.dot(p) / det, d.dot(q) / det)
        };
        let borderline = |r: &Ray, h: &Hit| {
            if !h.is_hit() {
                return false;
            }
            let tri = scene.triangle(h.tri as usize);
            let (t, u, v) = line(r, h.tri);
            let t64 = &b64.tris[h.tri as usize];
            let n = t64.e1.cross(t64.e2).normalize();
            let grazing = n.dot(r.dir.as_dvec3().normalize()).abs() < 1e-5;
            is_degenerate(tri[0], tri[1], tri[2])
                || grazing
                || u.min(v).min(1.0 - u - v).abs() < 1e-4
                || (t - r.t_min as f64).abs() < 1e-3 * t.abs().max(1.0)
        };
        for mode in [HitMode::Closest, HitMode::Any] {
            let (h64, h32) = (run(&b64, &rays, mode), run(&b32, &rays, mode));
            let mut differ = 0;
            for ((r, a), b) in rays.iter().zip(&h64).zip(&h32) {
                let same = a.is_hit() == b.is_hit()
                    && (mode == HitMode::Any || !a.is_hit() || a.tri == b.tri);
                if same {
                    if mode == HitMode::Closest && a.is_hit() {
                        assert!(
                            (a.t - b.t).abs() <= 1e-4 * a.t.abs().max(1.0),
                            "{a:?} {b:?}"
                        );
                    }
                    continue;
                }
                differ += 1;
                let tie =
                    a.is_hit() && b.is_hit() && (a.t - b.t).abs() <= 1e-5 * a.t.abs().max(1.0);
                let any_ok = mode == HitMode::Any && a.is_hit() && b.is_hit();
                assert!(
                    tie || any_ok || borderline(r, a) || borderline(r, b),
                    "{mode:?}: unexplained difference on {r:?}: f64 {a:?}, f32 {b:?}"
                );
            }
            assert!(
                differ * 10 <= rays.len(),
                "{mode:?}: {differ} of {} differ",
                rays.len()
            );
        }
    }

    /// Rays aimed at the shared diagonal of a quad 10⁴ units from the origin all hit one of
    /// its two triangles in `f64`; `f32` Möller-Trumbore may let some through.
    #[test]
    fn shared_edges_far_from_the_origin_do_not_leak() {
        let off = Vec3::splat(1.0e4);
        let p = [
            off,
            off + Vec3::new(1.0, 0.0, 0.0),
            off + Vec3::new(1.0, 1.0, 0.0),
            off + Vec3::new(0.0, 1.0, 0.0),
        ];
        let scene = raw_scene(p.to_vec(), vec![Vec3::Z; 4], vec![[0, 1, 2], [0, 2, 3]]);
        let b64 = BruteForce64::from_scene(&scene);
        let rays: Vec<Ray> = (0..4000)
            .map(|i| {
                let s = (i as f32 + 0.5) / 4000.0;
                let target = off + Vec3::new(s, s, 0.0);
                let origin = target + Vec3::new(0.3 * (i % 7) as f32 - 0.9, 0.17, 3.0);
                test_ray(origin, target - origin, 0.0, f32::INFINITY, i)
            })
            .collect();
        let h = with_threads(3, || run(&b64, &rays, HitMode::Closest)).unwrap();
        let escapes = h.iter().filter(|h| !h.is_hit()).count();
        assert_eq!(
            escapes, 0,
            "{escapes} rays slipped through the diagonal in f64"
        );
        assert_eq!(
            h,
            with_threads(1, || run(&b64, &rays, HitMode::Closest)).unwrap()
        );
    }

    /// Slivers the `f32` determinant bound rejects are still hit; zero-area triangles never.
    #[test]
    fn slivers_hit_and_zero_area_triangles_do_not() {
        let p = vec![
            Vec3::new(-1.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 1e-7, 0.0),
            Vec3::new(2.0, 0.0, 0.0),
        ];
        // A sliver 1e-7 high and a degenerate (collinear) triangle.
        let scene = raw_scene(p, vec![Vec3::Z; 4], vec![[0, 1, 2], [0, 1, 3]]);
        let b64 = BruteForce64::from_scene(&scene);
        let b32 = BruteForce::from_scene(&scene);
        let down = test_ray(
            Vec3::new(0.0, 2e-8, 1.0),
            Vec3::NEG_Z,
            0.0,
            f32::INFINITY,
            0,
        );
        let rays = vec![down];
        let h64 = run(&b64, &rays, HitMode::Closest);
        assert_eq!(h64[0].tri, 0, "{h64:?}");
        assert!((h64[0].t - 1.0).abs() < 1e-6);
        assert!(!run(&b32, &rays, HitMode::Closest)[0].is_hit());
        let along = test_ray(Vec3::new(-3.0, 0.0, 0.0), Vec3::X, 0.0, f32::INFINITY, 1);
        assert!(!run(&b64, &vec![along], HitMode::Closest)[0].is_hit());
    }

    #[test]
    fn candidate_queries_and_bad_rays_are_errors() {
        let scene = soup(3, 10);
        let b64 = BruteForce64::from_scene(&scene);
        let mut rays = random_rays(&scene, 4, 4);
        rays[2].dir = Vec3::NAN;
        let mut hits = vec![Hit::MISS; 4];
        let r = b64.intersect(
            &Cpu,
            &rays,
            Query::Scene,
            HitMode::Closest,
            &mut hits,
            &mut Stats::default(),
        );
        assert!(
            matches!(r, Err(crsh_core::CoreError::InvalidInput(_))),
            "{r:?}"
        );
        crate::intersect::bvh::tests::rejects_candidates_and_bad_rays(&b64, &scene);
    }
}
