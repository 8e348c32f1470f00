//! RTTest's projected-barycentric ray-triangle test (`intersect.test=projected`): seed 003
//! §4.2, listing 4.5 (`render_poly`), after Wald's PhD thesis (2004, §7.1).
//!
//! # The data (listing 4.5)
//!
//! RTTest keeps no vertices for intersection, only precomputed parameters (42 bytes there):
//!
//! ```text
//! typedef struct { BYTE axis[2]; Vector normal; float d, Xx, Xy, Yx, Yy, p1x, p1y; } render_poly;
//! ```
//!
//! [`ProjectedTriangle`] holds the same: `axis` = the two axes `(i, j)` the triangle is
//! projected on (the normal's largest component `k` is dropped, `i = k + 1`, `j = k + 2`
//! mod 3, so the projection keeps the most area); `normal` = `n = e1 × e2` (`e1 = b − a`,
//! `e2 = c − a`) and `d = n · a`, the plane; `p1` = `a` projected; `(Xx, Xy; Yx, Yy)` = the
//! inverse of the projected edge matrix `(e1_i e2_i; e1_j e2_j)`, whose determinant is `n_k`,
//! the largest normal component, so it is never small for a non-degenerate triangle. We add
//! the determinant bound `det_eps` of the other tests (46 bytes in all).
//!
//! # The test
//!
//! ```text
//! t   = (d − n·o) / (n·dir)                         the plane
//! h   = (o_i + t·dir_i − p1x,  o_j + t·dir_j − p1y)  the hit point, projected, relative to a
//! u   = Xx·h.0 + Xy·h.1                             weight of b
//! v   = Yx·h.0 + Yy·h.1                             weight of c
//! ```
//!
//! with the hit inside when `u ≥ 0`, `v ≥ 0`, `u + v ≤ 1` and `t` in the open interval, and the
//! ray rejected as parallel when `|n·dir| ≤ det_eps·|dir|` (`det_eps = DET_REL_EPS·|e1|·|e2|`,
//! the same relative bound as Möller-Trumbore's, since `n·dir = −det` there).
//!
//! # Where it is weaker
//!
//! `t` comes from the plane distance `d − n·o`, a difference of two products of the size
//! `|n|·|a|` and `|n|·|o|`: far from the origin (a scene translated by 1e5) it cancels, and the
//! hit point the barycentrics are computed from inherits the error of `t` along the ray, so
//! rays near edges of far-away triangles are decided by rounding sooner than with
//! Möller-Trumbore, whose barycentrics use `o − a` directly. Shared edges are not watertight:
//! the two triangles of an edge compute their barycentrics with different matrices.

use crsh_core::glam::Vec3;
use crsh_core::Ray;

use super::{
    inside, is_degenerate, lane_block_test, lane_packet_test, BlockHits, LaneBlock, LanePacket,
    RayPre, TriangleTest, DET_REL_EPS, LANES,
};

/// The projected-barycentric test as a [`TriangleTest`].
#[derive(Clone, Copy, Debug, Default)]
pub struct Projected;

/// RTTest's `render_poly` (listing 4.5) plus the determinant bound.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ProjectedTriangle {
    /// The projection axes `(i, j)` (the normal's largest component is the third axis).
    pub axis: [u8; 2],
    /// `n = e1 × e2` (zero for a degenerate triangle, which then never hits).
    pub normal: [f32; 3],
    /// `n · a`.
    pub d: f32,
    /// First row of the inverse projected edge matrix (gives `u`).
    pub x: [f32; 2],
    /// Second row (gives `v`).
    pub y: [f32; 2],
    /// `a` projected on `(i, j)`.
    pub p1: [f32; 2],
    /// `DET_REL_EPS·|e1|·|e2|` (0 for a degenerate triangle).
    pub det_eps: f32,
}

impl ProjectedTriangle {
    /// Prepares triangle `a, b, c` (degenerate ones get a zero normal and never hit).
    pub fn new(a: Vec3, b: Vec3, c: Vec3) -> ProjectedTriangle {
        if is_degenerate(a, b, c) {
            return ProjectedTriangle {
                axis: [0, 1],
                normal: [0.0; 3],
                d: 0.0,
                x: [0.0; 2],
                y: [0.0; 2],
                p1: [0.0; 2],
                det_eps: 0.0,
            };
        }
        let (e1, e2) = (b - a, c - a);
        let n = e1.cross(e2);
        let na = n.abs();
        let k = if na.x >= na.y && na.x >= na.z {
            0
        } else if na.y >= na.z {
            1
        } else {
            2
        };
        let (i, j) = ((k + 1) % 3, (k + 2) % 3);
        // (e1_i e2_i; e1_j e2_j)⁻¹ with determinant e1_i·e2_j − e2_i·e1_j = n_k.
        let det = e1[i] * e2[j] - e2[i] * e1[j];
        let inv = 1.0 / det;
        ProjectedTriangle {
            axis: [i as u8, j as u8],
            normal: n.to_array(),
            d: n.dot(a),
            x: [e2[j] * inv, -e2[i] * inv],
            y: [-e1[j] * inv, e1[i] * inv],
            p1: [a[i], a[j]],
            det_eps: DET_REL_EPS * e1.length() * e2.length(),
        }
    }

    /// `(det_ok, t, u, v)`: the test without the barycentric and interval checks.
    #[inline(always)]
    fn solve(&self, r: &RayPre) -> (bool, f32, f32, f32) {
        let n = self.normal;
        let nd = n[0] * r.d[0] + n[1] * r.d[1] + n[2] * r.d[2];
        let no = n[0] * r.o[0] + n[1] * r.o[1] + n[2] * r.o[2];
        let t = (self.d - no) / nd;
        let (i, j) = (self.axis[0] as usize, self.axis[1] as usize);
        let hu = r.o[i] + t * r.d[i] - self.p1[0];
        let hv = r.o[j] + t * r.d[j] - self.p1[1];
        let u = self.x[0] * hu + self.x[1] * hv;
        let v = self.y[0] * hu + self.y[1] * hv;
        (nd.abs() > self.det_eps * r.d_len, t, u, v)
    }
}

impl TriangleTest for Projected {
    const KIND: super::TestKind = super::TestKind::Projected;
    type Tri = ProjectedTriangle;
    type Block = LaneBlock<ProjectedTriangle>;
    type Ray = RayPre;
    type Packet = LanePacket<RayPre>;

    fn prepare(a: Vec3, b: Vec3, c: Vec3) -> ProjectedTriangle {
        ProjectedTriangle::new(a, b, c)
    }

    #[inline(always)]
    fn is_degenerate(tri: &ProjectedTriangle) -> bool {
        tri.normal == [0.0; 3]
    }

    fn block(tris: &[ProjectedTriangle]) -> LaneBlock<ProjectedTriangle> {
        let mut block = LaneBlock {
            tris: [ProjectedTriangle::new(Vec3::ZERO, Vec3::ZERO, Vec3::ZERO); LANES],
        };
        for (slot, t) in block.tris.iter_mut().zip(tris) {
            *slot = *t;
        }
        block
    }

    #[inline(always)]
    fn ray(origin: Vec3, dir: Vec3) -> RayPre {
        RayPre::new(origin, dir)
    }

    #[inline(always)]
    fn intersect(
        tri: &ProjectedTriangle,
        r: &RayPre,
        t_min: f32,
        t_max: f32,
    ) -> Option<(f32, f32, f32)> {
        let (det_ok, t, u, v) = tri.solve(r);
        (det_ok & inside(u, v) & (t > t_min) & (t < t_max)).then_some((t, u, v))
    }

    #[inline(always)]
    fn test_block(
        block: &LaneBlock<ProjectedTriangle>,
        r: &RayPre,
        t_min: f32,
        t_max: f32,
    ) -> BlockHits {
        lane_block_test::<Projected>(&block.tris, r, t_min, t_max)
    }

    fn empty_packet() -> LanePacket<RayPre> {
        LanePacket {
            rays: [RayPre::new(Vec3::ZERO, Vec3::ZERO); LANES],
            t_min: [0.0; LANES],
            t_max: [f32::NEG_INFINITY; LANES],
        }
    }

    #[inline(always)]
    fn set_lane(packet: &mut LanePacket<RayPre>, lane: usize, ray: &Ray) {
        packet.rays[lane] = RayPre::of(ray);
        packet.t_min[lane] = ray.t_min;
        packet.t_max[lane] = ray.t_max;
    }

    #[inline(always)]
    fn test_packet(packet: &LanePacket<RayPre>, tri: &ProjectedTriangle) -> (u32, BlockHits) {
        lane_packet_test::<Projected>(packet, tri)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_dropped_axis_is_the_normals_largest() {
        let t = ProjectedTriangle::new(Vec3::ZERO, Vec3::Y, Vec3::Z);
        assert_eq!(t.axis, [1, 2], "normal along x");
        let t = ProjectedTriangle::new(Vec3::ZERO, Vec3::Z, Vec3::X);
        assert_eq!(t.axis, [2, 0], "normal along y");
        let t = ProjectedTriangle::new(Vec3::ZERO, Vec3::X, Vec3::Y);
        assert_eq!(t.axis, [0, 1], "normal along z");
        // Barycentrics are the same whichever axis is dropped.
        for (a, b, c) in [
            (Vec3::ZERO, Vec3::Y, Vec3::Z),
            (Vec3::ZERO, Vec3::Z, Vec3::X),
            (
                Vec3::new(0.1, 0.2, 0.3),
                Vec3::new(1.2, 0.4, 0.1),
                Vec3::new(0.2, 1.1, 0.9),
            ),
        ] {
            let p = a * 0.2 + b * 0.5 + c * 0.3;
            let o = p + a.cross(b).normalize_or_zero() * 0.5 + Vec3::new(0.3, 0.3, 0.3);
            let (_, u, v) = Projected::intersect(
                &Projected::prepare(a, b, c),
                &RayPre::new(o, p - o),
                0.0,
                9.0,
            )
            .unwrap();
            assert!((u - 0.5).abs() < 1e-5 && (v - 0.3).abs() < 1e-5, "{u} {v}");
        }
    }
}
