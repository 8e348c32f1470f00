//! `bvh.exact = false`: obvhs's traversal as obvhs ships it, on the same tree.
//!
//! The loops of obvhs's `CwBvh::ray_traverse` (closest hit) and `ray_traverse_miss` (any
//! hit), with its node test (`CwBvhNode::intersect_ray`: entry distance clamped to `1e-4`,
//! the ray's `t_min` ignored, no rounding margin) and its triangle test
//! (`Triangle::intersect`, Möller-Trumbore as madmann91 writes it), on obvhs's own triangles
//! in leaf order. Only the ray's interval is crsh's: open, `(t_min, t_max)`, like every crsh
//! test (obvhs's test accepts `t = t_min`). The scene triangle id, `t`, `u` and `v` of the
//! hit are mapped to crsh's [`Hit`]. Nothing is counted (the tests are reported unknown, as
//! Embree's): this is the anchor users would call, not an instrument.
//!
//! What differs from the exact `bvh` (and brute force), each tested where it fails: a hit
//! closer than `1e-4`, or on a box the unmargined node test rounds away, is lost; a ray with
//! a `-0.0` direction component misses every box along that axis (obvhs's inverse is
//! `-1/ε` while its plane order takes the component as positive); obvhs's triangle test
//! rejects a barycentric of `-0.0` (edge hits crsh's test keeps) and can report a hit on a
//! triangle whose plane the ray runs parallel to (to `f32` precision); a tie in `t` goes to
//! the triangle reached first, not to the lower id; `t`, `u`, `v` are obvhs's arithmetic. The
//! ablation's hit agreement measures how often.

use crsh_core::glam::{UVec2, Vec3A};
use crsh_core::{Hit, HitMode, Ray};
use obvhs::cwbvh::node::CwBvhNode;
use obvhs::triangle::Triangle;

/// obvhs's form of `ray` with its far end at `t_max`.
#[inline(always)]
fn obvhs_ray(ray: &Ray, t_max: f32) -> obvhs::ray::Ray {
    obvhs::ray::Ray::new(
        Vec3A::from(ray.origin),
        Vec3A::from(ray.dir),
        ray.t_min,
        t_max,
    )
}

/// The `t` of obvhs's test of `tri` against `ray`, if it lies after `ray.tmin` (else
/// infinity: `traverse!` callers keep only `t < tmax`).
#[inline(always)]
fn hit_t(tri: &Triangle, ray: &obvhs::ray::Ray) -> f32 {
    let t = tri.intersect(ray);
    if t > ray.tmin {
        t
    } else {
        f32::INFINITY
    }
}

/// The barycentric weights of `tri`'s `v1` and `v2` where `ray` crosses its plane, in the
/// arithmetic of `Triangle::intersect` (its `u` and `v`).
#[inline]
fn weights(tri: &Triangle, ray: &obvhs::ray::Ray) -> (f32, f32) {
    let e1 = tri.v0 - tri.v1;
    let e2 = tri.v2 - tri.v0;
    let n = e1.cross(e2);
    let r = ray.direction.cross(tri.v0 - ray.origin);
    let inv_det = 1.0 / n.dot(ray.direction);
    (r.dot(e2) * inv_det, r.dot(e1) * inv_det)
}

/// Traces `ray` through `bvh` (primitive slot `s` is `tris[s]`, scene triangle `ids[s]`)
/// with obvhs's tests, merging into `best` like the exact trace (any hit: skipped when `best`
/// is a hit; closest: a hit replaces `best` when it is nearer).
#[inline]
pub(crate) fn trace(
    bvh: &obvhs::cwbvh::CwBvh,
    tris: &[Triangle],
    ids: &[u32],
    ray: &Ray,
    mode: HitMode,
    best: &mut Hit,
) {
    if bvh.nodes.is_empty() || crate::intersect::nothing_to_trace(ray, mode, best) {
        return;
    }
    let mut r = obvhs_ray(ray, ray.t_max.min(best.t));
    let mut state = bvh.new_traversal(r.direction);
    let mut node: &CwBvhNode;
    let mut found = None;
    'trace: {
        obvhs::traverse!(bvh, node, state, node.intersect_ray(&r, state.oct_inv4), {
            let slot = state.primitive_id as usize;
            let t = hit_t(&tris[slot], &r);
            if t < r.tmax {
                found = Some((slot, t));
                if mode == HitMode::Any {
                    break 'trace;
                }
                r.tmax = t;
            }
        });
    }
    if let Some((slot, t)) = found {
        let (u, v) = weights(&tris[slot], &r);
        *best = Hit {
            t,
            tri: ids[slot],
            u,
            v,
        };
    }
}
