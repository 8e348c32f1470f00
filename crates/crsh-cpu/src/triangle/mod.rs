//! The CPU backend's exact ray-triangle tests, one module per test, selectable per intersector
//! (`--set intersect.test=mt|watertight|projected`, on the `brute` and `bvh` intersectors, so on
//! every exact pipeline: `crsh` and `rah` run their final tests with `brute`'s candidate mode):
//!
//! - [`moller_trumbore`] (`mt`, the default): Möller-Trumbore on precomputed edges, with a
//!   relative determinant bound; structure-of-arrays blocks and packets that vectorize.
//! - [`watertight`] (`watertight`): Woop, Benthin and Wald, "Watertight Ray/Triangle
//!   Intersection", JCGT 2(1), 2013: a per-ray shear and permutation make the edge functions
//!   of a shared edge the same computation in both triangles, so no ray slips between them.
//! - [`projected`] (`projected`): RTTest's projected-barycentric test (seed 003 §4.2, listing
//!   4.5 `render_poly`, after Wald's 2004 thesis): the plane distance gives `t`, the hit point is
//!   projected on the two axes the normal is smallest along, and a precomputed 2×2 inverse gives
//!   the barycentrics.
//!
//! # What every test shares
//!
//! The rules below are the same for the three tests, so that their results differ only where
//! their arithmetic does (rounding near edges, far from the origin, at grazing angles):
//!
//! - **Interval.** A hit counts only strictly inside the ray's open interval `t_min < t < t_max`;
//!   there is no `t` epsilon (self-intersection is the ray generator's business).
//! - **Barycentrics** are inclusive (`u >= 0`, `v >= 0`, `u + v <= 1`, or the watertight test's
//!   signs), and [`Hit::u`](crsh_core::Hit) / [`Hit::v`](crsh_core::Hit) are the weights of
//!   the triangle's second and third vertex whichever test computed them.
//! - **Degenerate triangles** never hit. For Möller-Trumbore and the projected test these are
//!   [`is_degenerate`]'s (zero area, collinear or repeated vertices, non-finite ones, and
//!   needles whose angle at the first vertex has a sine below [`DET_REL_EPS`]: their f32 normal
//!   is rounding noise), decided in f64 once per scene; the watertight test, which never forms
//!   a normal, only drops triangles of exactly zero area ([`watertight::zero_area`]) and hits
//!   such needles.
//! - **Back faces** are hit like front faces.
//! - **Near-parallel rays.** Möller-Trumbore and the projected test reject a ray when the sine
//!   of its angle to the plane is at most [`DET_REL_EPS`] (relative, so independent of scale);
//!   the watertight test rejects only an exactly zero determinant (its point: no tolerance).
//!
//! # How intersectors use them
//!
//! A test is a type implementing [`TriangleTest`]: the per-triangle data it prepares once per
//! scene, [`LANES`] of them in a block for the brute-force loop, the per-ray data it computes
//! once per ray, and [`LANES`] rays in a packet for the candidate tests (one triangle against a
//! hierarchy node's rays). Intersectors are generic over the test and pick it once per query
//! ([`AnyTriangleSet`]), never per triangle. Within one test, every path (scalar, block,
//! packet) computes the same floating-point operations in the same order, so brute force (scene
//! or candidates) and the BVH return identical hits, bit for bit.
//!
//! The rasterizer's visibility-buffer resolve always uses Möller-Trumbore
//! ([`PreparedTriangle::plane_hit`]): primary visibility is not an intersector.

pub mod moller_trumbore;
pub mod projected;
pub mod watertight;

use std::fmt::Debug;

use crsh_core::glam::{DVec3, Vec3};
use crsh_core::{Hit, Ray};
use crsh_scene::Scene;

pub use moller_trumbore::{
    mt_lane, MollerTrumbore, PreparedTriangle, RayPacket, RayPre, TriangleBlock,
};
pub use projected::{Projected, ProjectedTriangle};
pub use watertight::{Watertight, WatertightRay, WatertightTriangle};

/// Relative bound on the sine of the angle between a ray and a triangle's plane (and between
/// the triangle's edges, for [`is_degenerate`]): Möller-Trumbore and the projected test reject
/// rays at or below it.
pub const DET_REL_EPS: f32 = 1e-6;

/// Triangles per block and rays per packet.
pub const LANES: usize = 8;

/// Which ray-triangle test (the `intersect.test` parameter).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum TestKind {
    /// Möller-Trumbore, f32 ([`moller_trumbore`]).
    #[default]
    MollerTrumbore,
    /// Woop, Benthin and Wald's watertight test ([`watertight`]).
    Watertight,
    /// RTTest's projected-barycentric test ([`projected`]).
    Projected,
}

impl TestKind {
    /// Every test, in the order `crsh pipelines` lists them.
    pub const ALL: [TestKind; 3] = [
        TestKind::MollerTrumbore,
        TestKind::Watertight,
        TestKind::Projected,
    ];

    /// The parameter value naming this test.
    pub fn name(self) -> &'static str {
        match self {
            TestKind::MollerTrumbore => "mt",
            TestKind::Watertight => "watertight",
            TestKind::Projected => "projected",
        }
    }

    /// The test called `name`, if any.
    pub fn from_name(name: &str) -> Option<TestKind> {
        TestKind::ALL.into_iter().find(|k| k.name() == name)
    }
}

/// The names of [`TestKind::ALL`], for the catalogue's parameter choices.
pub const TEST_NAMES: &[&str] = &["mt", "watertight", "projected"];

/// Per-lane results of a block or packet test: `t` (`+∞` where the lane missed), `u`, `v`.
#[derive(Clone, Copy, Debug)]
pub struct BlockHits {
    /// Hit distance per lane; `f32::INFINITY` where the lane did not hit inside the interval.
    pub t: [f32; LANES],
    /// `u` (weight of the second vertex) per lane.
    pub u: [f32; LANES],
    /// `v` (weight of the third vertex) per lane.
    pub v: [f32; LANES],
}

impl BlockHits {
    /// No lane hit.
    pub const NONE: BlockHits = BlockHits {
        t: [f32::INFINITY; LANES],
        u: [0.0; LANES],
        v: [0.0; LANES],
    };
}

/// The inclusive barycentric test `u >= 0, v >= 0, u + v <= 1` (false for NaN).
#[inline(always)]
pub fn inside(u: f32, v: f32) -> bool {
    (u >= 0.0) & (v >= 0.0) & (u + v <= 1.0)
}

/// Whether `a, b, c` span (numerically) no area: `|e1 × e2| <= DET_REL_EPS·|e1|·|e2|` in f64,
/// which includes repeated vertices and collinear ones. Such triangles are never hit, by any
/// test.
pub fn is_degenerate(a: Vec3, b: Vec3, c: Vec3) -> bool {
    let (a, b, c): (DVec3, DVec3, DVec3) = (a.as_dvec3(), b.as_dvec3(), c.as_dvec3());
    let (e1, e2) = (b - a, c - a);
    let cross = e1.cross(e2).length();
    let bound = DET_REL_EPS as f64 * e1.length() * e2.length();
    // NaN (non-finite input) counts as degenerate too.
    cross.partial_cmp(&bound) != Some(std::cmp::Ordering::Greater)
}

/// One exact ray-triangle test: its prepared data and its scalar, block and packet forms.
///
/// Implementations guarantee that [`TriangleTest::test_block`] and
/// [`TriangleTest::test_packet`] report, lane by lane, exactly what [`TriangleTest::intersect`]
/// reports (same `t`, `u`, `v` bits), and follow the shared rules of the module doc.
pub trait TriangleTest: Copy + Default + Debug + Send + Sync + 'static {
    /// Which test this is.
    const KIND: TestKind;
    /// One triangle, prepared once per scene.
    type Tri: Copy + Debug + PartialEq + Send + Sync;
    /// [`LANES`] triangles for the brute-force loop (padding lanes never hit).
    type Block: Copy + Debug + Send + Sync;
    /// What the test computes once per ray.
    type Ray: Copy + Debug + Send + Sync;
    /// Up to [`LANES`] rays (with their intervals) against one triangle; unused lanes never hit.
    type Packet: Copy + Debug + Send + Sync;

    /// Prepares triangle `a, b, c` (a degenerate one gets data that never hits).
    fn prepare(a: Vec3, b: Vec3, c: Vec3) -> Self::Tri;
    /// Whether the triangle was degenerate when prepared.
    fn is_degenerate(tri: &Self::Tri) -> bool;
    /// Packs up to [`LANES`] triangles into a block, padding with degenerate lanes.
    fn block(tris: &[Self::Tri]) -> Self::Block;
    /// The per-ray data of a ray from `origin` along `dir`.
    fn ray(origin: Vec3, dir: Vec3) -> Self::Ray;
    /// The hit of the ray with the triangle inside the open interval `(t_min, t_max)`, as
    /// `(t, u, v)`.
    fn intersect(tri: &Self::Tri, r: &Self::Ray, t_min: f32, t_max: f32)
        -> Option<(f32, f32, f32)>;
    /// One ray against every lane of a block.
    fn test_block(block: &Self::Block, r: &Self::Ray, t_min: f32, t_max: f32) -> BlockHits;
    /// A packet with no rays.
    fn empty_packet() -> Self::Packet;
    /// Puts `ray` (with its interval) in lane `lane` (`< LANES`).
    fn set_lane(packet: &mut Self::Packet, lane: usize, ray: &Ray);
    /// One triangle against every lane of a packet: bit `l` of the mask is set exactly when
    /// [`TriangleTest::intersect`] hits lane `l`'s ray, with the same `t`, `u`, `v`.
    fn test_packet(packet: &Self::Packet, tri: &Self::Tri) -> (u32, BlockHits);

    /// The per-ray data of `ray`.
    #[inline(always)]
    fn ray_of(ray: &Ray) -> Self::Ray {
        Self::ray(ray.origin, ray.dir)
    }

    /// [`TriangleTest::intersect`] as a [`Hit`] on triangle id `tri`.
    #[inline(always)]
    fn hit(t: &Self::Tri, r: &Self::Ray, t_min: f32, t_max: f32, tri: u32) -> Option<Hit> {
        Self::intersect(t, r, t_min, t_max).map(|(t, u, v)| Hit { t, tri, u, v })
    }
}

/// A block of [`LANES`] triangles stored as they are (array of structures): the block form of
/// the tests that have no structure-of-arrays layout of their own.
#[derive(Clone, Copy, Debug)]
pub struct LaneBlock<T: Copy> {
    /// The triangles; padding lanes are degenerate.
    pub tris: [T; LANES],
}

/// Up to [`LANES`] rays as per-ray data plus intervals: the packet form of the tests that have
/// no structure-of-arrays layout of their own. Unused lanes have an empty interval.
#[derive(Clone, Copy, Debug)]
pub struct LanePacket<R: Copy> {
    /// Per-ray data per lane.
    pub rays: [R; LANES],
    /// `t_min` per lane.
    pub t_min: [f32; LANES],
    /// `t_max` per lane (`-∞` in unused lanes, so nothing is inside their interval).
    pub t_max: [f32; LANES],
}

/// [`TriangleTest::test_block`] for a [`LaneBlock`]: the scalar test lane by lane.
#[inline(always)]
pub(crate) fn lane_block_test<T: TriangleTest>(
    tris: &[T::Tri; LANES],
    r: &T::Ray,
    t_min: f32,
    t_max: f32,
) -> BlockHits {
    let mut out = BlockHits::NONE;
    for (l, tri) in tris.iter().enumerate() {
        if let Some((t, u, v)) = T::intersect(tri, r, t_min, t_max) {
            out.t[l] = t;
            out.u[l] = u;
            out.v[l] = v;
        }
    }
    out
}

/// [`TriangleTest::test_packet`] for a [`LanePacket`]: the scalar test lane by lane.
#[inline(always)]
pub(crate) fn lane_packet_test<T: TriangleTest>(
    p: &LanePacket<T::Ray>,
    tri: &T::Tri,
) -> (u32, BlockHits) {
    let mut out = BlockHits::NONE;
    let mut mask = 0u32;
    for l in 0..LANES {
        if let Some((t, u, v)) = T::intersect(tri, &p.rays[l], p.t_min[l], p.t_max[l]) {
            out.t[l] = t;
            out.u[l] = u;
            out.v[l] = v;
            mask |= 1 << l;
        }
    }
    (mask, out)
}

/// A scene's triangles prepared once for test `T`: in scene order and in blocks of [`LANES`]
/// (block `k` lane `l` is triangle `k·LANES + l`).
#[derive(Clone, Debug, Default)]
pub struct TriangleSet<T: TriangleTest = MollerTrumbore> {
    tris: Vec<T::Tri>,
    blocks: Vec<T::Block>,
    degenerate: usize,
}

impl<T: TriangleTest> TriangleSet<T> {
    /// Prepares every triangle of `scene`.
    pub fn new(scene: &Scene) -> TriangleSet<T> {
        TriangleSet::from_triangles((0..scene.triangle_count()).map(|t| scene.triangle(t)))
    }

    /// Prepares the given triangles (ids are their positions in the iterator).
    pub fn from_triangles(tris: impl IntoIterator<Item = [Vec3; 3]>) -> TriangleSet<T> {
        let tris: Vec<T::Tri> = tris
            .into_iter()
            .map(|[a, b, c]| T::prepare(a, b, c))
            .collect();
        let degenerate = tris.iter().filter(|t| T::is_degenerate(t)).count();
        let blocks = tris.chunks(LANES).map(T::block).collect();
        TriangleSet {
            tris,
            blocks,
            degenerate,
        }
    }

    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.tris.len()
    }

    /// Whether there are no triangles.
    pub fn is_empty(&self) -> bool {
        self.tris.is_empty()
    }

    /// Number of degenerate triangles (never hit).
    pub fn degenerate_count(&self) -> usize {
        self.degenerate
    }

    /// The prepared triangles in scene order.
    pub fn triangles(&self) -> &[T::Tri] {
        &self.tris
    }

    /// The triangles in blocks of [`LANES`] (the last one padded with degenerate lanes).
    pub fn blocks(&self) -> &[T::Block] {
        &self.blocks
    }
}

/// A scene's triangles prepared for the test an intersector was configured with: matched once
/// per query, so the loops inside are monomorphic.
#[derive(Clone, Debug)]
pub enum AnyTriangleSet {
    /// Möller-Trumbore.
    MollerTrumbore(TriangleSet<MollerTrumbore>),
    /// Watertight.
    Watertight(TriangleSet<Watertight>),
    /// Projected barycentrics.
    Projected(TriangleSet<Projected>),
}

impl AnyTriangleSet {
    /// Prepares every triangle of `scene` for test `kind`.
    pub fn new(scene: &Scene, kind: TestKind) -> AnyTriangleSet {
        match kind {
            TestKind::MollerTrumbore => AnyTriangleSet::MollerTrumbore(TriangleSet::new(scene)),
            TestKind::Watertight => AnyTriangleSet::Watertight(TriangleSet::new(scene)),
            TestKind::Projected => AnyTriangleSet::Projected(TriangleSet::new(scene)),
        }
    }

    /// The test the triangles were prepared for.
    pub fn kind(&self) -> TestKind {
        match self {
            AnyTriangleSet::MollerTrumbore(_) => TestKind::MollerTrumbore,
            AnyTriangleSet::Watertight(_) => TestKind::Watertight,
            AnyTriangleSet::Projected(_) => TestKind::Projected,
        }
    }

    /// Number of triangles.
    pub fn len(&self) -> usize {
        match self {
            AnyTriangleSet::MollerTrumbore(s) => s.len(),
            AnyTriangleSet::Watertight(s) => s.len(),
            AnyTriangleSet::Projected(s) => s.len(),
        }
    }

    /// Whether there are no triangles.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Number of degenerate triangles (never hit).
    pub fn degenerate_count(&self) -> usize {
        match self {
            AnyTriangleSet::MollerTrumbore(s) => s.degenerate_count(),
            AnyTriangleSet::Watertight(s) => s.degenerate_count(),
            AnyTriangleSet::Projected(s) => s.degenerate_count(),
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A small deterministic generator for tests (xorshift64*).
    pub(crate) struct TestRng(pub u64);

    impl TestRng {
        pub(crate) fn next_u64(&mut self) -> u64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
        }
        /// Uniform in `[0, 1)`.
        pub(crate) fn f32(&mut self) -> f32 {
            (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
        }
        pub(crate) fn range(&mut self, lo: f32, hi: f32) -> f32 {
            lo + (hi - lo) * self.f32()
        }
        pub(crate) fn vec3(&mut self, lo: f32, hi: f32) -> Vec3 {
            Vec3::new(self.range(lo, hi), self.range(lo, hi), self.range(lo, hi))
        }
        pub(crate) fn unit(&mut self) -> Vec3 {
            loop {
                let v = self.vec3(-1.0, 1.0);
                let l = v.length();
                if l > 0.1 && l <= 1.0 {
                    return v / l;
                }
            }
        }
    }

    /// The closed meshes of the watertightness test (the stability suite's): an icosphere
    /// (2 subdivisions, vertices shared by index) and a cube of shared-edge triangles.
    fn closed_meshes() -> Vec<(&'static str, Vec<[Vec3; 3]>)> {
        use crsh_scene::stress::meshes;
        let tris = |m: &meshes::TriMesh| {
            (0..m.indices.len())
                .map(|t| m.triangle(t))
                .collect::<Vec<_>>()
        };
        let sphere = meshes::icosphere(2);
        let cube = meshes::shared_edge_cube(1).scaled_translated(0.7, Default::default());
        assert!(sphere.is_closed() && cube.is_closed());
        vec![("icosphere", tris(&sphere)), ("cube", tris(&cube))]
    }

    /// Rays from points inside a closed mesh aimed exactly (in f32) at its edges and vertices:
    /// returns `(rays, escapes)` for test `T` with the mesh moved by `shift`.
    fn escapes<T: TriangleTest>(tris: &[[Vec3; 3]], shift: Vec3, rng: &mut TestRng) -> (u32, u32) {
        let moved: Vec<[Vec3; 3]> = tris
            .iter()
            .map(|t| [t[0] + shift, t[1] + shift, t[2] + shift])
            .collect();
        let set = TriangleSet::<T>::from_triangles(moved.iter().copied());
        let (mut rays, mut escaped) = (0, 0);
        for t in &moved {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                let mut targets = vec![a, a + (b - a) * 0.5];
                targets.extend((0..6).map(|_| a + (b - a) * rng.f32()));
                for target in targets {
                    let origin = shift + rng.vec3(-0.2, 0.2);
                    let r = T::ray(origin, target - origin);
                    rays += 1;
                    let hit = set
                        .triangles()
                        .iter()
                        .any(|tri| T::intersect(tri, &r, 0.0, f32::INFINITY).is_some());
                    if !hit {
                        escaped += 1;
                    }
                }
            }
        }
        (rays, escaped)
    }

    #[test]
    fn watertight_rays_never_escape_closed_meshes() {
        for (name, tris) in closed_meshes() {
            for shift in [Vec3::ZERO, Vec3::splat(3.7), Vec3::new(1e3, -2e3, 5e2)] {
                let mut rng = TestRng(77);
                let (rays, wt) = escapes::<Watertight>(&tris, shift, &mut rng);
                let mut rng = TestRng(77);
                let (_, mt) = escapes::<MollerTrumbore>(&tris, shift, &mut rng);
                let mut rng = TestRng(77);
                let (_, pj) = escapes::<Projected>(&tris, shift, &mut rng);
                println!(
                    "{name} shifted by {shift}: {rays} rays at edges and vertices, escapes: \
                     watertight {wt}, mt {mt}, projected {pj}"
                );
                assert!(rays >= 250, "{rays} rays: not a test");
                assert_eq!(wt, 0, "{name} shifted by {shift}: watertight rays escaped");
            }
        }
    }

    /// Random rays at random triangles: every test agrees with the f64 reference except for
    /// rays passing within rounding distance of an edge.
    #[test]
    fn every_test_agrees_with_f64_except_within_rounding_of_an_edge() {
        fn check<T: TriangleTest>(rng: &mut TestRng) -> (u32, u32) {
            let (mut hits, mut off) = (0, 0);
            for _ in 0..4000 {
                let a = rng.vec3(-1.0, 1.0);
                let (b, c) = (a + rng.vec3(-1.0, 1.0), a + rng.vec3(-1.0, 1.0));
                if is_degenerate(a, b, c) {
                    continue;
                }
                let target = a + (b - a) * rng.range(-0.2, 1.0) + (c - a) * rng.range(-0.2, 1.0);
                let o = rng.vec3(-3.0, 3.0);
                let d = target - o;
                let got = T::intersect(&T::prepare(a, b, c), &T::ray(o, d), 0.0, f32::INFINITY);
                // f64: where the ray crosses the plane, and its barycentrics.
                let (a64, b64, c64, o64, d64) = (
                    a.as_dvec3(),
                    b.as_dvec3(),
                    c.as_dvec3(),
                    o.as_dvec3(),
                    d.as_dvec3(),
                );
                let n = (b64 - a64).cross(c64 - a64);
                let t = n.dot(a64 - o64) / n.dot(d64);
                let p = o64 + d64 * t;
                let area = n.length();
                let w_b = (p - a64).cross(c64 - a64).dot(n) / (area * area);
                let w_c = (b64 - a64).cross(p - a64).dot(n) / (area * area);
                let w_a = 1.0 - w_b - w_c;
                let sin = (n.dot(d64) / (area * d64.length())).abs();
                let want = t > 0.0 && w_a >= 0.0 && w_b >= 0.0 && w_c >= 0.0;
                let margin = w_a.abs().min(w_b.abs()).min(w_c.abs());
                // f32 rounding of the inputs moves the crossing by ~1e-7 relative, amplified by
                // 1 / sin at grazing angles.
                let tol = 1e-5 + 4e-6 / sin.max(1e-9);
                if got.is_some() != want {
                    // Only within rounding of an edge (or rejected as nearly parallel).
                    assert!(
                        margin < tol || sin <= 2e-6,
                        "{:?}: {a} {b} {c} from {o} along {d}: got {got:?}, f64 weights \
                         ({w_a}, {w_b}, {w_c}), t {t}",
                        T::KIND
                    );
                    off += 1;
                }
                if let (Some((tg, u, v)), true) = (got, want) {
                    hits += 1;
                    assert!(
                        (tg as f64 - t).abs() <= tol * t.abs().max(1.0),
                        "t {tg} vs {t}"
                    );
                    assert!(
                        (u as f64 - w_b).abs() < tol && (v as f64 - w_c).abs() < tol,
                        "{:?}: ({u}, {v}) vs f64 ({w_b}, {w_c}), sin {sin}",
                        T::KIND
                    );
                }
            }
            (hits, off)
        }
        for kind in TestKind::ALL {
            let mut rng = TestRng(5);
            let (hits, off) = match kind {
                TestKind::MollerTrumbore => check::<MollerTrumbore>(&mut rng),
                TestKind::Watertight => check::<Watertight>(&mut rng),
                TestKind::Projected => check::<Projected>(&mut rng),
            };
            assert!(hits > 1000, "{kind:?}: too few hits to be a test: {hits}");
            assert!(
                off < 5,
                "{kind:?}: {off} rays disagreed with f64 near edges"
            );
        }
    }

    /// The shared rules, for every test: known hits, the open interval, inclusive edges,
    /// parallel rays, degenerate triangles, back faces, non-unit directions.
    #[test]
    fn every_test_follows_the_shared_rules() {
        fn rules<T: TriangleTest>() {
            let k = T::KIND;
            let tri = T::prepare(Vec3::ZERO, Vec3::X, Vec3::Y);
            let down = |x: f32, y: f32| T::ray(Vec3::new(x, y, 1.0), -Vec3::Z);
            assert_eq!(
                T::intersect(&tri, &down(0.25, 0.5), 0.0, f32::INFINITY),
                Some((1.0, 0.25, 0.5)),
                "{k:?}"
            );
            for (x, y) in [(0.6, 0.6), (-0.1, 0.5), (0.5, -0.1)] {
                assert!(T::intersect(&tri, &down(x, y), 0.0, 9.0).is_none(), "{k:?}");
            }
            let r = down(0.25, 0.25);
            assert!(
                T::intersect(&tri, &r, 0.0, 1.0).is_none(),
                "{k:?}: t == t_max"
            );
            assert!(
                T::intersect(&tri, &r, 1.0, 2.0).is_none(),
                "{k:?}: t == t_min"
            );
            assert!(T::intersect(&tri, &r, 0.999, 1.001).is_some(), "{k:?}");
            for (x, y) in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (0.5, 0.0), (0.0, 0.5)] {
                assert!(
                    T::intersect(&tri, &down(x, y), 0.0, 9.0).is_some(),
                    "{k:?}: ({x}, {y}) is on the boundary"
                );
            }
            // Back face, non-unit direction.
            let up = T::ray(Vec3::new(0.25, 0.25, -1.0), Vec3::Z * 2.0);
            assert_eq!(
                T::intersect(&tri, &up, 0.0, 5.0),
                Some((0.5, 0.25, 0.25)),
                "{k:?}"
            );
            // Parallel, in and above the plane; pointing away.
            for (o, d) in [
                (Vec3::new(-1.0, 0.25, 0.0), Vec3::X),
                (Vec3::new(-1.0, 0.25, 0.5), Vec3::X),
                (Vec3::new(0.25, 0.25, 1.0), Vec3::Z),
            ] {
                assert!(
                    T::intersect(&tri, &T::ray(o, d), 0.0, 9.0).is_none(),
                    "{k:?}"
                );
            }
            // Degenerate triangles never hit.
            let mut rng = TestRng(11);
            for c in [
                [Vec3::ZERO, Vec3::ZERO, Vec3::ZERO],
                [Vec3::ZERO, Vec3::X, Vec3::X * 2.0],
                [Vec3::ZERO, Vec3::X, Vec3::new(f32::NAN, 0.0, 0.0)],
            ] {
                let t = T::prepare(c[0], c[1], c[2]);
                assert!(T::is_degenerate(&t), "{k:?}: {c:?}");
                for _ in 0..200 {
                    let o = rng.unit() * rng.range(0.1, 3.0);
                    let target = Vec3::new(rng.f32(), rng.range(-1e-9, 1e-9), 0.0);
                    let r = T::ray(o, target - o);
                    assert!(T::intersect(&t, &r, f32::NEG_INFINITY, f32::INFINITY).is_none());
                }
            }
            // Rays with NaN or zero directions miss.
            for (o, d) in [
                (Vec3::new(0.25, 0.25, 1.0), Vec3::ZERO),
                (Vec3::new(0.25, 0.25, 1.0), Vec3::new(f32::NAN, 0.0, -1.0)),
                (Vec3::new(f32::NAN, 0.25, 1.0), -Vec3::Z),
            ] {
                assert!(
                    T::intersect(&tri, &T::ray(o, d), 0.0, 9.0).is_none(),
                    "{k:?}"
                );
            }
        }
        rules::<MollerTrumbore>();
        rules::<Watertight>();
        rules::<Projected>();
    }

    /// Blocks and packets report exactly what the scalar test reports, for every test.
    #[test]
    fn blocks_and_packets_match_scalar_bit_for_bit() {
        fn check<T: TriangleTest>() {
            let mut rng = TestRng(3);
            let tris: Vec<[Vec3; 3]> = (0..37)
                .map(|i| {
                    let a = rng.vec3(-1.0, 1.0);
                    if i % 13 == 0 {
                        [a, a, a + Vec3::X]
                    } else {
                        [a, a + rng.vec3(-0.5, 0.5), a + rng.vec3(-0.5, 0.5)]
                    }
                })
                .collect();
            let set = TriangleSet::<T>::from_triangles(tris.iter().copied());
            assert_eq!(set.blocks().len(), 5);
            assert_eq!(set.degenerate_count(), 3);
            let mut hits = 0;
            for round in 0..80 {
                let count = 1 + round % LANES;
                let rays: Vec<Ray> = (0..count)
                    .map(|i| {
                        let [a, b, c] = tris[(round * 7 + i) % tris.len()];
                        let o = rng.vec3(-2.0, 2.0);
                        let target =
                            a + (b - a) * rng.range(-0.1, 0.7) + (c - a) * rng.range(-0.1, 0.7);
                        let t_max = if i % 3 == 0 { 2.0 } else { f32::INFINITY };
                        crate::intersect::brute::tests::test_ray(o, target - o, 1e-4, t_max, i)
                    })
                    .collect();
                let mut packet = T::empty_packet();
                for (l, r) in rays.iter().enumerate() {
                    T::set_lane(&mut packet, l, r);
                }
                for (id, tri) in set.triangles().iter().enumerate() {
                    let (mask, ph) = T::test_packet(&packet, tri);
                    assert_eq!(mask >> count, 0, "an unused lane hit");
                    for (l, ray) in rays.iter().enumerate() {
                        let r = T::ray_of(ray);
                        let scalar = T::intersect(tri, &r, ray.t_min, ray.t_max);
                        let bh = T::test_block(&set.blocks()[id / LANES], &r, ray.t_min, ray.t_max);
                        let lane = id % LANES;
                        match scalar {
                            Some((t, u, v)) => {
                                hits += 1;
                                assert_ne!(mask & (1 << l), 0);
                                let bits = (t.to_bits(), u.to_bits(), v.to_bits());
                                assert_eq!(
                                    (ph.t[l].to_bits(), ph.u[l].to_bits(), ph.v[l].to_bits()),
                                    bits
                                );
                                assert_eq!(
                                    (
                                        bh.t[lane].to_bits(),
                                        bh.u[lane].to_bits(),
                                        bh.v[lane].to_bits()
                                    ),
                                    bits
                                );
                            }
                            None => {
                                assert_eq!(mask & (1 << l), 0);
                                assert_eq!(ph.t[l], f32::INFINITY);
                                assert_eq!(bh.t[lane], f32::INFINITY);
                            }
                        }
                    }
                }
            }
            assert!(
                hits > 100,
                "{:?}: too few hits to be a test: {hits}",
                T::KIND
            );
        }
        check::<MollerTrumbore>();
        check::<Watertight>();
        check::<Projected>();
    }

    #[test]
    fn names_round_trip() {
        for k in TestKind::ALL {
            assert_eq!(TestKind::from_name(k.name()), Some(k));
        }
        assert_eq!(
            TEST_NAMES,
            TestKind::ALL.map(TestKind::name).as_slice(),
            "the catalogue's choices"
        );
        assert_eq!(TestKind::from_name("nope"), None);
    }
}
