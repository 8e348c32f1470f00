//! The watertight ray-triangle test of Woop, Benthin and Wald, "Watertight Ray/Triangle
//! Intersection", JCGT 2(1), 2013 (`intersect.test=watertight`).
//!
//! # The test (the paper's §3 and its listing)
//!
//! Per ray, once ([`WatertightRay`]): `kz` is the axis where `|d|` is largest, `kx = kz + 1`,
//! `ky = kx + 1` (mod 3), swapped when `d[kz] < 0` to keep the winding; the shear constants are
//! `Sx = d[kx]/d[kz]`, `Sy = d[ky]/d[kz]`, `Sz = 1/d[kz]`. This maps the ray to the `+z` axis
//! through the origin of a sheared, translated space.
//!
//! Per triangle: the vertices relative to the ray origin, `A = a − o` (and `B`, `C`), sheared
//! to `Ax = A[kx] − Sx·A[kz]`, `Ay = A[ky] − Sy·A[kz]`; the 2D edge functions
//!
//! ```text
//! U = Cx·By − Cy·Bx      (edge B→C: the weight of a)
//! V = Ax·Cy − Ay·Cx      (edge C→A: the weight of b)
//! W = Bx·Ay − By·Ax      (edge A→B: the weight of c)
//! ```
//!
//! are recomputed in f64 when any of them is exactly 0 (the paper's fallback: f32 products of
//! f32 inputs are exact in f64, so the sign of an edge function on the edge is decided exactly).
//! The ray misses when the signs differ (`U, V, W` not all ≥ 0 and not all ≤ 0); otherwise
//! `det = U + V + W` (0: the ray lies in the plane: miss), `T = U·Az + V·Bz + W·Cz` with
//! `Az = Sz·A[kz]`, and `t = T / det`. Both faces hit; `Hit::u = V/det`, `Hit::v = W/det`.
//!
//! # Why it is watertight
//!
//! Two triangles sharing an edge compute that edge's function from the same two transformed
//! vertices with the same operations (the transform depends on the ray only), so the two values
//! are equal up to sign: a ray cannot pass between them. On the edge itself the value is 0 (in
//! f64, exactly), both triangles accept it, and the closest-hit tie rule picks one. So rays aimed
//! at shared edges and vertices of a closed mesh always hit (the tests shoot them from inside
//! meshes at several offsets; Möller-Trumbore and the projected test let some through).
//!
//! The triangle is stored as its three vertices ([`WatertightTriangle`], 36 bytes + flag): the
//! edge functions must see the very same vertex values in both triangles of an edge, which
//! `a + (b − a)` does not give back.
//!
//! # What it does not do
//!
//! No tolerance: a ray exactly in the plane (`det = 0`) misses, a ray at a grazing angle hits
//! wherever its edge functions agree (Möller-Trumbore's relative determinant bound rejects it).
//! The `t` computed from a nearly-zero `det` is as precise as the operands allow; the interval
//! test is exact on that `t`. Without the paper's conservative `t` the test
//! does not bound the rounding of `t` itself (see the paper's §4 for the extra care a ray-box
//! traversal needs; our BVH widens its distance interval, see [`crate::intersect::bvh`]).

use crsh_core::glam::Vec3;
use crsh_core::Ray;

use super::{
    lane_block_test, lane_packet_test, BlockHits, LaneBlock, LanePacket, TriangleTest, LANES,
};

/// The watertight test as a [`TriangleTest`].
#[derive(Clone, Copy, Debug, Default)]
pub struct Watertight;

/// A triangle for the watertight test: its vertices as given (degenerate ones collapsed to
/// their first vertex, which no ray can hit).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WatertightTriangle {
    /// The vertices `a`, `b`, `c`.
    pub v: [[f32; 3]; 3],
    /// Whether the triangle was degenerate when prepared.
    pub degenerate: bool,
}

/// The per-ray values of the watertight test: origin, the axis permutation and the shear.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WatertightRay {
    /// Origin.
    pub o: [f32; 3],
    /// `kx`, `ky`, `kz`.
    pub k: [usize; 3],
    /// `Sx`, `Sy`, `Sz`.
    pub s: [f32; 3],
}

impl WatertightRay {
    /// The values for a ray from `origin` along `dir`.
    #[inline(always)]
    pub fn new(origin: Vec3, dir: Vec3) -> WatertightRay {
        let d = dir.to_array();
        let a = dir.abs();
        // The largest |d| component (the first of equal ones); NaN directions end up with NaN
        // shears, and every comparison below then fails: a miss.
        let kz = if a.x >= a.y && a.x >= a.z {
            0
        } else if a.y >= a.z {
            1
        } else {
            2
        };
        let mut kx = (kz + 1) % 3;
        let mut ky = (kx + 1) % 3;
        if d[kz] < 0.0 {
            std::mem::swap(&mut kx, &mut ky);
        }
        WatertightRay {
            o: origin.to_array(),
            k: [kx, ky, kz],
            s: [d[kx] / d[kz], d[ky] / d[kz], 1.0 / d[kz]],
        }
    }
}

/// Whether `a, b, c` span exactly no area (in f64, where the cross product of f32 edges is
/// exact up to one rounding) or are not finite: the only triangles this test calls degenerate.
/// Needles and slivers thinner than [`super::DET_REL_EPS`] (which the other tests reject as
/// degenerate: their f32 normal is rounding noise) are real triangles here, because the edge
/// functions never form a normal.
pub fn zero_area(a: Vec3, b: Vec3, c: Vec3) -> bool {
    if !(a.is_finite() && b.is_finite() && c.is_finite()) {
        return true;
    }
    let (a, b, c) = (a.as_dvec3(), b.as_dvec3(), c.as_dvec3());
    (b - a).cross(c - a) == crsh_core::glam::DVec3::ZERO
}

/// The test itself: `(t, u, v)` when the edge-function signs agree and `det ≠ 0`, whatever
/// `t` (the interval is the caller's).
#[inline(always)]
fn solve(tri: &WatertightTriangle, r: &WatertightRay) -> Option<(f32, f32, f32)> {
    let [kx, ky, kz] = r.k;
    let [sx, sy, sz] = r.s;
    let rel = |p: &[f32; 3]| [p[0] - r.o[0], p[1] - r.o[1], p[2] - r.o[2]];
    let (a, b, c) = (rel(&tri.v[0]), rel(&tri.v[1]), rel(&tri.v[2]));
    let ax = a[kx] - sx * a[kz];
    let ay = a[ky] - sy * a[kz];
    let bx = b[kx] - sx * b[kz];
    let by = b[ky] - sy * b[kz];
    let cx = c[kx] - sx * c[kz];
    let cy = c[ky] - sy * c[kz];
    let mut u = cx * by - cy * bx;
    let mut v = ax * cy - ay * cx;
    let mut w = bx * ay - by * ax;
    if u == 0.0 || v == 0.0 || w == 0.0 {
        let (ax, ay, bx, by, cx, cy) = (
            ax as f64, ay as f64, bx as f64, by as f64, cx as f64, cy as f64,
        );
        u = (cx * by - cy * bx) as f32;
        v = (ax * cy - ay * cx) as f32;
        w = (bx * ay - by * ax) as f32;
    }
    let negative = (u < 0.0) | (v < 0.0) | (w < 0.0);
    let positive = (u > 0.0) | (v > 0.0) | (w > 0.0);
    if negative & positive {
        return None;
    }
    let det = u + v + w;
    // `!(det != 0)` also rejects NaN.
    if det == 0.0 || det.is_nan() {
        return None;
    }
    let t_scaled = u * (sz * a[kz]) + v * (sz * b[kz]) + w * (sz * c[kz]);
    let inv = 1.0 / det;
    Some((t_scaled * inv, v * inv, w * inv))
}

impl TriangleTest for Watertight {
    const KIND: super::TestKind = super::TestKind::Watertight;
    type Tri = WatertightTriangle;
    type Block = LaneBlock<WatertightTriangle>;
    type Ray = WatertightRay;
    type Packet = LanePacket<WatertightRay>;

    fn prepare(a: Vec3, b: Vec3, c: Vec3) -> WatertightTriangle {
        if zero_area(a, b, c) {
            let p = if a.is_finite() { a } else { Vec3::ZERO };
            return WatertightTriangle {
                v: [p.to_array(); 3],
                degenerate: true,
            };
        }
        WatertightTriangle {
            v: [a.to_array(), b.to_array(), c.to_array()],
            degenerate: false,
        }
    }

    #[inline(always)]
    fn is_degenerate(tri: &WatertightTriangle) -> bool {
        tri.degenerate
    }

    fn block(tris: &[WatertightTriangle]) -> LaneBlock<WatertightTriangle> {
        let mut block = LaneBlock {
            tris: [Watertight::prepare(Vec3::ZERO, Vec3::ZERO, Vec3::ZERO); LANES],
        };
        for (slot, t) in block.tris.iter_mut().zip(tris) {
            *slot = *t;
        }
        block
    }

    #[inline(always)]
    fn ray(origin: Vec3, dir: Vec3) -> WatertightRay {
        WatertightRay::new(origin, dir)
    }

    #[inline(always)]
    fn intersect(
        tri: &WatertightTriangle,
        r: &WatertightRay,
        t_min: f32,
        t_max: f32,
    ) -> Option<(f32, f32, f32)> {
        if tri.degenerate {
            return None;
        }
        solve(tri, r).filter(|&(t, _, _)| (t > t_min) & (t < t_max))
    }

    #[inline(always)]
    fn test_block(
        block: &LaneBlock<WatertightTriangle>,
        r: &WatertightRay,
        t_min: f32,
        t_max: f32,
    ) -> BlockHits {
        lane_block_test::<Watertight>(&block.tris, r, t_min, t_max)
    }

    fn empty_packet() -> LanePacket<WatertightRay> {
        LanePacket {
            rays: [WatertightRay::new(Vec3::ZERO, Vec3::Z); LANES],
            t_min: [0.0; LANES],
            t_max: [f32::NEG_INFINITY; LANES],
        }
    }

    #[inline(always)]
    fn set_lane(packet: &mut LanePacket<WatertightRay>, lane: usize, ray: &Ray) {
        packet.rays[lane] = WatertightRay::new(ray.origin, ray.dir);
        packet.t_min[lane] = ray.t_min;
        packet.t_max[lane] = ray.t_max;
    }

    #[inline(always)]
    fn test_packet(
        packet: &LanePacket<WatertightRay>,
        tri: &WatertightTriangle,
    ) -> (u32, BlockHits) {
        lane_packet_test::<Watertight>(packet, tri)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_f64_fallback_decides_rays_exactly_on_an_edge() {
        // Two triangles of a quad sharing the diagonal (0,0)-(1,1) at z = 0; rays straight down
        // through diagonal points have U, V or W exactly 0 and must hit (at least) one of them.
        let a = Watertight::prepare(Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0));
        let b = Watertight::prepare(Vec3::ZERO, Vec3::new(1.0, 1.0, 0.0), Vec3::Y);
        for i in 0..=64 {
            let s = i as f32 / 64.0;
            let r = Watertight::ray(Vec3::new(s, s, 2.0), -Vec3::Z);
            let ha = Watertight::intersect(&a, &r, 0.0, 9.0);
            let hb = Watertight::intersect(&b, &r, 0.0, 9.0);
            assert!(ha.is_some() && hb.is_some(), "{s}: {ha:?} {hb:?}");
        }
    }

    #[test]
    fn winding_is_kept_for_negative_major_axes() {
        // The same hit from all six major directions gives the same barycentrics.
        let tri = Watertight::prepare(
            Vec3::new(-1.0, -1.0, -1.0),
            Vec3::new(1.0, -0.5, 0.2),
            Vec3::new(0.1, 1.0, 0.6),
        );
        let p = Vec3::new(-1.0, -1.0, -1.0) * 0.5
            + Vec3::new(1.0, -0.5, 0.2) * 0.3
            + Vec3::new(0.1, 1.0, 0.6) * 0.2;
        for d in [Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z, -Vec3::Z] {
            let d = (d + Vec3::new(0.1, 0.2, 0.15)).normalize();
            let r = Watertight::ray(p - d * 3.0, d);
            let (t, u, v) = Watertight::intersect(&tri, &r, 0.0, 9.0).unwrap();
            assert!((t - 3.0).abs() < 1e-5, "{d}: t {t}");
            assert!(
                (u - 0.3).abs() < 1e-5 && (v - 0.2).abs() < 1e-5,
                "{d}: {u} {v}"
            );
        }
    }
}
