//! Möller-Trumbore on precomputed triangles (`intersect.test=mt`, the default), and the
//! rasterizer's visibility-buffer resolve.
//!
//! Every intersector of this crate (brute force, its candidate-pair mode, the CWBVH), when
//! configured with this test, and the rasterizer's visibility-buffer resolve call [`mt_lane`]
//! (or its one-triangle form [`mt_vec`], the same arithmetic) through [`PreparedTriangle`],
//! [`TriangleBlock`] or [`RayPacket`], with the per-ray values of [`RayPre`], so they compute
//! the same `t`, `u`, `v` with the same floating-point operations in the same order: their
//! hits are identical bit for bit, not merely close.
//!
//! # Data
//!
//! Per triangle `a, b, c` the test reads `v0 = a`, `e1 = b - a`, `e2 = c - a` and a
//! determinant scale `det_eps = DET_REL_EPS·|e1|·|e2|`, prepared once per scene
//! ([`super::TriangleSet::new`]): 40 bytes in [`PreparedTriangle`] (array of structures, for BVH
//! leaves and candidate pairs) and in [`TriangleBlock`]s of [`LANES`] triangles (structure of
//! arrays, for the brute-force loop, which the compiler vectorizes). The candidate tests turn
//! it around: one triangle against up to [`LANES`] rays of a hierarchy node held as a
//! [`RayPacket`] (structure of arrays of the rays).
//!
//! # Epsilon policy
//!
//! - **Determinant.** A ray is rejected when `|det| <= det_eps·|d|`, i.e. when
//!   `|sin φ·cos θ| <= DET_REL_EPS` for the angle `φ` between the edges and the angle `θ`
//!   between the ray and the normal. The bound is relative, so it does not depend on the
//!   scene's scale or on `|d|`; it is about 2.5 times the worst rounding error of `det`, so an
//!   accepted determinant always has the right sign (front / back face never flips) and
//!   rays parallel to the plane (`det` = 0) are rejected. Triangles whose edges are parallel
//!   within that bound (zero-area, collinear, repeated vertices; checked in f64 when they are
//!   prepared) get zero edges and can never pass it: **degenerate triangles never hit**.
//! - **Barycentrics** are tested inclusively, `u >= 0`, `v >= 0`, `u + v <= 1`, so a ray whose
//!   barycentrics come out exactly on an edge or a vertex hits (when both triangles of a
//!   shared edge hit, the closest-hit tie rule picks the one with the smaller `t`, then the
//!   lower id). Möller-Trumbore is not watertight, though: the two triangles of a shared edge
//!   round their edge functions differently, so a ray passing within rounding distance of the
//!   edge (relative error of order `ε·|o - v0| / (|e|·sin φ·|cos θ|)`) can slip between
//!   them. Rays that miss an edge by more than that always hit the triangle on their side
//!   (see the tests); the [`super::watertight`] test closes the gap at a cost.
//! - **Distance.** A hit counts only strictly inside the ray's open interval
//!   `t_min < t < t_max`. There is no `t` epsilon here: self-intersection is avoided by the ray
//!   generator's `t_min` (and origin offset).
//! - **Back faces** are hit like front faces (`det < 0`); culling is the caller's business.

use bytemuck::{Pod, Zeroable};
use crsh_core::glam::{Vec3, Vec3A};
use crsh_core::{Hit, Ray};

use super::{inside, is_degenerate, BlockHits, TriangleTest, DET_REL_EPS, LANES};

/// The Möller-Trumbore test as a [`TriangleTest`]: [`PreparedTriangle`]s, [`TriangleBlock`]s,
/// [`RayPre`] and [`RayPacket`].
#[derive(Clone, Copy, Debug, Default)]
pub struct MollerTrumbore;

impl TriangleTest for MollerTrumbore {
    const KIND: super::TestKind = super::TestKind::MollerTrumbore;
    type Tri = PreparedTriangle;
    type Block = TriangleBlock;
    type Ray = RayPre;
    type Packet = RayPacket;

    #[inline(always)]
    fn prepare(a: Vec3, b: Vec3, c: Vec3) -> PreparedTriangle {
        PreparedTriangle::new(a, b, c)
    }

    #[inline(always)]
    fn is_degenerate(tri: &PreparedTriangle) -> bool {
        tri.is_degenerate()
    }

    fn block(tris: &[PreparedTriangle]) -> TriangleBlock {
        TriangleBlock::from_triangles(tris)
    }

    #[inline(always)]
    fn ray(origin: Vec3, dir: Vec3) -> RayPre {
        RayPre::new(origin, dir)
    }

    #[inline(always)]
    fn intersect(
        tri: &PreparedTriangle,
        r: &RayPre,
        t_min: f32,
        t_max: f32,
    ) -> Option<(f32, f32, f32)> {
        tri.intersect(r, t_min, t_max)
    }

    #[inline(always)]
    fn test_block(block: &TriangleBlock, r: &RayPre, t_min: f32, t_max: f32) -> BlockHits {
        block.test(r, t_min, t_max)
    }

    #[inline(always)]
    fn empty_packet() -> RayPacket {
        RayPacket::EMPTY
    }

    #[inline(always)]
    fn set_lane(packet: &mut RayPacket, lane: usize, ray: &Ray) {
        packet.set(lane, ray);
    }

    #[inline(always)]
    fn test_packet(packet: &RayPacket, tri: &PreparedTriangle) -> (u32, BlockHits) {
        packet.test(tri)
    }
}

/// The per-ray values the test needs: origin, direction and `|d|` (computed once per ray, the
/// same way for every intersector).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RayPre {
    /// Origin.
    pub o: [f32; 3],
    /// Direction.
    pub d: [f32; 3],
    /// Length of `d`, scaling the determinant bound.
    pub d_len: f32,
}

impl RayPre {
    /// The values for a ray from `origin` along `dir`.
    #[inline(always)]
    pub fn new(origin: Vec3, dir: Vec3) -> RayPre {
        let d = [dir.x, dir.y, dir.z];
        RayPre {
            o: [origin.x, origin.y, origin.z],
            d,
            d_len: (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt(),
        }
    }

    /// The values for `ray`.
    #[inline(always)]
    pub fn of(ray: &Ray) -> RayPre {
        RayPre::new(ray.origin, ray.dir)
    }
}

/// The Möller-Trumbore solve on scalars: `(det_ok, t, u, v)` where `det_ok` means the
/// determinant test passed (the ray crosses the plane at a usable angle). The inclusive
/// barycentric test is [`inside`]; the `t` interval is the caller's.
///
/// Branch-free so that a loop over [`LANES`] triangles vectorizes; every caller in the crate
/// goes through this one function so results are identical across intersectors.
#[inline(always)]
pub fn mt_lane(
    v0: [f32; 3],
    e1: [f32; 3],
    e2: [f32; 3],
    det_eps: f32,
    r: &RayPre,
) -> (bool, f32, f32, f32) {
    let [dx, dy, dz] = r.d;
    // p = d × e2
    let px = dy * e2[2] - dz * e2[1];
    let py = dz * e2[0] - dx * e2[2];
    let pz = dx * e2[1] - dy * e2[0];
    let det = e1[0] * px + e1[1] * py + e1[2] * pz;
    let inv = 1.0 / det;
    // s = o - v0
    let sx = r.o[0] - v0[0];
    let sy = r.o[1] - v0[1];
    let sz = r.o[2] - v0[2];
    let u = (sx * px + sy * py + sz * pz) * inv;
    // q = s × e1
    let qx = sy * e1[2] - sz * e1[1];
    let qy = sz * e1[0] - sx * e1[2];
    let qz = sx * e1[1] - sy * e1[0];
    let v = (dx * qx + dy * qy + dz * qz) * inv;
    let t = (e2[0] * qx + e2[1] * qy + e2[2] * qz) * inv;
    (det.abs() > det_eps * r.d_len, t, u, v)
}

/// [`mt_lane`] for one triangle in glam's `Vec3A` (four-wide SSE on x86-64): the same
/// operations in the same order (each cross product component `a·b − c·d`, each dot product
/// `(x + y) + z`, no fused multiply-add), so the same `(det_ok, t, u, v)` bit for bit, in
/// about half the instructions. The single-ray tests ([`PreparedTriangle::intersect`]) use
/// it; the lane loops keep [`mt_lane`], which vectorizes across triangles instead.
#[inline(always)]
pub fn mt_vec(tri: &PreparedTriangle, r: &RayPre) -> (bool, f32, f32, f32) {
    let d = Vec3A::from_array(r.d);
    let e1 = Vec3A::from_array(tri.e1);
    let e2 = Vec3A::from_array(tri.e2);
    let p = d.cross(e2);
    let det = e1.dot(p);
    let inv = 1.0 / det;
    let s = Vec3A::from_array(r.o) - Vec3A::from_array(tri.v0);
    let u = s.dot(p) * inv;
    let q = s.cross(e1);
    let v = d.dot(q) * inv;
    let t = e2.dot(q) * inv;
    (det.abs() > tri.det_eps * r.d_len, t, u, v)
}

/// One triangle prepared for the test (40 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct PreparedTriangle {
    /// First vertex `a`.
    pub v0: [f32; 3],
    /// `b - a` (zero for a degenerate triangle).
    pub e1: [f32; 3],
    /// `c - a` (zero for a degenerate triangle).
    pub e2: [f32; 3],
    /// `DET_REL_EPS·|e1|·|e2|`.
    pub det_eps: f32,
}

impl PreparedTriangle {
    /// Prepares triangle `a, b, c`; degenerate ones (see [`is_degenerate`]) get zero edges so
    /// they never hit.
    pub fn new(a: Vec3, b: Vec3, c: Vec3) -> PreparedTriangle {
        if is_degenerate(a, b, c) {
            return PreparedTriangle {
                v0: a.to_array(),
                e1: [0.0; 3],
                e2: [0.0; 3],
                det_eps: 0.0,
            };
        }
        let e1 = b - a;
        let e2 = c - a;
        PreparedTriangle {
            v0: a.to_array(),
            e1: e1.to_array(),
            e2: e2.to_array(),
            det_eps: DET_REL_EPS * e1.length() * e2.length(),
        }
    }

    /// Whether this triangle was degenerate when prepared (it can never be hit).
    pub fn is_degenerate(&self) -> bool {
        self.e1 == [0.0; 3] && self.e2 == [0.0; 3]
    }

    /// Intersection with the ray's *plane* test only: `(t, u, v)` whenever the determinant
    /// test passes, whatever the barycentrics and `t` (the rasterizer's visibility-buffer
    /// resolve uses this for the triangle a pixel sees). Same arithmetic as [`Self::intersect`].
    #[inline(always)]
    pub fn plane_hit(&self, r: &RayPre) -> Option<(f32, f32, f32)> {
        let (det_ok, t, u, v) = mt_vec(self, r);
        (det_ok && t.is_finite() && u.is_finite() && v.is_finite()).then_some((t, u, v))
    }

    /// The hit of the ray `r` with this triangle inside the open interval `(t_min, t_max)`,
    /// as `(t, u, v)`.
    #[inline(always)]
    pub fn intersect(&self, r: &RayPre, t_min: f32, t_max: f32) -> Option<(f32, f32, f32)> {
        let (det_ok, t, u, v) = mt_vec(self, r);
        (det_ok & inside(u, v) & (t > t_min) & (t < t_max)).then_some((t, u, v))
    }

    /// [`Self::intersect`] as a [`Hit`] on triangle id `tri`.
    #[inline(always)]
    pub fn hit(&self, r: &RayPre, t_min: f32, t_max: f32, tri: u32) -> Option<Hit> {
        self.intersect(r, t_min, t_max)
            .map(|(t, u, v)| Hit { t, tri, u, v })
    }
}

/// [`LANES`] triangles in structure-of-arrays form (320 bytes) for the brute-force loop.
/// Padding lanes hold degenerate triangles, which never hit.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct TriangleBlock {
    /// `v0` x, y, z per lane.
    pub v0: [[f32; LANES]; 3],
    /// `e1` x, y, z per lane.
    pub e1: [[f32; LANES]; 3],
    /// `e2` x, y, z per lane.
    pub e2: [[f32; LANES]; 3],
    /// `det_eps` per lane.
    pub det_eps: [f32; LANES],
}

impl TriangleBlock {
    /// Packs up to [`LANES`] triangles (lane `l` = `tris[l]`); the other lanes are zero
    /// (degenerate, never hit).
    pub fn from_triangles(tris: &[PreparedTriangle]) -> TriangleBlock {
        let mut b = TriangleBlock::zeroed();
        for (l, t) in tris.iter().take(LANES).enumerate() {
            for k in 0..3 {
                b.v0[k][l] = t.v0[k];
                b.e1[k][l] = t.e1[k];
                b.e2[k][l] = t.e2[k];
            }
            b.det_eps[l] = t.det_eps;
        }
        b
    }

    /// Tests the ray against all lanes; a lane's `t` is finite exactly when
    /// [`PreparedTriangle::intersect`] would report a hit, with the same `t`, `u`, `v`.
    #[inline(always)]
    pub fn test(&self, r: &RayPre, t_min: f32, t_max: f32) -> BlockHits {
        let mut out = BlockHits {
            t: [f32::INFINITY; LANES],
            u: [0.0; LANES],
            v: [0.0; LANES],
        };
        for l in 0..LANES {
            let (det_ok, t, u, v) = mt_lane(
                [self.v0[0][l], self.v0[1][l], self.v0[2][l]],
                [self.e1[0][l], self.e1[1][l], self.e1[2][l]],
                [self.e2[0][l], self.e2[1][l], self.e2[2][l]],
                self.det_eps[l],
                r,
            );
            let hit = det_ok & inside(u, v) & (t > t_min) & (t < t_max);
            out.t[l] = if hit { t } else { f32::INFINITY };
            out.u[l] = u;
            out.v[l] = v;
        }
        out
    }
}

/// Up to [`LANES`] rays in structure-of-arrays form, for testing one triangle against several
/// rays at once (the candidate tests of [`crate::intersect::brute`]: a hierarchy node's rays
/// against each of its candidate triangles). Each lane holds the [`RayPre`] values of its ray,
/// so [`RayPacket::test`] computes, lane by lane, exactly what [`PreparedTriangle::intersect`]
/// computes for that ray, bit for bit. Unused lanes have a zero direction and an empty
/// interval: they never hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RayPacket {
    /// Origin x, y, z per lane.
    pub o: [[f32; LANES]; 3],
    /// Direction x, y, z per lane.
    pub d: [[f32; LANES]; 3],
    /// `|d|` per lane (as [`RayPre::d_len`]).
    pub d_len: [f32; LANES],
    /// `t_min` per lane.
    pub t_min: [f32; LANES],
    /// `t_max` per lane.
    pub t_max: [f32; LANES],
}

impl RayPacket {
    /// A packet with no rays (every lane unused).
    pub const EMPTY: RayPacket = RayPacket {
        o: [[0.0; LANES]; 3],
        d: [[0.0; LANES]; 3],
        d_len: [0.0; LANES],
        t_min: [0.0; LANES],
        t_max: [0.0; LANES],
    };

    /// Puts `ray` in lane `lane` (`< LANES`).
    #[inline(always)]
    pub fn set(&mut self, lane: usize, ray: &Ray) {
        let r = RayPre::of(ray);
        for k in 0..3 {
            self.o[k][lane] = r.o[k];
            self.d[k][lane] = r.d[k];
        }
        self.d_len[lane] = r.d_len;
        self.t_min[lane] = ray.t_min;
        self.t_max[lane] = ray.t_max;
    }

    /// Tests `tri` against every lane: the bit `l` of the returned mask is set exactly when
    /// [`PreparedTriangle::intersect`] reports a hit for lane `l`'s ray, and then the lane's
    /// `t`, `u`, `v` are the same values (elsewhere `t` is `+∞`).
    #[inline(always)]
    pub fn test(&self, tri: &PreparedTriangle) -> (u32, BlockHits) {
        let mut out = BlockHits {
            t: [f32::INFINITY; LANES],
            u: [0.0; LANES],
            v: [0.0; LANES],
        };
        let mut mask = 0u32;
        for l in 0..LANES {
            let r = RayPre {
                o: [self.o[0][l], self.o[1][l], self.o[2][l]],
                d: [self.d[0][l], self.d[1][l], self.d[2][l]],
                d_len: self.d_len[l],
            };
            let (det_ok, t, u, v) = mt_lane(tri.v0, tri.e1, tri.e2, tri.det_eps, &r);
            let hit = det_ok & inside(u, v) & (t > self.t_min[l]) & (t < self.t_max[l]);
            out.t[l] = if hit { t } else { f32::INFINITY };
            out.u[l] = u;
            out.v[l] = v;
            mask |= (hit as u32) << l;
        }
        (mask, out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::triangle::tests::TestRng;
    use crate::triangle::TriangleSet;

    fn tri() -> PreparedTriangle {
        PreparedTriangle::new(Vec3::ZERO, Vec3::X, Vec3::Y)
    }

    fn down_at(x: f32, y: f32) -> RayPre {
        RayPre::new(Vec3::new(x, y, 1.0), -Vec3::Z)
    }

    #[test]
    fn hit_and_miss_known_cases() {
        let t = tri();
        let (d, u, v) = t
            .intersect(&down_at(0.25, 0.5), 0.0, f32::INFINITY)
            .unwrap();
        assert_eq!((d, u, v), (1.0, 0.25, 0.5));
        assert!(t
            .intersect(&down_at(0.6, 0.6), 0.0, f32::INFINITY)
            .is_none());
        assert!(t
            .intersect(&down_at(-0.1, 0.5), 0.0, f32::INFINITY)
            .is_none());
        assert!(t
            .intersect(&down_at(0.5, -0.1), 0.0, f32::INFINITY)
            .is_none());
        // Pointing away.
        let away = RayPre::new(Vec3::new(0.25, 0.25, 1.0), Vec3::Z);
        assert!(t.intersect(&away, 0.0, f32::INFINITY).is_none());
        // Non-unit direction: t scales.
        let r = RayPre::new(Vec3::new(0.25, 0.25, 1.0), Vec3::new(0.0, 0.0, -2.0));
        assert_eq!(t.intersect(&r, 0.0, f32::INFINITY).unwrap().0, 0.5);
    }

    /// The one-triangle form computes what the lane form computes, bit for bit (NaN
    /// included), over scales from 1e-3 to 1e5, grazing and parallel rays, degenerate
    /// triangles and zero direction components.
    #[test]
    fn vector_form_is_the_lane_form() {
        let bits =
            |(ok, t, u, v): (bool, f32, f32, f32)| (ok, t.to_bits(), u.to_bits(), v.to_bits());
        let mut rng = TestRng(11);
        for i in 0..20_000 {
            let scale = 10f32.powi(i % 9 - 3);
            let a = rng.vec3(-1.0, 1.0) * scale;
            let (b, c) = match i % 7 {
                // Degenerate: repeated vertex, collinear.
                0 => (a, rng.vec3(-1.0, 1.0) * scale),
                1 => (a * 2.0, a * 3.0),
                _ => (rng.vec3(-1.0, 1.0) * scale, rng.vec3(-1.0, 1.0) * scale),
            };
            let tri = PreparedTriangle::new(a, b, c);
            let mut dir = rng.unit();
            match i % 5 {
                // A zero component, and a direction in the triangle's plane.
                0 => dir.x = 0.0,
                1 => dir = Vec3::from(tri.e1) - Vec3::from(tri.e2) * 0.5,
                _ => {}
            }
            let r = RayPre::new(rng.vec3(-2.0, 2.0) * scale, dir);
            let lane = mt_lane(tri.v0, tri.e1, tri.e2, tri.det_eps, &r);
            assert_eq!(bits(mt_vec(&tri, &r)), bits(lane), "{tri:?} {r:?}");
        }
    }

    #[test]
    fn interval_is_open() {
        let t = tri();
        let r = down_at(0.25, 0.25);
        assert!(t.intersect(&r, 0.0, 1.0).is_none(), "t == t_max excluded");
        assert!(t.intersect(&r, 1.0, 2.0).is_none(), "t == t_min excluded");
        assert!(t.intersect(&r, 0.999, 1.001).is_some());
        assert!(t.intersect(&r, 1.001, 5.0).is_none());
    }

    #[test]
    fn edges_and_vertices_are_inclusive() {
        let t = tri();
        for (x, y) in [
            (0.0, 0.0),
            (1.0, 0.0),
            (0.0, 1.0),
            (0.5, 0.0),
            (0.0, 0.5),
            (0.5, 0.5),
        ] {
            assert!(
                t.intersect(&down_at(x, y), 0.0, 10.0).is_some(),
                "({x}, {y})"
            );
        }
        // A shared edge between two triangles of a quad. Rays perpendicular to the quad
        // through the diagonal are computed exactly and hit both triangles.
        let a = PreparedTriangle::new(Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0));
        let b = PreparedTriangle::new(Vec3::ZERO, Vec3::new(1.0, 1.0, 0.0), Vec3::Y);
        let mut rng = TestRng(7);
        for _ in 0..1000 {
            let s = rng.f32();
            let r = down_at(s, s);
            assert!(
                a.intersect(&r, 0.0, 2.0).is_some() && b.intersect(&r, 0.0, 2.0).is_some(),
                "{s}"
            );
        }
        // Oblique rays aimed exactly at the diagonal: Möller-Trumbore is not watertight (the
        // two triangles round their edge functions differently), so such a ray can slip
        // through, but only when it passes within rounding distance of the edge.
        let mut slipped = 0;
        for _ in 0..2000 {
            let s = rng.f32();
            let target = Vec3::new(s, s, 0.0);
            let mut dir = rng.unit();
            if dir.z > 0.0 {
                dir = -dir;
            }
            let o = target - dir * 2.0;
            let r = RayPre::new(o, dir);
            if a.intersect(&r, 0.0, 4.0).is_none() && b.intersect(&r, 0.0, 4.0).is_none() {
                slipped += 1;
                // Where the ray really crosses z = 0 (f64) is on the diagonal up to rounding.
                let (o, d) = (o.as_dvec3(), dir.as_dvec3());
                let p = o + d * (-o.z / d.z);
                assert!((p.x - p.y).abs() < 1e-5, "slipped far from the edge: {p:?}");
            }
        }
        assert!(
            slipped < 600,
            "{slipped} of 2000 rays slipped through the shared edge"
        );
        // Rays that miss the edge by more than rounding hit the triangle on their side.
        for _ in 0..2000 {
            let s = rng.range(0.01, 0.99);
            let off = if rng.f32() < 0.5 { 1e-4 } else { -1e-4 };
            let target = Vec3::new(s + off, s - off, 0.0);
            let mut dir = rng.unit();
            if dir.z > -0.05 {
                dir = Vec3::new(dir.x, dir.y, -dir.z.abs() - 0.05).normalize();
            }
            let r = RayPre::new(target - dir * 2.0, dir);
            let (ha, hb) = (
                a.intersect(&r, 0.0, 4.0).is_some(),
                b.intersect(&r, 0.0, 4.0).is_some(),
            );
            assert_eq!((ha, hb), (off > 0.0, off < 0.0), "{target:?} {dir:?}");
        }
    }

    #[test]
    fn parallel_rays_miss() {
        let t = tri();
        // In the plane, through the triangle.
        let r = RayPre::new(Vec3::new(-1.0, 0.25, 0.0), Vec3::X);
        assert!(t.intersect(&r, 0.0, f32::INFINITY).is_none());
        assert!(t.plane_hit(&r).is_none());
        // Above the plane, parallel.
        let r = RayPre::new(Vec3::new(-1.0, 0.25, 0.5), Vec3::X);
        assert!(t.intersect(&r, 0.0, f32::INFINITY).is_none());
        // Grazing at an angle below the bound.
        let r = RayPre::new(Vec3::new(-1.0, 0.25, 1e-8), Vec3::new(1.0, 0.0, -1e-8));
        assert!(t.intersect(&r, 0.0, f32::INFINITY).is_none());
        // Grazing, but well above the bound: hit.
        let r = RayPre::new(Vec3::new(-1.0, 0.25, 1.25e-3), Vec3::new(1.0, 0.0, -1e-3));
        assert!(t.intersect(&r, 0.0, f32::INFINITY).is_some());
    }

    #[test]
    fn degenerate_triangles_never_hit() {
        let cases = [
            [Vec3::ZERO, Vec3::ZERO, Vec3::ZERO],
            [Vec3::ZERO, Vec3::X, Vec3::X],
            [Vec3::ZERO, Vec3::X, Vec3::X * 2.0],
            [
                Vec3::new(0.1, 0.2, 0.3),
                Vec3::new(0.4, 0.5, 0.6),
                Vec3::new(0.7, 0.8, 0.9),
            ],
            [Vec3::ZERO, Vec3::X, Vec3::new(0.5, 1e-9, 0.0)],
        ];
        let mut rng = TestRng(11);
        for c in cases {
            assert!(is_degenerate(c[0], c[1], c[2]), "{c:?}");
            let t = PreparedTriangle::new(c[0], c[1], c[2]);
            assert!(t.is_degenerate());
            let centre = (c[0] + c[1] + c[2]) / 3.0;
            for _ in 0..500 {
                let o = centre + rng.unit() * rng.range(0.1, 3.0);
                let r = RayPre::new(o, centre - o);
                assert!(t.intersect(&r, f32::NEG_INFINITY, f32::INFINITY).is_none());
                assert!(t.plane_hit(&r).is_none());
            }
        }
        let set = TriangleSet::<MollerTrumbore>::from_triangles(cases.iter().copied().chain([[
            Vec3::ZERO,
            Vec3::X,
            Vec3::Y,
        ]]));
        assert_eq!(set.degenerate_count(), 5);
        assert_eq!(set.len(), 6);
    }

    #[test]
    fn back_faces_are_reported() {
        let t = tri();
        let up = RayPre::new(Vec3::new(0.25, 0.25, -1.0), Vec3::Z);
        assert_eq!(t.intersect(&up, 0.0, 5.0).unwrap(), (1.0, 0.25, 0.25));
    }

    #[test]
    fn blocks_match_scalar_bit_for_bit() {
        let mut rng = TestRng(3);
        let tris: Vec<[Vec3; 3]> = (0..37)
            .map(|_| {
                let a = rng.vec3(-1.0, 1.0);
                [a, a + rng.vec3(-0.5, 0.5), a + rng.vec3(-0.5, 0.5)]
            })
            .collect();
        let set = TriangleSet::<MollerTrumbore>::from_triangles(tris.iter().copied());
        assert_eq!(set.blocks().len(), 5);
        let mut hits = 0;
        for i in 0..500 {
            // Aim at a point of a random triangle (slightly outside it sometimes).
            let [a, b, c] = tris[i % tris.len()];
            let (u, v) = (rng.range(-0.1, 1.0), rng.range(-0.1, 1.0));
            let o = rng.vec3(-2.0, 2.0);
            let r = RayPre::new(o, a + (b - a) * u * 0.6 + (c - a) * v * 0.6 - o);
            for (k, b) in set.blocks().iter().enumerate() {
                let bh = b.test(&r, 0.0, 100.0);
                for l in 0..LANES {
                    let id = k * LANES + l;
                    let scalar = set
                        .triangles()
                        .get(id)
                        .and_then(|t| t.intersect(&r, 0.0, 100.0));
                    match scalar {
                        Some((t, u, v)) => {
                            hits += 1;
                            assert_eq!(
                                (bh.t[l].to_bits(), bh.u[l].to_bits(), bh.v[l].to_bits()),
                                (t.to_bits(), u.to_bits(), v.to_bits())
                            );
                        }
                        None => assert_eq!(bh.t[l], f32::INFINITY),
                    }
                }
            }
        }
        assert!(hits > 100, "too few hits to be a test: {hits}");
    }

    #[test]
    fn packets_match_scalar_bit_for_bit() {
        let mut rng = TestRng(9);
        let tris: Vec<PreparedTriangle> = (0..40)
            .map(|i| {
                let a = rng.vec3(-1.0, 1.0);
                if i % 13 == 0 {
                    PreparedTriangle::new(a, a, a + Vec3::X)
                } else {
                    PreparedTriangle::new(a, a + rng.vec3(-0.6, 0.6), a + rng.vec3(-0.6, 0.6))
                }
            })
            .collect();
        let mut hits = 0;
        for round in 0..60 {
            // 1..=LANES rays aimed near the triangles, with finite and infinite intervals.
            let count = 1 + round % LANES;
            let rays: Vec<Ray> = (0..count)
                .map(|i| {
                    let o = rng.vec3(-2.0, 2.0);
                    let t = &tris[(round * 7 + i) % tris.len()];
                    let target = Vec3::from(t.v0)
                        + Vec3::from(t.e1) * rng.range(-0.1, 0.7)
                        + Vec3::from(t.e2) * rng.range(-0.1, 0.7);
                    let t_max = if i % 3 == 0 { 2.0 } else { f32::INFINITY };
                    crate::intersect::brute::tests::test_ray(o, target - o, 1e-4, t_max, i)
                })
                .collect();
            let mut packet = RayPacket::EMPTY;
            for (l, r) in rays.iter().enumerate() {
                packet.set(l, r);
            }
            for tri in &tris {
                let (mask, bh) = packet.test(tri);
                assert_eq!(mask >> count, 0, "an unused lane hit");
                for (l, ray) in rays.iter().enumerate() {
                    match tri.intersect(&RayPre::of(ray), ray.t_min, ray.t_max) {
                        Some((t, u, v)) => {
                            hits += 1;
                            assert_ne!(mask & (1 << l), 0);
                            assert_eq!(
                                (bh.t[l].to_bits(), bh.u[l].to_bits(), bh.v[l].to_bits()),
                                (t.to_bits(), u.to_bits(), v.to_bits())
                            );
                        }
                        None => {
                            assert_eq!(mask & (1 << l), 0);
                            assert_eq!(bh.t[l], f32::INFINITY);
                        }
                    }
                }
            }
        }
        assert!(hits > 100, "too few hits to be a test: {hits}");
    }

    #[test]
    fn plane_hit_agrees_with_intersect() {
        let t = PreparedTriangle::new(
            Vec3::new(0.0, 0.0, -2.0),
            Vec3::new(1.0, 0.0, -2.5),
            Vec3::new(0.0, 1.0, -1.5),
        );
        let mut rng = TestRng(5);
        for _ in 0..200 {
            let r = RayPre::new(
                Vec3::ZERO,
                Vec3::new(rng.range(-0.2, 0.8), rng.range(-0.2, 0.8), -2.0),
            );
            let p = t.plane_hit(&r).unwrap();
            if let Some(h) = t.intersect(&r, 0.0, f32::INFINITY) {
                assert_eq!(h, p);
            } else {
                assert!(p.1 < 0.0 || p.2 < 0.0 || p.1 + p.2 > 1.0);
            }
        }
    }
}
