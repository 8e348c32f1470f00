//! Origin offsets from precomputed empty hemispheres: Zoet & Bikker, "Accelerating Ray
//! Tracing with Origin Offsets" (seed 001).
//!
//! A set of hemispheres is placed on the scene's triangles, each guaranteed to contain no
//! geometry (§3). A ray leaving a triangle whose start lies inside one of the triangle's
//! hemispheres can start its traversal where it leaves that hemisphere instead, skipping the
//! leaf it starts in and often several levels above it. This module builds the sets
//! ([`HemisphereSet::build`]) and answers the query ([`HemisphereSet::offset_t_min`] for rays
//! leaving a surface, [`HemisphereSet::cut_t_max`] for shadow rays arriving at one); the ray
//! generators call it, and the query is a pure function over a flat table
//! ([`offset_t_min`], [`cut_t_max`], [`hemisphere_interval`]) so that it ports to WGSL as is.
//!
//! # Placement (§3.1)
//!
//! [`SetKind`] names the four strategies of §3.1 / figure 3:
//! - `center`: one hemisphere at the triangle's centroid (figure 2).
//! - `vertex`: one at each vertex (zero at concave corners, as §3.1 says).
//! - `median`: one halfway between each vertex and the centroid, plus the centroid one (the
//!   64-byte layout of §3.2: "adding the extra hemisphere will increase the per triangle data
//!   to 64 bytes, exactly a cache line"). Records are `[m_a, m_b, m_c, centroid]`.
//! - `polygon`: triangles are grouped into planar polygons (edge-connected through shared
//!   vertex *positions*, same orientation, normals within [`POLYGON_SIN`]); each triangle uses
//!   the largest centroid hemisphere of its polygon ("select the largest of all hemispheres and
//!   assigning this to each triangle of the polygon", §3.1), stored with the indexed lookup of
//!   §3.2: one `u32` per triangle and one hemisphere per polygon. Ties go to the lowest
//!   triangle id.
//!
//! # What a hemisphere is
//!
//! A hemisphere sits on triangle `T` at a centre `c`, on the front side of `T`'s geometric
//! normal `n = normalize((b − a) × (c − a))` (computed in `f64`). With the coplanarity
//! tolerance `h = PLANE_REL · max |coordinate of T's vertices|` ([`PLANE_REL`]), its radius
//! `r` is the **exact** distance from `c` to the nearest geometry on the normal's side: over
//! every triangle except `T`, the distance from `c` to the closest point of
//! `triangle ∩ {x : n·(x − c) ≥ h}`. The region
//!
//! `R = {x : |x − c| < r, n·(x − c) > h}`
//!
//! then holds no point of any triangle (`T` itself lies in its plane, below `h`). Geometry
//! within `h` of `T`'s plane (coplanar neighbours, whose `f32` vertices are off the exact plane
//! by rounding) is ignored, which is what lets a hemisphere grow beyond its own triangle
//! (figure 2's red triangle is the kind of geometry that limits it). Concave corners give
//! (nearly) zero naturally: a neighbour rising at angle `θ` from a vertex bounds the vertex
//! hemisphere at `h / sin θ`, which the shrink below turns into 0. Nothing on the normal's side
//! gives `+∞`. Degenerate triangles (those no ray-triangle test of [`crate::triangle`] hits,
//! [`crate::triangle::is_degenerate`], whose normals are rounding noise) get radius 0.
//! Triangles of exactly zero area ([`crsh_scene::is_degenerate_triangle`]) are not geometry:
//! no test of [`crate::triangle`] can hit them; every other triangle is (needles included,
//! which the watertight test hits).
//!
//! # Construction
//!
//! Efficient construction is §6's open question; here radii come from a nearest-distance
//! query, not from casting rays: an obvhs [`Bvh2`] over the scene's triangles, traversed
//! branch and bound (nearest box first; a box is pruned when its distance to `c` exceeds the
//! best distance found, or when it lies entirely below the plane `n·(x − c) = h`). The
//! distance to one triangle clips it to the half-space (a convex polygon of at most 4
//! vertices) and measures point-to-convex-polygon distance in `f64`. Pruning keeps a relative
//! slack of 1e-9, far above the `f64` rounding of the distances, so the result is the minimum
//! over *all* triangles whatever the tree's shape: sites are independent, computed in parallel
//! with rayon and collected in order, so the table is the same bit for bit for any thread
//! count.
//!
//! # Stored records and their margins
//!
//! The query runs in `f32` on stored, rounded data, and the intersectors' `t` carries rounding
//! relative to the magnitude of the coordinates; the stored hemisphere is therefore a
//! conservative subset of `R`, so that whatever the query computes lies in `R`:
//!
//! - the stored centre is `c_s = f32(c + 2h·n)`: lifted by `2h` along the normal, so that the
//!   query needs no `h` (its half-space is `n·(x − c_s) > 0`). The `f32` rounding `ε = |c_s −
//!   (c + 2h·n)|` is below `1.1e-7·max|c|` < `h`, so every point above `c_s`'s plane is more
//!   than `2h − ε > h` above `c`'s;
//! - the stored radius is
//!   `r_s = r − 2h − ε − (SHRINK_REL · r + SHRINK_COORD · (max|c| + r))`, rounded down to
//!   `f32`, and 0 when negative. `2h + ε` makes the lifted ball a subset of the original
//!   (triangle inequality). The other two terms leave room between the returned `t` and the
//!   geometry just outside `R` for the intersectors' rounding of that geometry's `t`, which is
//!   about `u·(|o − v| + t) / sin θ` for Möller-Trumbore (`u = 2⁻²⁴`, `θ` the angle between the
//!   ray and the hit triangle): [`SHRINK_REL`] = 1e-4 (~1700 ULPs of the radius, 0.01% of
//!   each offset) covers the part that grows with the distance down to `sin θ ≈ 1e-3`, and
//!   the query's own errors that grow with the radius (its squares and square root);
//!   [`SHRINK_COORD`] = 2e-6 (~34 ULPs of the coordinates) covers the part that grows with the
//!   coordinates' magnitude for hits that are not grazing, at the cost of hemispheres smaller
//!   than that, which could not move a ray out of a leaf anyway;
//! - the query itself shrinks once more by `QUERY_REL · (max|o − c_s| + max|c_s| + r_s)`
//!   ([`QUERY_REL`] = 2e-6) in radius and in height, which covers its own `f32` errors (the
//!   closest-approach point is computed from the ray origin, so its error grows with the
//!   origin's distance, which matters for a shadow ray from a far light) and the `f32`
//!   rounding of the stored normal, and moves the returned `t` by [`T_REL`] = 1e-5 of itself
//!   towards the side that skips less (the intersectors' `t` error grows with `t`, as the
//!   Wächter segments of [`crate::raygen::whitted`] measure: 32 ULPs of the length there).
//!
//! At the base plane no such trade is needed: a ray that leaves `R` downwards reaches geometry
//! within `h` of the plane (a coplanar neighbour) only after a path `≥ 0.9h / sin θ`, and the
//! hit's error is a few ULPs of the coordinates `/ sin θ`, 16 times less.
//!
//! What is left is a hit at grazing incidence near the hemisphere's boundary: its `t` error
//! grows as `1 / sin θ` without bound (down to [`crate::triangle::DET_REL_EPS`] for
//! Möller-Trumbore, to 0 for the watertight test), so no finite margin covers it, and which
//! side of the returned `t` it lands on is rounding noise. Aiming rays at the very points that
//! limit the hemispheres (the tests' targeted check with `HEMI_SITES=3000`: 4.2 million
//! ray-and-set queries, half of them shadow segments, on the test scenes), 6 answers differ,
//! all hits at `sin θ ≤ 2.1e-4`, none of them a hit inside the hemisphere in `f64`; with every
//! margin at 0 the same check (at its default size) gives thousands of differences, head-on
//! hits among them. Random rays (`HEMI_POINTS=5000`: 3.4 million queries, grazing directions
//! and origins on edges and corners included) give none.
//!
//! # Query
//!
//! For each hemisphere `i` of the ray's triangle, the ray's intersection with the (convex)
//! stored region is one interval `(t0, t1)`: the ball's chord intersected with the half-space's
//! half-line ([`hemisphere_interval`]).
//!
//! - [`offset_t_min`]: a ray leaving triangle `tri` whose start `o + t_min·d` lies in some
//!   region (`t0 ≤ t_min < t1`) may start at the largest such `t1` instead (§3: "If the ray
//!   intersects multiple hemispheres, the greatest intersection distance is used"). With every
//!   policy of [`crate::raygen::whitted::OffsetPolicy`] the start is the interval's start, so
//!   `normal` origins (moved off the plane) and `scaled` / `fixed` ones (on the plane, `t_min`
//!   moving the start off it) and `wachter` ones (`t_min = 0`) all work; a start closer to the
//!   plane than the lift and the margins (about `4e-6` of the coordinates plus `2e-6` of the
//!   radius) gets no offset. The result is clamped
//!   to `t_max`: when it reaches `t_max` (`+∞` for an unbounded ray when nothing lies above)
//!   the ray ends without traversal.
//! - [`cut_t_max`]: a shadow ray from a light that ends on triangle `tri` (the thesis's
//!   convention, the end point `o + t_max·d` slightly off the surface): if its end lies in some
//!   region (`t0 < t_max ≤ t1`), nothing lies on the segment after the smallest such `t0`, and
//!   `t_max` becomes it; when it falls to `t_min` the segment is empty (unoccluded).
//!
//! Both leave the interval as it is when no region contains the end in question, for a
//! triangle id out of range, and for an invalid ray.
//!
//! # Measured
//!
//! Release build, 2 shared cores (load ~3.5), `cargo test --release -p crsh-cpu --lib
//! origin_offset::tests::measure -- --ignored --nocapture`; build time includes the BVH.
//! Mean radius: finite stored radii per triangle that uses them, relative to the diagonal.
//!
//! | scene (triangles) | set | build | table | zero | `+∞` | mean radius |
//! | --- | --- | --- | --- | --- | --- | --- |
//! | dragon (47,794) | center | 104 ms | 0.76 MB | 0% | 0.2% | 0.0043 |
//! | | vertex | 285 ms | 2.29 MB | 23.2% | 0.2% | 0.0034 |
//! | | median | 350 ms | 3.06 MB | 0% | 0.2% | 0.0040 |
//! | | polygon (47,565 polygons) | 126 ms | 0.95 MB | 0% | 0.2% | 0.0043 |
//! | bunny (69,451) | center | 245 ms | 1.11 MB | 0% | 0.9% | 0.0057 |
//! | | vertex | 456 ms | 3.33 MB | 8.5% | 0.9% | 0.0051 |
//! | | median | 768 ms | 4.44 MB | 0% | 0.9% | 0.0055 |
//! | | polygon (68,782 polygons) | 292 ms | 1.38 MB | 0% | 0.9% | 0.0057 |
//! | sponza (262,205) | center | 1.1 s | 4.20 MB | 0% | 0% | 0.0012 |
//! | | vertex | 4.1 s | 12.6 MB | 24.7% | 0% | 0.0010 |
//! | | median | 5.5 s | 16.8 MB | 0% | 0% | 0.0011 |
//! | | polygon (219,317 polygons) | 1.7 s | 4.56 MB | 0% | 0% | 0.0015 |
//!
//! The normals add 16 B per slot. Vertex hemispheres are zero at concave corners, as §3.1
//! predicts (a quarter of them in the architectural sponza). The timings are the faster of two
//! runs on a shared machine; the other took up to twice as long (dragon center 213 ms, bunny
//! vertex 866 ms).
//!
//! # GPU layout
//!
//! For a WGSL port, [`HemisphereSet::records`] is an `array<vec4<f32>>` (centre `xyz`, radius
//! `w`), [`HemisphereSet::per_slot`] consecutive records per *slot*; the slot of triangle `t`
//! is `t` for `center`, `vertex` and `median`, and [`HemisphereSet::triangle_index`]`[t]`
//! (an `array<u32>`) for `polygon`. Radii: `0` never contains anything (unusable), finite
//! values are ordinary, and `+∞` is stored as [`INFINITE_RADIUS`] (`f32::MAX`, finite, because
//! WGSL may assume that no infinity occurs); the query tests for it before squaring.
//! [`HemisphereSet::normals`] is an `array<vec4<f32>>` per slot (unit `xyz`, `w = 0`): the
//! query needs the normal the hemisphere was built with, which for `polygon` is the chosen
//! triangle's, not the ray's, and the `f64` normal rounded to `f32` is accurate even for thin
//! triangles, where one recomputed from the vertices in `f32` is not. It is counted apart
//! ([`HemisphereSet::normal_bytes`]) from the paper's sizes ([`HemisphereSet::bytes`]): a
//! renderer that keeps geometric normals per triangle already has them.

use std::time::{Duration, Instant};

use crsh_core::glam::{DVec3, Vec3};
use crsh_core::{f32_down, Ray};
use crsh_scene::Scene;
use obvhs::bvh2::builder::build_bvh2_from_tris;
use obvhs::bvh2::node::Bvh2Node;
use obvhs::bvh2::Bvh2;
use obvhs::triangle::Triangle;
use obvhs::BvhBuildParams;
use rayon::prelude::*;

use crate::intersect::bvh::obvhs_triangle;
use crate::triangle::is_degenerate;

/// Coplanarity tolerance, relative to the largest coordinate (absolute value) of a
/// hemisphere's triangle: `h = PLANE_REL · max|v|` (16 `f32` ULPs). Geometry closer than `h`
/// above the triangle's plane is ignored (see the module docs).
pub const PLANE_REL: f64 = 1e-6;

/// The stored radius's shrink relative to the radius (see the module docs).
pub const SHRINK_REL: f64 = 1e-4;

/// The stored radius's shrink relative to `max|c| + r`, the coordinates' magnitude (see the
/// module docs).
pub const SHRINK_COORD: f64 = 2e-6;

/// The query's margin in radius and height, relative to `max|o − c_s| + max|c_s| + r_s`.
pub const QUERY_REL: f32 = 2e-6;

/// The returned `t` moves by this fraction of itself to the side that skips less.
pub const T_REL: f32 = 1e-5;

/// Two edge-sharing triangles belong to one polygon when the sine of the angle between their
/// normals is at most this (and the normals point the same way).
pub const POLYGON_SIN: f64 = 1e-4;

/// A stored radius meaning `+∞` (nothing above the triangle's plane), finite for WGSL.
pub const INFINITE_RADIUS: f32 = f32::MAX;

/// The names of [`SetKind::ALL`], in that order.
pub const SET_NAMES: &[&str] = &["center", "vertex", "median", "polygon"];

/// A hemisphere placement strategy (§3.1, figure 3).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum SetKind {
    /// One hemisphere at the centroid (16 B per triangle).
    Center,
    /// One at each vertex (48 B per triangle).
    Vertex,
    /// One halfway between each vertex and the centroid, plus the centroid (64 B).
    Median,
    /// The largest centroid hemisphere of the triangle's planar polygon (4 B per triangle
    /// plus 16 B per polygon).
    Polygon,
}

impl SetKind {
    /// Every kind, in the paper's order.
    pub const ALL: [SetKind; 4] = [
        SetKind::Center,
        SetKind::Vertex,
        SetKind::Median,
        SetKind::Polygon,
    ];

    /// The name of this kind (`center`, `vertex`, `median`, `polygon`).
    pub fn name(self) -> &'static str {
        match self {
            SetKind::Center => "center",
            SetKind::Vertex => "vertex",
            SetKind::Median => "median",
            SetKind::Polygon => "polygon",
        }
    }

    /// The kind called `name`, if any.
    pub fn from_name(name: &str) -> Option<SetKind> {
        SetKind::ALL.into_iter().find(|k| k.name() == name)
    }

    /// Hemispheres per slot (per triangle, or per polygon for `polygon`).
    pub fn per_slot(self) -> usize {
        match self {
            SetKind::Center | SetKind::Polygon => 1,
            SetKind::Vertex => 3,
            SetKind::Median => 4,
        }
    }
}

/// Where a hemisphere sits, before its radius is known: exact (`f64`) centre, the unit normal
/// of its triangle (zero for a degenerate triangle) and the coplanarity tolerance `h`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Site {
    /// The triangle it sits on.
    pub tri: u32,
    /// Centre (centroid, vertex or median point), in `f64`.
    pub centre: DVec3,
    /// Unit geometric normal of the triangle (`f64`); zero when the triangle is degenerate.
    pub normal: DVec3,
    /// Coplanarity tolerance, `PLANE_REL · max|v|` over the triangle's vertices.
    pub h: f64,
}

/// The sites of every triangle of `scene` for `kind`, triangle-major, [`SetKind::per_slot`]
/// per triangle (`polygon` uses the centroids, one per triangle, before grouping).
pub fn sites(scene: &Scene, kind: SetKind) -> Vec<Site> {
    (0..scene.triangle_count())
        .into_par_iter()
        .flat_map_iter(|t| {
            let [a, b, c] = scene.triangle(t);
            let (a64, b64, c64) = (a.as_dvec3(), b.as_dvec3(), c.as_dvec3());
            let normal = if is_degenerate(a, b, c) {
                DVec3::ZERO
            } else {
                (b64 - a64).cross(c64 - a64).normalize_or_zero()
            };
            let h = PLANE_REL * a.abs().max(b.abs()).max(c.abs()).max_element() as f64;
            let g = (a64 + b64 + c64) / 3.0;
            let centres: Vec<DVec3> = match kind {
                SetKind::Center | SetKind::Polygon => vec![g],
                SetKind::Vertex => vec![a64, b64, c64],
                SetKind::Median => vec![(a64 + g) * 0.5, (b64 + g) * 0.5, (c64 + g) * 0.5, g],
            };
            centres.into_iter().map(move |centre| Site {
                tri: t as u32,
                centre,
                normal,
                h,
            })
        })
        .collect()
}

/// The distance from `c` to the part of triangle `t` on or above height `h`
/// (`{x ∈ t : n·(x − c) ≥ h}`), `+∞` when there is none: the triangle clipped to the
/// half-space (a convex polygon of at most four vertices), then point-to-polygon distance.
pub fn clipped_distance(c: DVec3, n: DVec3, h: f64, t: &[DVec3; 3]) -> f64 {
    let heights = t.map(|v| n.dot(v - c) - h);
    if heights.iter().all(|&x| x < 0.0) {
        return f64::INFINITY;
    }
    // Sutherland-Hodgman against one plane, keeping the triangle's orientation.
    let mut poly = [DVec3::ZERO; 4];
    let mut k = 0;
    for i in 0..3 {
        let j = (i + 1) % 3;
        let (ha, hb) = (heights[i], heights[j]);
        if ha >= 0.0 {
            poly[k] = t[i];
            k += 1;
        }
        if (ha >= 0.0) != (hb >= 0.0) {
            poly[k] = t[i] + (t[j] - t[i]) * (ha / (ha - hb));
            k += 1;
        }
    }
    let poly = &poly[..k];
    // The projection of c on the triangle's plane lies in the polygon when it lies in the
    // triangle and on or above height h; then the plane distance is the answer.
    let m = (t[1] - t[0]).cross(t[2] - t[0]);
    let m_len = m.length();
    if m_len > 0.0 {
        let inside_tri = (0..3).all(|i| {
            let e = t[(i + 1) % 3] - t[i];
            e.cross(c - t[i]).dot(m) >= 0.0
        });
        if inside_tri {
            let plane = m.dot(c - t[0]) / m_len;
            // c − plane·m̂ is the projection; its height is −plane·(n·m̂) (− h).
            let proj_height = -plane * n.dot(m) / m_len - h;
            if proj_height >= 0.0 {
                return plane.abs();
            }
        }
    }
    // Otherwise the closest point is on the polygon's boundary.
    (0..k)
        .map(|i| segment_distance(c, poly[i], poly[(i + 1) % k]))
        .fold(f64::INFINITY, f64::min)
}

/// Distance from `p` to the segment `a b` (a point when `a = b`).
fn segment_distance(p: DVec3, a: DVec3, b: DVec3) -> f64 {
    let ab = b - a;
    let len2 = ab.length_squared();
    let s = if len2 > 0.0 {
        (ab.dot(p - a) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (a + ab * s - p).length()
}

/// The scene's triangles that are geometry (every one but those of exactly zero area) in a
/// binary BVH, for the nearest-distance queries.
struct Occluders {
    bvh: Bvh2,
    /// Vertices in `f64`, in the order the BVH's primitive indices refer to.
    tris: Vec<[DVec3; 3]>,
    /// Scene triangle id of each.
    ids: Vec<u32>,
}

impl Occluders {
    fn new(scene: &Scene) -> Option<Occluders> {
        let (ids, tris32): (Vec<u32>, Vec<[Vec3; 3]>) = (0..scene.triangle_count())
            .into_par_iter()
            .filter_map(|t| {
                let tri = scene.triangle(t);
                (!crsh_scene::is_degenerate_triangle(tri[0], tri[1], tri[2]))
                    .then_some((t as u32, tri))
            })
            .unzip();
        if ids.is_empty() {
            return None;
        }
        let obvhs_tris: Vec<Triangle> = tris32.iter().map(|&t| obvhs_triangle(t)).collect();
        let bvh = build_bvh2_from_tris(
            &obvhs_tris,
            BvhBuildParams::fast_build(),
            &mut Duration::default(),
        );
        let tris = tris32.iter().map(|t| t.map(|v| v.as_dvec3())).collect();
        Some(Occluders { bvh, tris, ids })
    }

    /// Squared distance from the site's centre to the node's box, or `+∞` when the box lies
    /// entirely below height `h` (nothing in it can count).
    fn bound(node: &Bvh2Node, site: &Site) -> f64 {
        let aabb = node.aabb();
        let lo = Vec3::from(aabb.min).as_dvec3();
        let hi = Vec3::from(aabb.max).as_dvec3();
        let (c, n) = (site.centre, site.normal);
        let top = DVec3::new(
            if n.x >= 0.0 { hi.x } else { lo.x },
            if n.y >= 0.0 { hi.y } else { lo.y },
            if n.z >= 0.0 { hi.z } else { lo.z },
        );
        // The slack covers the f64 rounding of vertex heights (relative to the magnitudes).
        let slack = 1e-12 * (lo.abs().max(hi.abs()).max_element() + c.abs().max_element());
        if n.dot(top - c) < site.h - slack {
            return f64::INFINITY;
        }
        (lo - c).max(c - hi).max(DVec3::ZERO).length_squared()
    }

    /// Whether a node whose squared bound is `lb` can hold something closer than `best`.
    fn may_improve(lb: f64, best: f64) -> bool {
        lb.is_finite() && lb <= best * best * (1.0 + 1e-9)
    }

    /// The exact radius of `site` (see the module docs); `stack` is scratch space.
    fn radius(&self, site: &Site, stack: &mut Vec<u32>) -> f64 {
        if site.normal == DVec3::ZERO {
            return 0.0;
        }
        let nodes = &self.bvh.nodes;
        let mut best = f64::INFINITY;
        stack.clear();
        if Occluders::bound(&nodes[0], site).is_finite() {
            stack.push(0);
        }
        while let Some(i) = stack.pop() {
            let node = &nodes[i as usize];
            if !Occluders::may_improve(Occluders::bound(node, site), best) {
                continue;
            }
            if node.is_leaf() {
                let first = node.first_index as usize;
                for &p in &self.bvh.primitive_indices[first..first + node.prim_count as usize] {
                    let p = p as usize;
                    if self.ids[p] != site.tri {
                        let d = clipped_distance(site.centre, site.normal, site.h, &self.tris[p]);
                        best = best.min(d);
                    }
                }
            } else {
                let (a, b) = (node.first_index, node.first_index + 1);
                let la = Occluders::bound(&nodes[a as usize], site);
                let lb = Occluders::bound(&nodes[b as usize], site);
                // Nearer child on top of the stack.
                let (near, far, l_near, l_far) = if la <= lb {
                    (a, b, la, lb)
                } else {
                    (b, a, lb, la)
                };
                if Occluders::may_improve(l_far, best) {
                    stack.push(far);
                }
                if Occluders::may_improve(l_near, best) {
                    stack.push(near);
                }
            }
        }
        best
    }
}

/// The exact radius of every site (see the module docs), in order: parallel, deterministic.
pub fn exact_radii(scene: &Scene, sites: &[Site]) -> Vec<f64> {
    let Some(occ) = Occluders::new(scene) else {
        return sites
            .iter()
            .map(|s| {
                if s.normal == DVec3::ZERO {
                    0.0
                } else {
                    f64::INFINITY
                }
            })
            .collect();
    };
    sites
        .par_iter()
        .map_init(Vec::new, |stack, s| occ.radius(s, stack))
        .collect()
}

/// The stored record of a site with exact radius `r` (see the module docs): lifted centre and
/// shrunk radius.
pub fn stored_record(site: &Site, r: f64) -> [f32; 4] {
    if site.normal == DVec3::ZERO || r.is_nan() || r <= 0.0 {
        let c = site.centre.as_vec3();
        return [c.x, c.y, c.z, 0.0];
    }
    let lift = 2.0 * site.h;
    let target = site.centre + site.normal * lift;
    let cs = target.as_vec3();
    let eps = (cs.as_dvec3() - target).length();
    // The lift keeps every point above c_s's plane more than h above c's (module docs).
    debug_assert!(site.normal.dot(cs.as_dvec3() - site.centre) > site.h);
    let radius = if r.is_infinite() {
        INFINITE_RADIUS
    } else {
        let mag = site.centre.abs().max_element();
        let shrunk = r - lift - eps - (SHRINK_REL * r + SHRINK_COORD * (mag + r));
        if shrunk > 0.0 {
            // Never INFINITE_RADIUS by accident.
            f32_down(shrunk).min(f32::from_bits(INFINITE_RADIUS.to_bits() - 1))
        } else {
            0.0
        }
    };
    [cs.x, cs.y, cs.z, radius]
}

/// Planar polygons: the polygon id of every triangle (ids in order of each polygon's lowest
/// triangle) and the number of polygons. Degenerate triangles are polygons of their own.
fn polygons(scene: &Scene, normals: &[DVec3]) -> (Vec<u32>, usize) {
    let n = scene.triangle_count();
    // Edges keyed by their endpoints' positions (bit patterns, −0 as +0), sorted, so that
    // triangles sharing a position but not an index are neighbours too.
    let key = |v: Vec3| {
        let v = v + Vec3::ZERO; // −0.0 + 0.0 = +0.0
        [v.x.to_bits(), v.y.to_bits(), v.z.to_bits()]
    };
    let mut edges: Vec<([[u32; 3]; 2], u32)> = (0..n)
        .into_par_iter()
        .filter(|&t| normals[t] != DVec3::ZERO)
        .flat_map_iter(|t| {
            let v = scene.triangle(t).map(key);
            (0..3).map(move |i| {
                let (a, b) = (v[i], v[(i + 1) % 3]);
                ([a.min(b), a.max(b)], t as u32)
            })
        })
        .collect();
    edges.par_sort_unstable();
    let mut parent: Vec<u32> = (0..n as u32).collect();
    fn find(parent: &mut [u32], mut x: u32) -> u32 {
        while parent[x as usize] != x {
            let up = parent[parent[x as usize] as usize];
            parent[x as usize] = up;
            x = up;
        }
        x
    }
    let coplanar = |a: u32, b: u32| {
        let (na, nb) = (normals[a as usize], normals[b as usize]);
        na.dot(nb) > 0.0 && na.cross(nb).length() <= POLYGON_SIN
    };
    for run in edges.chunk_by(|x, y| x.0 == y.0) {
        for (i, &(_, a)) in run.iter().enumerate() {
            for &(_, b) in &run[i + 1..] {
                if a != b && coplanar(a, b) {
                    let (ra, rb) = (find(&mut parent, a), find(&mut parent, b));
                    // The lower root wins: the partition's representation is deterministic.
                    let (lo, hi) = (ra.min(rb), ra.max(rb));
                    parent[hi as usize] = lo;
                }
            }
        }
    }
    let mut id_of_root = vec![u32::MAX; n];
    let mut count = 0u32;
    let ids = (0..n as u32)
        .map(|t| {
            let root = find(&mut parent, t) as usize;
            if id_of_root[root] == u32::MAX {
                id_of_root[root] = count;
                count += 1;
            }
            id_of_root[root]
        })
        .collect();
    (ids, count as usize)
}

/// A built hemisphere set: the flat tables the query reads, and what the build measured.
#[derive(Clone, Debug, PartialEq)]
pub struct HemisphereSet {
    kind: SetKind,
    /// `per_slot` records per slot: centre `xyz` (lifted), stored radius `w`.
    records: Vec<[f32; 4]>,
    /// Unit normal per slot (`w = 0`).
    normals: Vec<[f32; 4]>,
    /// Polygon: the slot of each triangle; empty for the other kinds.
    index: Vec<u32>,
    /// Polygon: the triangle whose centroid hemisphere each slot holds; empty otherwise.
    donors: Vec<u32>,
    /// The exact (unshrunk, unlifted) radius of each record.
    exact: Vec<f64>,
    triangles: usize,
    diagonal: f32,
    build_ms: f64,
}

/// What a built set holds (see [`HemisphereSet::summary`]).
#[derive(Clone, Debug, PartialEq)]
pub struct SetSummary {
    /// The kind's name.
    pub kind: &'static str,
    /// Triangles of the scene.
    pub triangles: usize,
    /// Slots (triangles, or polygons for `polygon`).
    pub slots: usize,
    /// Stored hemispheres (records).
    pub hemispheres: usize,
    /// Fraction of hemispheres whose stored radius is 0. This and the next two count the
    /// hemispheres as the triangles use them: a `polygon` record once per triangle of its
    /// polygon.
    pub zero_fraction: f64,
    /// Fraction of hemispheres with nothing above (`+∞`).
    pub infinite_fraction: f64,
    /// Mean stored radius over the finite ones (zeros included), relative to the scene's
    /// bounding-box diagonal.
    pub mean_finite_radius_rel: f64,
    /// The table's memory in the paper's layout ([`HemisphereSet::bytes`]).
    pub bytes: usize,
    /// The normals' memory ([`HemisphereSet::normal_bytes`]).
    pub normal_bytes: usize,
    /// Build time in milliseconds.
    pub build_ms: f64,
}

impl std::fmt::Display for SetSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}: {} hemispheres ({} slots, {} triangles), {:.1}% zero, {:.1}% infinite, mean \
             finite radius {:.4} of the diagonal, {} B (+{} B normals), built in {:.1} ms",
            self.kind,
            self.hemispheres,
            self.slots,
            self.triangles,
            100.0 * self.zero_fraction,
            100.0 * self.infinite_fraction,
            self.mean_finite_radius_rel,
            self.bytes,
            self.normal_bytes,
            self.build_ms
        )
    }
}

impl HemisphereSet {
    /// Builds the set `kind` for `scene` (see the module docs): sites, exact radii by a
    /// nearest-distance BVH query, stored records; for `polygon`, the grouping and the choice
    /// of each polygon's largest hemisphere. Parallel with rayon; the same table for any
    /// thread count.
    pub fn build(scene: &Scene, kind: SetKind) -> HemisphereSet {
        let start = Instant::now();
        let sites = sites(scene, kind);
        let exact = exact_radii(scene, &sites);
        let records: Vec<[f32; 4]> = sites
            .par_iter()
            .zip(exact.par_iter())
            .map(|(s, &r)| stored_record(s, r))
            .collect();
        let per = kind.per_slot();
        let tri_normals: Vec<DVec3> = sites.iter().step_by(per).map(|s| s.normal).collect();
        let normal4 = |n: DVec3| {
            let n = n.as_vec3();
            [n.x, n.y, n.z, 0.0]
        };
        let (records, normals, index, donors, exact) = if kind == SetKind::Polygon {
            let (poly, count) = polygons(scene, &tri_normals);
            // The largest stored radius of each polygon, ties to the lowest triangle id.
            let mut chosen = vec![u32::MAX; count];
            for (t, &p) in poly.iter().enumerate() {
                let c = &mut chosen[p as usize];
                if *c == u32::MAX || records[t][3] > records[*c as usize][3] {
                    *c = t as u32;
                }
            }
            let chosen: Vec<usize> = chosen.into_iter().map(|t| t as usize).collect();
            (
                chosen.iter().map(|&t| records[t]).collect(),
                chosen.iter().map(|&t| normal4(tri_normals[t])).collect(),
                poly,
                chosen.iter().map(|&t| t as u32).collect(),
                chosen.iter().map(|&t| exact[t]).collect(),
            )
        } else {
            let normals = tri_normals.iter().map(|&n| normal4(n)).collect();
            (records, normals, Vec::new(), Vec::new(), exact)
        };
        HemisphereSet {
            kind,
            records,
            normals,
            index,
            donors,
            exact,
            triangles: scene.triangle_count(),
            diagonal: scene.bounds.diagonal(),
            build_ms: start.elapsed().as_secs_f64() * 1e3,
        }
    }

    /// The placement strategy.
    pub fn kind(&self) -> SetKind {
        self.kind
    }

    /// Hemispheres per slot ([`SetKind::per_slot`]).
    pub fn per_slot(&self) -> usize {
        self.kind.per_slot()
    }

    /// Triangles of the scene the set was built for.
    pub fn triangle_count(&self) -> usize {
        self.triangles
    }

    /// The slot of triangle `tri` (itself, or its polygon), `None` when out of range.
    pub fn slot(&self, tri: u32) -> Option<usize> {
        if tri as usize >= self.triangles {
            return None;
        }
        Some(if self.kind == SetKind::Polygon {
            self.index[tri as usize] as usize
        } else {
            tri as usize
        })
    }

    /// The records of triangle `tri`'s hemispheres (empty when out of range).
    pub fn hemispheres(&self, tri: u32) -> &[[f32; 4]] {
        let per = self.per_slot();
        self.slot(tri)
            .map_or(&[], |s| &self.records[s * per..(s + 1) * per])
    }

    /// The unit normal triangle `tri`'s hemispheres were built with (zero when degenerate or
    /// out of range).
    pub fn normal(&self, tri: u32) -> Vec3 {
        self.slot(tri).map_or(Vec3::ZERO, |s| {
            let [x, y, z, _] = self.normals[s];
            Vec3::new(x, y, z)
        })
    }

    /// Every record, slot-major (centre `xyz`, radius `w`; see the module docs' GPU layout).
    pub fn records(&self) -> &[[f32; 4]] {
        &self.records
    }

    /// The normal of every slot (`xyz`, `w = 0`).
    pub fn normals(&self) -> &[[f32; 4]] {
        &self.normals
    }

    /// `polygon`: the slot (polygon) of every triangle; empty for the other kinds.
    pub fn triangle_index(&self) -> &[u32] {
        &self.index
    }

    /// `polygon`: the triangle whose centroid hemisphere each slot (polygon) holds; empty for
    /// the other kinds.
    pub fn donors(&self) -> &[u32] {
        &self.donors
    }

    /// The exact radius (before lifting and shrinking) of every record, in record order.
    pub fn exact_radii(&self) -> &[f64] {
        &self.exact
    }

    /// Memory of the table in the paper's layout (§3.2): 16 B per hemisphere record, plus
    /// for `polygon` a 4 B index per triangle (`center` 16 B, `vertex` 48 B, `median` 64 B
    /// per triangle; `polygon` 4 B per triangle + 16 B per polygon).
    pub fn bytes(&self) -> usize {
        self.records.len() * 16 + self.index.len() * 4
    }

    /// Memory of the normals (16 B per slot), which the paper's sizes do not count.
    pub fn normal_bytes(&self) -> usize {
        self.normals.len() * 16
    }

    /// Build time in milliseconds (sites, BVH, radii, records, grouping).
    pub fn build_ms(&self) -> f64 {
        self.build_ms
    }

    /// Counts and sizes: hemispheres, fraction of zero and infinite radii, mean finite radius
    /// relative to the scene's diagonal (all three per triangle that uses the hemisphere),
    /// memory, build time.
    pub fn summary(&self) -> SetSummary {
        // Each record weighs as many triangles as use it (one, or its polygon's size).
        let per = self.per_slot();
        let mut weight = vec![1u64; self.records.len()];
        if self.kind == SetKind::Polygon {
            weight.iter_mut().for_each(|w| *w = 0);
            for &slot in &self.index {
                weight[slot as usize] += 1;
            }
        }
        let (mut used, mut zero, mut infinite, mut finite_sum) = (0u64, 0u64, 0u64, 0.0f64);
        for (rec, &w) in self.records.iter().zip(&weight) {
            used += w;
            if rec[3] == 0.0 {
                zero += w;
            }
            if rec[3] == INFINITE_RADIUS {
                infinite += w;
            } else {
                finite_sum += w as f64 * rec[3] as f64;
            }
        }
        let frac = |k: u64| {
            if used == 0 {
                0.0
            } else {
                k as f64 / used as f64
            }
        };
        let finite = used - infinite;
        SetSummary {
            kind: self.kind.name(),
            triangles: self.triangles,
            slots: self.records.len() / per,
            hemispheres: self.records.len(),
            zero_fraction: frac(zero),
            infinite_fraction: frac(infinite),
            mean_finite_radius_rel: if finite == 0 || self.diagonal <= 0.0 {
                0.0
            } else {
                finite_sum / finite as f64 / self.diagonal as f64
            },
            bytes: self.bytes(),
            normal_bytes: self.normal_bytes(),
            build_ms: self.build_ms,
        }
    }

    /// [`offset_t_min`] with triangle `tri`'s hemispheres: the new `t_min` of `ray`, which
    /// leaves `tri` (unchanged when `tri` is out of range).
    pub fn offset_t_min(&self, tri: u32, ray: &Ray) -> f32 {
        offset_t_min(
            self.hemispheres(tri),
            self.normal(tri),
            ray.origin,
            ray.dir,
            ray.t_min,
            ray.t_max,
        )
    }

    /// [`cut_t_max`] with triangle `tri`'s hemispheres: the new `t_max` of the shadow ray
    /// `ray`, which ends on `tri` (unchanged when `tri` is out of range).
    pub fn cut_t_max(&self, tri: u32, ray: &Ray) -> f32 {
        cut_t_max(
            self.hemispheres(tri),
            self.normal(tri),
            ray.origin,
            ray.dir,
            ray.t_min,
            ray.t_max,
        )
    }
}

/// The interval `(t0, t1)` of the ray `o + t·d` inside the stored hemisphere `rec` (centre
/// `xyz`, radius `w`, [`INFINITE_RADIUS`] for `+∞`) with unit normal `n`, shrunk by the
/// query's margin (see the module docs); `t0 ≥ t1` when empty. `d` need not be unit.
///
/// Computed about the ray's closest approach to the centre (`t_c = −(o − c)·d / d·d`), so that
/// the chord does not cancel catastrophically when the origin is far (a shadow ray from a
/// light): chord `t_c ± √((r_q² − |w⊥|²) / d·d)` with `r_q = r − m`, intersected with the
/// half-line where the height above the centre's plane exceeds `m`.
#[inline]
pub fn hemisphere_interval(rec: [f32; 4], n: Vec3, o: Vec3, d: Vec3) -> (f32, f32) {
    const EMPTY: (f32, f32) = (f32::INFINITY, f32::NEG_INFINITY);
    let c = Vec3::new(rec[0], rec[1], rec[2]);
    let r = rec[3];
    let dd = d.dot(d);
    let w = o - c;
    let valid = r > 0.0 && dd > 0.0 && w.is_finite() && dd.is_finite();
    if !valid {
        return EMPTY;
    }
    // From here on everything is finite or ±∞ (never NaN).
    let infinite = r >= INFINITE_RADIUS;
    let scale = w.abs().max_element() + c.abs().max_element() + if infinite { 0.0 } else { r };
    let m = QUERY_REL * scale;
    let tc = -w.dot(d) / dd;
    let wp = w + d * tc; // closest approach, relative to the centre
    let (mut lo, mut hi) = if infinite {
        (f32::NEG_INFINITY, f32::INFINITY)
    } else {
        let rq = r - m;
        if rq <= 0.0 {
            return EMPTY;
        }
        let disc = (rq * rq - wp.dot(wp)) / dd;
        if disc <= 0.0 {
            return EMPTY;
        }
        let s = disc.sqrt();
        (-s, s)
    };
    let hn = n.dot(wp);
    let dn = n.dot(d);
    if dn > 0.0 {
        lo = lo.max((m - hn) / dn);
    } else if dn < 0.0 {
        hi = hi.min((m - hn) / dn);
    } else if hn <= m {
        return EMPTY;
    }
    if lo >= hi {
        return EMPTY;
    }
    (tc + lo, tc + hi)
}

/// The new `t_min` of a ray leaving a triangle whose hemispheres are `records` (normal
/// `normal`): among the regions containing the ray's start `o + t_min·d`
/// (`t0 ≤ t_min < t1`), the largest exit `t1`, moved back by [`T_REL`] of itself; `t_min`
/// when none contains it (or the interval is empty or not a number). Clamped to `t_max`: a
/// result `≥ t_max` means nothing lies on the ray (`+∞` for an unbounded ray with nothing
/// above). See the module docs.
#[inline]
pub fn offset_t_min(
    records: &[[f32; 4]],
    normal: Vec3,
    o: Vec3,
    d: Vec3,
    t_min: f32,
    t_max: f32,
) -> f32 {
    let valid = t_min < t_max; // false for NaN
    if !valid {
        return t_min;
    }
    records
        .iter()
        .map(|&rec| hemisphere_interval(rec, normal, o, d))
        .filter(|&(t0, t1)| t0 <= t_min && t_min < t1)
        .map(|(_, t1)| nudge(t1, -T_REL))
        .fold(t_min, f32::max)
        .min(t_max)
}

/// `t` moved by `rel · |t|` (infinities stay).
#[inline]
fn nudge(t: f32, rel: f32) -> f32 {
    if t.is_finite() {
        t + rel * t.abs()
    } else {
        t
    }
}

/// The new `t_max` of a shadow ray ending on a triangle whose hemispheres are `records`
/// (normal `normal`): among the regions containing the ray's end `o + t_max·d`
/// (`t0 < t_max ≤ t1`), the smallest entry `t0`, moved forward by [`T_REL`] of itself;
/// `t_max` when none contains it. Never below `t_min`: a result `≤ t_min` means the segment
/// holds nothing (unoccluded). See the module docs.
#[inline]
pub fn cut_t_max(
    records: &[[f32; 4]],
    normal: Vec3,
    o: Vec3,
    d: Vec3,
    t_min: f32,
    t_max: f32,
) -> f32 {
    let valid = t_min < t_max; // false for NaN
    if !valid {
        return t_max;
    }
    records
        .iter()
        .map(|&rec| hemisphere_interval(rec, normal, o, d))
        .filter(|&(t0, t1)| t0 < t_max && t_max <= t1)
        .map(|(t0, _)| nudge(t0, T_REL))
        .fold(t_max, f32::min)
        .max(t_min)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raygen::whitted::{offset_segment, Leg, OffsetPolicy, Segment};
    use crate::triangle::tests::TestRng;
    use crate::triangle::{MollerTrumbore, Projected, TriangleSet, TriangleTest, Watertight};
    use crsh_core::{Hit, RayKind};
    use crsh_scene::stress::meshes::{self, TriMesh};
    use crsh_scene::{Camera, Material, SceneBuilder};

    /// A scene of the given meshes (one material, a camera looking at the origin).
    fn mesh_scene(name: &str, parts: &[TriMesh]) -> Scene {
        let mut b = SceneBuilder::new(name);
        let m = b.material(Material::default());
        b.camera(Camera {
            eye: Vec3::new(0.0, 0.5, 6.0),
            target: Vec3::ZERO,
            up: Vec3::Y,
            vfov_deg: 45.0,
            aspect: None,
        });
        for (i, part) in parts.iter().enumerate() {
            b.mesh(format!("part{i}"), &part.positions, None, &part.indices, m);
        }
        b.build(name).unwrap()
    }

    /// The inside of a box: 12 inward triangles, every vertex a concave corner.
    fn box_interior() -> Scene {
        mesh_scene(
            "box-interior",
            &[meshes::inward_box(
                Vec3::splat(-1.0),
                Vec3::new(1.0, 1.5, 2.0),
            )],
        )
    }

    /// An inward box (4×4 quads a face) around a bumpy sphere, a torus and a floor plane,
    /// moved by `shift` (large shifts stress the margins' coordinate terms).
    fn room(shift: DVec3) -> Scene {
        let mut walls = meshes::shared_edge_cube(3).map(|p| p * DVec3::new(3.0, 2.0, 2.5));
        for t in &mut walls.indices {
            t.swap(1, 2); // inward
        }
        let parts = [
            walls,
            meshes::bumpy_sphere(2, 0.1).scaled_translated(0.8, DVec3::new(-1.0, -0.9, 0.0)),
            meshes::torus(0.7, 0.25, 16, 8).scaled_translated(1.0, DVec3::new(1.3, -0.5, 0.3)),
            // A floor facing up, cutting the sphere.
            meshes::grid_plane(3).map(|p| DVec3::new(p.x * 2.0, -1.2, -p.y * 1.5)),
        ];
        let parts: Vec<TriMesh> = parts
            .into_iter()
            .map(|m| m.scaled_translated(1.0, shift))
            .collect();
        let name = if shift == DVec3::ZERO {
            "room".to_string()
        } else {
            format!("room+{shift}")
        };
        mesh_scene(&name, &parts)
    }

    fn sphere(levels: u32) -> Scene {
        mesh_scene("icosphere", &[meshes::icosphere(levels)])
    }

    /// The small scenes of the exactness and conservativeness tests.
    fn scenes() -> Vec<Scene> {
        let mut out: Vec<Scene> = crsh_scene::builtin::STATIC_NAMES
            .iter()
            .map(|n| crsh_scene::builtin::build(n).unwrap())
            .collect();
        out.push(crsh_scene::random::triangle_soup(300, 7).unwrap());
        out.push(crate::intersect::brute::tests::soup(21, 250));
        out.push(box_interior());
        out.push(room(DVec3::ZERO));
        out.push(sphere(2));
        out
    }

    // ---- (a) exactness -------------------------------------------------------------------

    /// Ericson's closest point on triangle `abc` to `p` (Real-Time Collision Detection 5.1.5).
    fn closest_on_triangle(p: DVec3, a: DVec3, b: DVec3, c: DVec3) -> DVec3 {
        let (ab, ac, ap) = (b - a, c - a, p - a);
        let (d1, d2) = (ab.dot(ap), ac.dot(ap));
        if d1 <= 0.0 && d2 <= 0.0 {
            return a;
        }
        let bp = p - b;
        let (d3, d4) = (ab.dot(bp), ac.dot(bp));
        if d3 >= 0.0 && d4 <= d3 {
            return b;
        }
        let vc = d1 * d4 - d3 * d2;
        if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
            return a + ab * (d1 / (d1 - d3));
        }
        let cp = p - c;
        let (d5, d6) = (ab.dot(cp), ac.dot(cp));
        if d6 >= 0.0 && d5 <= d6 {
            return c;
        }
        let vb = d5 * d2 - d1 * d6;
        if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
            return a + ac * (d2 / (d2 - d6));
        }
        let va = d3 * d6 - d5 * d4;
        if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
            return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
        }
        let denom = 1.0 / (va + vb + vc);
        a + ab * (vb * denom) + ac * (vc * denom)
    }

    /// The closest point of segment `a b` to `p`.
    fn closest_on_segment(p: DVec3, a: DVec3, b: DVec3) -> DVec3 {
        let ab = b - a;
        let len2 = ab.length_squared();
        if len2 == 0.0 {
            return a;
        }
        a + ab * (ab.dot(p - a) / len2).clamp(0.0, 1.0)
    }

    /// The clipped distance by another route, with the closest point: the closest point of
    /// the whole triangle when it is high enough, else (the constraint is active) the closest
    /// point of the segment where the triangle crosses height `h`.
    fn brute_clipped_point(c: DVec3, n: DVec3, h: f64, t: &[DVec3; 3]) -> (f64, DVec3) {
        let heights = t.map(|v| n.dot(v - c) - h);
        if heights.iter().all(|&x| x < 0.0) {
            return (f64::INFINITY, DVec3::ZERO);
        }
        let q = closest_on_triangle(c, t[0], t[1], t[2]);
        if n.dot(q - c) - h >= 0.0 {
            return ((q - c).length(), q);
        }
        let mut pts = Vec::new();
        for i in 0..3 {
            let j = (i + 1) % 3;
            let (hi, hj) = (heights[i], heights[j]);
            if hi == 0.0 {
                pts.push(t[i]);
            }
            if (hi > 0.0 && hj < 0.0) || (hi < 0.0 && hj > 0.0) {
                pts.push(t[i] + (t[j] - t[i]) * (hi / (hi - hj)));
            }
        }
        let mut best = ((q - c).length(), q);
        if pts.is_empty() {
            return best;
        }
        best.0 = f64::INFINITY;
        for a in &pts {
            for b in &pts {
                let x = closest_on_segment(c, *a, *b);
                let d = (x - c).length();
                if d < best.0 {
                    best = (d, x);
                }
            }
        }
        best
    }

    fn brute_clipped(c: DVec3, n: DVec3, h: f64, t: &[DVec3; 3]) -> f64 {
        brute_clipped_point(c, n, h, t).0
    }

    /// The point of the geometry that limits each site's radius (`None`: infinite or zero).
    fn witnesses(scene: &Scene, sites: &[Site]) -> Vec<Option<DVec3>> {
        let tris: Vec<(u32, [DVec3; 3])> = (0..scene.triangle_count())
            .filter(|&t| !scene.is_degenerate(t))
            .map(|t| (t as u32, scene.triangle(t).map(|v| v.as_dvec3())))
            .collect();
        sites
            .par_iter()
            .map(|s| {
                if s.normal == DVec3::ZERO {
                    return None;
                }
                let (d, q) = tris
                    .iter()
                    .filter(|(id, _)| *id != s.tri)
                    .map(|(_, t)| brute_clipped_point(s.centre, s.normal, s.h, t))
                    .fold(
                        (f64::INFINITY, DVec3::ZERO),
                        |a, b| if b.0 < a.0 { b } else { a },
                    );
                d.is_finite().then_some(q)
            })
            .collect()
    }

    /// O(N²): every site against every triangle (but its own and those of zero area).
    fn brute_radii(scene: &Scene, sites: &[Site]) -> Vec<f64> {
        let tris: Vec<(u32, [DVec3; 3])> = (0..scene.triangle_count())
            .filter(|&t| !scene.is_degenerate(t))
            .map(|t| (t as u32, scene.triangle(t).map(|v| v.as_dvec3())))
            .collect();
        sites
            .par_iter()
            .map(|s| {
                if s.normal == DVec3::ZERO {
                    return 0.0;
                }
                tris.iter()
                    .filter(|(id, _)| *id != s.tri)
                    .map(|(_, t)| brute_clipped(s.centre, s.normal, s.h, t))
                    .fold(f64::INFINITY, f64::min)
            })
            .collect()
    }

    #[test]
    fn radii_are_the_exact_clipped_distances() {
        for scene in scenes() {
            for kind in [SetKind::Center, SetKind::Vertex, SetKind::Median] {
                let s = sites(&scene, kind);
                let fast = exact_radii(&scene, &s);
                let brute = brute_radii(&scene, &s);
                let (mut finite, mut infinite) = (0, 0);
                for (i, (&a, &b)) in fast.iter().zip(&brute).enumerate() {
                    if a.is_infinite() || b.is_infinite() {
                        assert_eq!(a, b, "{} {} site {i}: {:?}", scene.name, kind.name(), s[i]);
                        infinite += 1;
                    } else {
                        assert!(
                            (a - b).abs() <= 1e-9 * a.max(b),
                            "{} {} site {i}: bvh {a} brute {b} ({:?})",
                            scene.name,
                            kind.name(),
                            s[i]
                        );
                        finite += 1;
                    }
                }
                println!(
                    "{}: {} {} sites, {finite} finite, {infinite} infinite",
                    scene.name,
                    kind.name(),
                    s.len()
                );
                // The set keeps the same radii, record for record.
                let set = HemisphereSet::build(&scene, kind);
                assert_eq!(set.exact_radii(), &fast[..]);
                assert_eq!(set.records().len(), s.len());
            }
        }
    }

    #[test]
    fn concave_corners_give_zero_vertex_hemispheres() {
        let scene = box_interior();
        let vertex = HemisphereSet::build(&scene, SetKind::Vertex);
        let s = sites(&scene, SetKind::Vertex);
        for (i, (rec, &r)) in vertex
            .records()
            .iter()
            .zip(vertex.exact_radii())
            .enumerate()
        {
            // A wall rising at 90° bounds a corner hemisphere at exactly h.
            assert!(r <= 1.0001 * s[i].h, "site {i}: radius {r}, h {}", s[i].h);
            assert_eq!(rec[3], 0.0, "site {i}");
        }
        assert_eq!(vertex.summary().zero_fraction, 1.0);
        // Centroids and medians sit away from the corners.
        for kind in [SetKind::Center, SetKind::Median] {
            let set = HemisphereSet::build(&scene, kind);
            assert!(set.records().iter().all(|r| r[3] > 0.05), "{}", kind.name());
        }
    }

    #[test]
    fn records_are_lifted_and_shrunk_subsets() {
        for scene in [room(DVec3::ZERO), room(DVec3::new(1e3, -2e3, 5e2))] {
            let s = sites(&scene, SetKind::Median);
            let set = HemisphereSet::build(&scene, SetKind::Median);
            for ((site, rec), &r) in s.iter().zip(set.records()).zip(set.exact_radii()) {
                if rec[3] == 0.0 {
                    continue;
                }
                let cs = DVec3::new(rec[0] as f64, rec[1] as f64, rec[2] as f64);
                // Above c's plane by more than h, and the stored ball inside the exact one.
                assert!(site.normal.dot(cs - site.centre) > site.h);
                if rec[3] != INFINITE_RADIUS {
                    assert!((cs - site.centre).length() + rec[3] as f64 <= r);
                } else {
                    assert!(r.is_infinite());
                }
            }
        }
    }

    #[test]
    fn polygons_group_planar_neighbours() {
        let count = |scene: &Scene| {
            let set = HemisphereSet::build(scene, SetKind::Polygon);
            assert_eq!(set.triangle_index().len(), scene.triangle_count());
            assert_eq!(
                set.bytes(),
                4 * scene.triangle_count() + 16 * set.records().len()
            );
            set.records().len()
        };
        let plane = mesh_scene("plane", &[meshes::grid_plane(4)]);
        assert_eq!(count(&plane), 1);
        // Nothing above a lone plane; the summary counts the one record for 32 triangles.
        let sum = HemisphereSet::build(&plane, SetKind::Polygon).summary();
        assert_eq!((sum.hemispheres, sum.infinite_fraction), (1, 1.0));
        assert_eq!(
            count(&mesh_scene("cube", &[meshes::shared_edge_cube(2)])),
            6
        );
        assert_eq!(count(&sphere(1)), 80);
        // Each triangle gets its polygon's largest centroid hemisphere, with its normal.
        for scene in [
            room(DVec3::ZERO),
            crsh_scene::builtin::build("office-boxes").unwrap(),
        ] {
            let center = HemisphereSet::build(&scene, SetKind::Center);
            let poly = HemisphereSet::build(&scene, SetKind::Polygon);
            assert!(poly.records().len() < scene.triangle_count());
            for t in 0..scene.triangle_count() as u32 {
                let own = center.hemispheres(t)[0];
                let used = poly.hemispheres(t)[0];
                assert!(used[3] >= own[3]);
                let donor = (0..scene.triangle_count() as u32)
                    .find(|&u| poly.slot(u) == poly.slot(t) && center.hemispheres(u)[0] == used)
                    .expect("a member's own hemisphere");
                assert_eq!(poly.normal(t), center.normal(donor));
                let sin = poly.normal(t).cross(center.normal(t)).length();
                assert!(sin < 2e-4 && poly.normal(t).dot(center.normal(t)) > 0.0);
            }
            println!("{}: {}", scene.name, poly.summary());
        }
    }

    #[test]
    fn names_sizes_and_layout() {
        for kind in SetKind::ALL {
            assert_eq!(SetKind::from_name(kind.name()), Some(kind));
        }
        assert_eq!(SET_NAMES, SetKind::ALL.map(|k| k.name()));
        assert_eq!(SetKind::from_name("sphere"), None);
        let scene = room(DVec3::ZERO);
        let n = scene.triangle_count();
        for (kind, bytes) in [
            (SetKind::Center, 16),
            (SetKind::Vertex, 48),
            (SetKind::Median, 64),
        ] {
            let set = HemisphereSet::build(&scene, kind);
            assert_eq!(set.bytes(), bytes * n);
            assert_eq!(set.normal_bytes(), 16 * n);
            assert!(set.triangle_index().is_empty());
            assert_eq!(set.hemispheres(3).len(), kind.per_slot());
            assert!(set.hemispheres(n as u32).is_empty());
            let sum = set.summary();
            assert_eq!(sum.hemispheres, kind.per_slot() * n);
            assert!(sum.mean_finite_radius_rel > 0.0 && sum.mean_finite_radius_rel < 1.0);
            println!("{sum}");
        }
        // A ray of an unknown triangle is left alone.
        let ray = test_ray(Vec3::ZERO, Vec3::Y, 0.5, 9.0);
        let set = HemisphereSet::build(&scene, SetKind::Center);
        assert_eq!(set.offset_t_min(u32::MAX, &ray), 0.5);
        assert_eq!(set.cut_t_max(n as u32, &ray), 9.0);
    }

    #[test]
    fn query_on_a_floor_under_a_ceiling() {
        // A floor quad at y = 0 facing up, a ceiling quad at y = 1 facing down.
        let quad = |y: f32, flip: bool| {
            let mut m = TriMesh {
                positions: [[-2.0, -2.0], [2.0, -2.0], [2.0, 2.0], [-2.0, 2.0]]
                    .map(|[x, z]| Vec3::new(x, y, z))
                    .to_vec(),
                indices: vec![[0, 2, 1], [0, 3, 2]],
            };
            if flip {
                m.indices.iter_mut().for_each(|t| t.swap(1, 2));
            }
            m
        };
        let scene = mesh_scene("floor", &[quad(0.0, false), quad(1.0, true)]);
        assert!(scene.triangle(0)[0].y == 0.0);
        let set = HemisphereSet::build(&scene, SetKind::Center);
        assert_eq!(set.normal(0), Vec3::Y);
        let [_, a, _, b] = set.hemispheres(0)[0];
        assert!(a > 0.0 && a < 1e-5, "lifted centre y {a}");
        assert!(b > 0.999 && b < 1.0, "radius {b}");
        let g = scene.triangle(0).iter().copied().sum::<Vec3>() / 3.0;
        // Straight up from the floor's centroid, just off the surface: offset to ~1.
        let up = test_ray(g, Vec3::Y, 1e-4, f32::INFINITY);
        let t = set.offset_t_min(0, &up);
        assert!(t > 0.999 && t < 1.0, "{t}");
        // Starting below the lifted base (on the plane): no offset.
        let flat = test_ray(g, Vec3::Y, 0.0, f32::INFINITY);
        assert_eq!(set.offset_t_min(0, &flat), 0.0);
        // Going down from inside: offset to where it leaves through the (lifted) base.
        let down = test_ray(g + Vec3::Y * 1e-4, -Vec3::Y, 0.0, f32::INFINITY);
        let t = set.offset_t_min(0, &down);
        assert!(t > 9e-5 && t < 1e-4, "{t}");
        // Leaving through the back (from below the floor): no offset.
        let back = test_ray(g - Vec3::Y * 1e-4, -Vec3::Y, 0.0, f32::INFINITY);
        assert_eq!(set.offset_t_min(0, &back), 0.0);
        // A ray that ends inside the hemisphere before leaving it: clamped to t_max.
        let short = test_ray(g, Vec3::Y, 1e-4, 0.5);
        assert_eq!(set.offset_t_min(0, &short), 0.5);
        // A shadow ray from a light just under the ceiling to the floor: cut where it enters.
        let light = g + Vec3::Y * 0.9;
        let shadow = test_ray(light, -Vec3::Y, 0.0, 0.9 - 1e-4);
        let cut = set.cut_t_max(0, &shadow);
        assert!(cut <= shadow.t_min + 1e-5, "{cut}");
        // ... and from above the ceiling's height it is cut at the sphere's top.
        let high = test_ray(g + Vec3::Y * 3.0, -Vec3::Y, 0.0, 3.0 - 1e-4);
        let cut = set.cut_t_max(0, &high);
        assert!(cut > 2.0 && cut < 2.002, "{cut}");
        // The interval of a ray in the plane: empty (the half-space is open).
        let (t0, t1) = hemisphere_interval(set.hemispheres(0)[0], Vec3::Y, g, Vec3::X);
        assert!(t0 >= t1);
    }

    #[test]
    fn infinite_radius_is_encoded_and_skips_the_whole_ray() {
        let scene = sphere(1);
        let set = HemisphereSet::build(&scene, SetKind::Center);
        assert!(set.records().iter().all(|r| r[3] == INFINITE_RADIUS));
        assert_eq!(set.summary().infinite_fraction, 1.0);
        let [a, b, c] = scene.triangle(5);
        let g = (a + b + c) / 3.0;
        let n = set.normal(5);
        let ray = test_ray(
            g + n * 1e-4,
            (n + (b - a).normalize()).normalize(),
            0.0,
            f32::INFINITY,
        );
        assert_eq!(set.offset_t_min(5, &ray), f32::INFINITY);
        let bounded = test_ray(g + n * 1e-4, n, 0.0, 7.0);
        assert_eq!(set.offset_t_min(5, &bounded), 7.0);
        // From a light far outside, the shadow ray's whole segment above the plane goes.
        let l = g + n * 50.0;
        let shadow = test_ray(l, -n, 1e-3, 50.0 - 1e-4);
        let cut = set.cut_t_max(5, &shadow);
        assert!(cut <= shadow.t_min, "{cut}");
        // Invalid rays are left alone.
        let bad = test_ray(Vec3::NAN, n, 0.0, 1.0);
        assert_eq!(set.offset_t_min(5, &bad), 0.0);
        assert_eq!(set.cut_t_max(5, &bad), 1.0);
        let zero = test_ray(g + n * 1e-4, Vec3::ZERO, 0.0, 1.0);
        assert_eq!(set.offset_t_min(5, &zero), 0.0);
    }

    // ---- (b) conservativeness --------------------------------------------------------------

    fn test_ray(origin: Vec3, dir: Vec3, t_min: f32, t_max: f32) -> Ray {
        crate::intersect::brute::tests::test_ray(origin, dir, t_min, t_max, 0)
    }

    fn seg_ray(s: &Segment, kind: RayKind) -> Ray {
        let mut r = test_ray(s.origin, s.dir, s.t_min, s.t_max);
        r.kind = kind as u32;
        r
    }

    /// Closest hit (by [`Hit::closer_than`]) and whether anything is hit in `(t_min, t_max)`:
    /// every triangle, in id order (the brute-force intersector's answer).
    fn brute_hits<T: TriangleTest>(
        set: &TriangleSet<T>,
        ray: &Ray,
        t_min: f32,
        t_max: f32,
    ) -> (Hit, bool) {
        let r = T::ray_of(ray);
        let mut best = Hit::MISS;
        let mut any = false;
        for (i, tri) in set.triangles().iter().enumerate() {
            if let Some(h) = T::hit(tri, &r, t_min, t_max, i as u32) {
                any = true;
                if h.closer_than(&best) {
                    best = h;
                }
            }
        }
        (best, any)
    }

    /// Möller-Trumbore in `f64` without tolerances: the exact-enough `t` of the ray on `t`.
    fn exact_hit(t: [DVec3; 3], o: DVec3, d: DVec3) -> Option<f64> {
        let (e1, e2) = (t[1] - t[0], t[2] - t[0]);
        let p = d.cross(e2);
        let det = e1.dot(p);
        if det == 0.0 {
            return None;
        }
        let s = o - t[0];
        let u = s.dot(p) / det;
        let q = s.cross(e1);
        let v = d.dot(q) / det;
        (u >= 0.0 && v >= 0.0 && u + v <= 1.0).then(|| e2.dot(q) / det)
    }

    fn bits(h: &Hit) -> (u32, u32, u32, u32) {
        (h.t.to_bits(), h.tri, h.u.to_bits(), h.v.to_bits())
    }

    /// The three tests' prepared triangles.
    struct Tests {
        mt: TriangleSet<MollerTrumbore>,
        wt: TriangleSet<Watertight>,
        pj: TriangleSet<Projected>,
    }

    impl Tests {
        fn new(scene: &Scene) -> Tests {
            Tests {
                mt: TriangleSet::new(scene),
                wt: TriangleSet::new(scene),
                pj: TriangleSet::new(scene),
            }
        }

        /// What the tests hit in the skipped part `[lo, hi]` of `ray`: the smallest sine of
        /// the angle between the ray and a triangle hit there (`+∞` when none), and whether
        /// one of those triangles is hit there in `f64` too (a real violation, not the `f32`
        /// tests' rounding).
        fn skipped(&self, scene: &Scene, ray: &Ray, lo: f32, hi: f32) -> (f32, bool) {
            fn hits<T: TriangleTest>(s: &TriangleSet<T>, ray: &Ray, lo: f32, hi: f32) -> Vec<u32> {
                let r = T::ray_of(ray);
                (0..s.len() as u32)
                    .filter(|&i| {
                        T::intersect(
                            &s.triangles()[i as usize],
                            &r,
                            f32::NEG_INFINITY,
                            f32::INFINITY,
                        )
                        .is_some_and(|(t, _, _)| t >= lo && t <= hi)
                    })
                    .collect()
            }
            let mut ids = hits(&self.mt, ray, lo, hi);
            ids.extend(hits(&self.wt, ray, lo, hi));
            ids.extend(hits(&self.pj, ray, lo, hi));
            let (o, d) = (ray.origin.as_dvec3(), ray.dir.as_dvec3());
            let tol = 1e-9 * (1.0 + hi.abs() as f64);
            let mut sine = f32::INFINITY;
            let mut real = false;
            for i in ids {
                let t = scene.triangle(i as usize);
                let n = (t[1] - t[0]).cross(t[2] - t[0]).normalize_or_zero();
                sine = sine.min(n.dot(ray.dir.normalize()).abs());
                if let Some(t64) = exact_hit(t.map(|v| v.as_dvec3()), o, d) {
                    real |= t64 > lo as f64 + tol && t64 < hi as f64 - tol;
                }
            }
            (sine, real)
        }

        /// Whether the three tests give the same closest hit and any-hit answer on
        /// `(a_min, a_max)` and on `(b_min, b_max)`; an empty interval is a miss.
        fn same(&self, ray: &Ray, a: (f32, f32), b: (f32, f32)) -> bool {
            fn one<T: TriangleTest>(
                s: &TriangleSet<T>,
                ray: &Ray,
                a: (f32, f32),
                b: (f32, f32),
            ) -> bool {
                let run = |(lo, hi): (f32, f32)| {
                    if lo < hi {
                        brute_hits(s, ray, lo, hi)
                    } else {
                        (Hit::MISS, false)
                    }
                };
                let (ha, aa) = run(a);
                let (hb, ab) = run(b);
                bits(&ha) == bits(&hb) && aa == ab
            }
            one(&self.mt, ray, a, b) && one(&self.wt, ray, a, b) && one(&self.pj, ray, a, b)
        }
    }

    /// A cosine-weighted direction about the unit `n`.
    fn cosine_dir(rng: &mut TestRng, n: Vec3) -> Vec3 {
        let (u1, u2) = (rng.f32(), rng.f32());
        let (r, phi) = (u1.sqrt(), std::f32::consts::TAU * u2);
        let (t, b) = n.any_orthonormal_pair();
        (t * (r * phi.cos()) + b * (r * phi.sin()) + n * (1.0 - u1).max(0.0).sqrt()).normalize()
    }

    /// A direction at a grazing angle (sine 1e-4 .. 1e-2) above the unit `n`.
    fn grazing_dir(rng: &mut TestRng, n: Vec3) -> Vec3 {
        let (t, b) = n.any_orthonormal_pair();
        let phi = std::f32::consts::TAU * rng.f32();
        let s = 10f32.powf(rng.range(-4.0, -2.0));
        (t * phi.cos() + b * phi.sin() + n * s).normalize()
    }

    /// A point on triangle `t` as a renderer computes it, uniform or near an edge or corner.
    fn surface_point(rng: &mut TestRng, t: [Vec3; 3]) -> Vec3 {
        let (mut u, mut v) = (rng.f32(), rng.f32());
        if u + v > 1.0 {
            (u, v) = (1.0 - u, 1.0 - v);
        }
        match rng.next_u64() % 4 {
            0 => u = 10f32.powf(rng.range(-7.0, -2.0)),
            1 => {
                u = 10f32.powf(rng.range(-7.0, -2.0));
                v = 10f32.powf(rng.range(-7.0, -2.0));
            }
            2 => {
                let k = rng.next_u64() % 3;
                (u, v) = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0)][k as usize];
            }
            _ => {}
        }
        let w = 1.0 - u - v;
        t[0] * w + t[1] * u + t[2] * v
    }

    /// What the conservativeness check found.
    #[derive(Debug, Default)]
    struct Tally {
        rays: u64,
        offset: u64,
        ended: u64,
        shadow: u64,
        cut: u64,
        emptied: u64,
        mismatches: Vec<String>,
        /// Per mismatch, the smallest sine of the angle between the ray and a triangle it
        /// hits in the skipped part (how grazing the lost hit is).
        lost_sines: Vec<f32>,
        /// Mismatches whose skipped part holds a hit in `f64` too.
        real: u64,
    }

    impl Tally {
        fn add(&mut self, o: Tally) {
            self.rays += o.rays;
            self.offset += o.offset;
            self.ended += o.ended;
            self.shadow += o.shadow;
            self.cut += o.cut;
            self.emptied += o.emptied;
            self.mismatches.extend(o.mismatches);
            self.lost_sines.extend(o.lost_sines);
            self.real += o.real;
        }
    }

    /// One scene's comparisons: an interval a set moved against the original one.
    struct Check<'a> {
        scene: &'a Scene,
        tests: Tests,
    }

    impl Check<'_> {
        fn new(scene: &Scene) -> Check<'_> {
            Check {
                scene,
                tests: Tests::new(scene),
            }
        }

        /// A ray leaving `tri`: counts it, and a mismatch when `offset_t_min` changes a hit.
        fn extension(
            &self,
            set: &HemisphereSet,
            tri: u32,
            ray: &Ray,
            policy: &OffsetPolicy,
            tally: &mut Tally,
        ) {
            tally.rays += 1;
            let t_new = set.offset_t_min(tri, ray);
            assert!(t_new >= ray.t_min || ray.t_min >= ray.t_max);
            if t_new == ray.t_min {
                return;
            }
            tally.offset += 1;
            tally.ended += (t_new >= ray.t_max) as u64;
            if !self
                .tests
                .same(ray, (ray.t_min, ray.t_max), (t_new, ray.t_max))
            {
                let what = format!("tri {tri} {ray:?} offset {t_new}");
                self.mismatch(set, policy, ray, (ray.t_min, t_new), what, tally);
            }
        }

        /// A shadow segment ending on `tri`: counts it, and a mismatch when `cut_t_max`
        /// changes a hit.
        fn shadow(
            &self,
            set: &HemisphereSet,
            tri: u32,
            ray: &Ray,
            policy: &OffsetPolicy,
            tally: &mut Tally,
        ) {
            tally.shadow += 1;
            let t_new = set.cut_t_max(tri, ray);
            assert!(t_new <= ray.t_max);
            if t_new == ray.t_max {
                return;
            }
            tally.cut += 1;
            tally.emptied += (t_new <= ray.t_min) as u64;
            if !self
                .tests
                .same(ray, (ray.t_min, ray.t_max), (ray.t_min, t_new))
            {
                let what = format!("shadow tri {tri} {ray:?} cut {t_new}");
                self.mismatch(set, policy, ray, (t_new, ray.t_max), what, tally);
            }
        }

        fn mismatch(
            &self,
            set: &HemisphereSet,
            policy: &OffsetPolicy,
            ray: &Ray,
            (lo, hi): (f32, f32),
            what: String,
            tally: &mut Tally,
        ) {
            let (sine, real) = self.tests.skipped(self.scene, ray, lo, hi);
            tally.lost_sines.push(sine);
            tally.real += real as u64;
            tally.mismatches.push(format!(
                "{} {} {} {what}",
                self.scene.name,
                set.kind().name(),
                policy.name()
            ));
        }
    }

    fn policies(scene: &Scene) -> [OffsetPolicy; 4] {
        let off = 1e-5 * scene.bounds.diagonal();
        [
            OffsetPolicy::Normal(off),
            OffsetPolicy::Scaled(off),
            OffsetPolicy::Fixed(1e-4),
            OffsetPolicy::Wachter,
        ]
    }

    /// Random rays leaving random surface points (every policy, cosine-weighted and grazing
    /// directions, front and back, unbounded and towards a light) and shadow segments from
    /// lights: the offset / cut interval must give the same hits as the original one.
    fn check_conservative(
        scene: &Scene,
        sets: &[HemisphereSet],
        points: usize,
        seed: u64,
    ) -> Tally {
        let check = Check::new(scene);
        let b = scene.bounds;
        (0..points)
            .into_par_iter()
            .map(|k| {
                let mut rng = TestRng(seed ^ (k as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1);
                let mut tally = Tally::default();
                let tri = (rng.next_u64() % scene.triangle_count() as u64) as u32;
                let t = scene.triangle(tri as usize);
                let face = (t[1] - t[0]).cross(t[2] - t[0]).normalize_or_zero();
                if face == Vec3::ZERO {
                    return tally;
                }
                let p = surface_point(&mut rng, t);
                // Seen from behind one time in six: the surface's normal is flipped.
                let geo = if rng.next_u64().is_multiple_of(6) {
                    -face
                } else {
                    face
                };
                let mut dirs = vec![
                    cosine_dir(&mut rng, geo),
                    cosine_dir(&mut rng, geo),
                    grazing_dir(&mut rng, geo),
                ];
                if rng.next_u64().is_multiple_of(4) {
                    dirs.push(cosine_dir(&mut rng, -geo)); // leaving through the back
                }
                let light = b.min + (b.max - b.min) * rng.vec3(-0.1, 1.1);
                for policy in policies(scene) {
                    let mut legs: Vec<Leg> = dirs.iter().map(|&d| Leg::Along(d)).collect();
                    legs.push(Leg::To(light));
                    for leg in legs {
                        let Some(s) = offset_segment(p, geo, leg, &policy) else {
                            continue;
                        };
                        let ray = seg_ray(&s, RayKind::Reflection);
                        for set in sets {
                            check.extension(set, tri, &ray, &policy, &mut tally);
                        }
                    }
                    // A shadow segment from the light to the point (front side only, as
                    // `cull_backfacing` makes them).
                    if (light - p).dot(geo) <= 0.0 {
                        continue;
                    }
                    let Some(s) = offset_segment(p, geo, Leg::From(light), &policy) else {
                        continue;
                    };
                    let ray = seg_ray(&s, RayKind::Shadow);
                    for set in sets {
                        check.shadow(set, tri, &ray, &policy, &mut tally);
                    }
                }
                tally
            })
            .reduce(Tally::default, |mut a, b| {
                a.add(b);
                a
            })
    }

    /// Rays aimed at the geometry that limits each hemisphere, where the returned `t` lies on
    /// the hemisphere's boundary and rounding decides: from the site itself and from points
    /// of the triangle near it (for `polygon`, from points of the polygon's triangles), towards
    /// the limiting point with jitter from 0 to 1e-2 rad, under every policy; and shadow
    /// segments from lights beyond the limiting point.
    fn check_targeted(scene: &Scene, set: &HemisphereSet, seed: u64) -> Tally {
        let check = Check::new(scene);
        let polygon = set.kind() == SetKind::Polygon;
        let s = sites(scene, if polygon { SetKind::Center } else { set.kind() });
        // Polygon: the triangles each donor serves.
        let mut served: Vec<Vec<u32>> = vec![Vec::new(); scene.triangle_count()];
        if polygon {
            for t in 0..scene.triangle_count() as u32 {
                let donor = set.donors()[set.slot(t).unwrap()];
                served[donor as usize].push(t);
            }
        }
        // At most `HEMI_SITES` sites (default 200), evenly spread.
        let most: usize = std::env::var("HEMI_SITES")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(200);
        let stride = s.len().div_ceil(most).max(1);
        let s: Vec<Site> = s.into_iter().step_by(stride).collect();
        let w = witnesses(scene, &s);
        (0..s.len())
            .into_par_iter()
            .filter_map(|i| w[i].map(|q| (i, q)))
            .map(|(i, q)| {
                let mut rng = TestRng(seed ^ (i as u64 + 1).wrapping_mul(0x9e37_79b9_7f4a_7c15));
                let mut tally = Tally::default();
                let site = s[i];
                let users: Vec<u32> = if polygon {
                    (0..3)
                        .filter_map(|_| {
                            let list = &served[site.tri as usize];
                            (!list.is_empty())
                                .then(|| list[(rng.next_u64() % list.len() as u64) as usize])
                        })
                        .collect()
                } else {
                    vec![site.tri]
                };
                let q32 = q.as_vec3();
                for tri in users {
                    let t = scene.triangle(tri as usize);
                    let geo = (t[1] - t[0]).cross(t[2] - t[0]).normalize_or_zero();
                    if geo == Vec3::ZERO {
                        continue;
                    }
                    let c = site.centre.as_vec3();
                    let mut starts = Vec::new();
                    if tri == site.tri {
                        starts.push(c);
                    }
                    for _ in 0..3 {
                        let p = surface_point(&mut rng, t);
                        let lambda = if tri == site.tri {
                            10f32.powf(rng.range(-4.0, 0.0))
                        } else {
                            1.0
                        };
                        starts.push(c + (p - c) * lambda);
                    }
                    for p in starts {
                        for jitter in [0.0, 1e-6, 1e-4, 1e-2] {
                            let d = ((q32 - p).normalize_or_zero() + rng.unit() * jitter)
                                .normalize_or_zero();
                            let light = q32 + (q32 - p) * rng.range(0.1, 3.0) + rng.unit() * jitter;
                            if d.dot(geo) <= 0.0 {
                                continue;
                            }
                            for policy in policies(scene) {
                                if let Some(seg) = offset_segment(p, geo, Leg::Along(d), &policy) {
                                    let ray = seg_ray(&seg, RayKind::Ao);
                                    check.extension(set, tri, &ray, &policy, &mut tally);
                                }
                                if (light - p).dot(geo) <= 0.0 {
                                    continue;
                                }
                                if let Some(seg) = offset_segment(p, geo, Leg::From(light), &policy)
                                {
                                    let ray = seg_ray(&seg, RayKind::Shadow);
                                    check.shadow(set, tri, &ray, &policy, &mut tally);
                                }
                            }
                        }
                    }
                }
                tally
            })
            .reduce(Tally::default, |mut a, b| {
                a.add(b);
                a
            })
    }

    #[test]
    fn offsets_keep_hits_at_the_hemisphere_boundary() {
        let mut scenes = scenes();
        scenes.push(room(DVec3::new(1e3, -2e3, 5e2)));
        let mut total = Tally::default();
        for (i, scene) in scenes.iter().enumerate() {
            for set in all_sets(scene) {
                let tally = check_targeted(scene, &set, 500 + i as u64);
                println!(
                    "{} {}: {} rays, {} offset, {} shadow, {} cut, {} mismatches",
                    scene.name,
                    set.kind().name(),
                    tally.rays,
                    tally.offset,
                    tally.shadow,
                    tally.cut,
                    tally.mismatches.len()
                );
                total.add(tally);
            }
        }
        for m in total.mismatches.iter().take(10) {
            println!("{m}");
        }
        println!(
            "{} rays, {} shadow rays, {} mismatches, sines of their lost hits: {:?}",
            total.rays,
            total.shadow,
            total.mismatches.len(),
            total.lost_sines
        );
        // In exact arithmetic nothing lies in a skipped part: every hit the f32 tests find
        // there is one they place there by rounding ...
        assert_eq!(total.real, 0, "hits inside a hemisphere");
        // ... which only a grazing hit's rounding can exceed the margins by (see the module
        // docs): a hit whose sine with the ray is ≥ 1e-3 is never lost or gained.
        assert!(
            total.lost_sines.iter().all(|&s| s < 1e-3),
            "{:?}",
            total.lost_sines
        );
        assert!(
            total.offset * 2 > total.rays && total.cut * 2 > total.shadow,
            "{total:?}"
        );
    }

    fn all_sets(scene: &Scene) -> Vec<HemisphereSet> {
        SetKind::ALL
            .iter()
            .map(|&k| HemisphereSet::build(scene, k))
            .collect()
    }

    #[test]
    fn offsets_never_change_a_hit() {
        let mut scenes = scenes();
        scenes.push(room(DVec3::new(1e3, -2e3, 5e2)));
        scenes.push(room(DVec3::new(3e4, 1e4, -2e4)));
        let mut total = Tally::default();
        for (i, scene) in scenes.iter().enumerate() {
            let sets = all_sets(scene);
            // `HEMI_POINTS` runs a longer search.
            let points = std::env::var("HEMI_POINTS")
                .ok()
                .and_then(|v| v.parse().ok())
                .unwrap_or(if scene.triangle_count() > 1500 {
                    150
                } else {
                    300
                });
            let tally = check_conservative(scene, &sets, points, 1000 + i as u64);
            println!(
                "{}: {} rays, {} offset ({} ended), {} shadow, {} cut ({} emptied), {} mismatches",
                scene.name,
                tally.rays,
                tally.offset,
                tally.ended,
                tally.shadow,
                tally.cut,
                tally.emptied,
                tally.mismatches.len()
            );
            total.add(tally);
        }
        for m in total.mismatches.iter().take(10) {
            println!("{m}");
        }
        assert!(
            total.mismatches.is_empty(),
            "{} mismatches",
            total.mismatches.len()
        );
        // Not vacuous: many rays were moved, some skipped, many shadow rays were cut.
        assert!(total.offset * 4 > total.rays, "{total:?}");
        assert!(total.ended > 0 && total.cut * 4 > total.shadow && total.emptied > 0);
    }

    #[test]
    fn the_check_catches_hemispheres_that_are_too_large() {
        // The same check with radii inflated by 30%: hits are lost, and it says so.
        let scene = room(DVec3::ZERO);
        let mut sets = vec![HemisphereSet::build(&scene, SetKind::Center)];
        for r in &mut sets[0].records {
            if r[3] != INFINITE_RADIUS {
                r[3] *= 1.3;
            }
        }
        let tally = check_conservative(&scene, &sets, 300, 77);
        assert!(!tally.mismatches.is_empty(), "{tally:?}");
    }

    // ---- (c) usefulness --------------------------------------------------------------------

    #[test]
    fn a_convex_sphere_ends_most_extension_rays() {
        let scene = sphere(3);
        let off = 1e-5 * scene.bounds.diagonal();
        for set in all_sets(&scene) {
            for policy in [
                OffsetPolicy::Normal(off),
                OffsetPolicy::Scaled(off),
                OffsetPolicy::Wachter,
            ] {
                let mut rng = TestRng(4242);
                let (mut rays, mut ended) = (0, 0);
                for _ in 0..2000 {
                    let tri = (rng.next_u64() % scene.triangle_count() as u64) as u32;
                    let t = scene.triangle(tri as usize);
                    let n = (t[1] - t[0]).cross(t[2] - t[0]).normalize();
                    let p = surface_point(&mut rng, t);
                    let d = cosine_dir(&mut rng, n);
                    let s = offset_segment(p, n, Leg::Along(d), &policy).unwrap();
                    let ray = seg_ray(&s, RayKind::Diffuse);
                    rays += 1;
                    if set.offset_t_min(tri, &ray) >= ray.t_max {
                        ended += 1;
                    }
                }
                let frac = ended as f64 / rays as f64;
                println!(
                    "sphere {} {}: {:.1}% of rays end",
                    set.kind().name(),
                    policy.name(),
                    100.0 * frac
                );
                assert!(
                    frac > 0.9,
                    "{} {}: {frac}",
                    set.kind().name(),
                    policy.name()
                );
            }
        }
    }

    // ---- (d) determinism -------------------------------------------------------------------

    #[test]
    fn tables_do_not_depend_on_the_thread_count() {
        for scene in [
            room(DVec3::ZERO),
            crsh_scene::builtin::build("office-boxes").unwrap(),
        ] {
            for kind in SetKind::ALL {
                let build = |threads| {
                    crate::with_threads(threads, || HemisphereSet::build(&scene, kind)).unwrap()
                };
                let (mut one, two) = (build(1), build(2));
                one.build_ms = two.build_ms;
                let exact_bits = |s: &HemisphereSet| {
                    s.exact_radii()
                        .iter()
                        .map(|r| r.to_bits())
                        .collect::<Vec<_>>()
                };
                assert_eq!(exact_bits(&one), exact_bits(&two));
                let rec_bits = |s: &HemisphereSet| {
                    s.records()
                        .iter()
                        .flat_map(|r| r.map(f32::to_bits))
                        .collect::<Vec<_>>()
                };
                assert_eq!(rec_bits(&one), rec_bits(&two));
                assert_eq!(one, two, "{} {}", scene.name, kind.name());
            }
        }
    }

    // ---- measurements ----------------------------------------------------------------------

    /// Build time and memory per set on the shared scenes (`cargo test --release -p crsh-cpu
    /// --lib origin_offset -- --ignored --nocapture`).
    #[test]
    #[ignore]
    fn measure_shared_scenes() {
        for path in [
            "../../../shared/scenes/bunny/bunny.toml",
            "../../../shared/scenes/dragon/dragon.toml",
            "../../../shared/scenes/sponza/sponza.toml",
        ] {
            let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(path);
            if !path.exists() {
                println!("{}: not found", path.display());
                continue;
            }
            let scene = crsh_scene::load_path(&path).unwrap();
            println!("{}", scene.summary());
            for kind in SetKind::ALL {
                let set = HemisphereSet::build(&scene, kind);
                println!("  {}", set.summary());
            }
        }
    }
}
