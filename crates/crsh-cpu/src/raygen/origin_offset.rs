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
//! side of the returned `t` it lands on is rounding noise. The tests aim 4.2 million rays at the
//! very points that limit the hemispheres: 6 answers differ, all hits at `sin θ ≤ 2.1e-4`, none
//! of them a hit inside the hemisphere in `f64`; with every margin at 0 the same rays give
//! thousands of differences, head-on hits among them. Random rays (3.2 million, grazing ones
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
use crsh_core::Ray;
use crsh_scene::Scene;
use obvhs::bvh2::builder::build_bvh2_from_tris;
use obvhs::bvh2::node::Bvh2Node;
use obvhs::bvh2::Bvh2;
use obvhs::triangle::Triangle;
use obvhs::BvhBuildParams;
use rayon::prelude::*;

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
        let obvhs_tris: Vec<Triangle> = tris32
            .iter()
            .map(|&[a, b, c]| Triangle {
                v0: a.into(),
                v1: b.into(),
                v2: c.into(),
            })
            .collect();
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

/// The largest `f32` not above `x` (for `x ≥ 0`).
fn f32_down(x: f64) -> f32 {
    let f = x as f32;
    if f as f64 > x {
        f32::from_bits(f.to_bits() - 1)
    } else {
        f
    }
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
    /// Fraction of hemispheres whose stored radius is 0.
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
    /// relative to the scene's diagonal, memory, build time.
    pub fn summary(&self) -> SetSummary {
        let n = self.records.len();
        let zero = self.records.iter().filter(|r| r[3] == 0.0).count();
        let infinite = self
            .records
            .iter()
            .filter(|r| r[3] == INFINITE_RADIUS)
            .count();
        let finite_sum: f64 = self
            .records
            .iter()
            .filter(|r| r[3] != INFINITE_RADIUS)
            .map(|r| r[3] as f64)
            .sum();
        let frac = |k: usize| if n == 0 { 0.0 } else { k as f64 / n as f64 };
        let finite = n - infinite;
        SetSummary {
            kind: self.kind.name(),
            triangles: self.triangles,
            slots: self.normals.len(),
            hemispheres: n,
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
    let mut best = t_min;
    for &rec in records {
        let (t0, t1) = hemisphere_interval(rec, normal, o, d);
        if t0 <= t_min && t_min < t1 {
            let t = if t1.is_finite() {
                t1 - T_REL * t1.abs()
            } else {
                t1
            };
            best = best.max(t);
        }
    }
    best.min(t_max)
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
    let mut best = t_max;
    for &rec in records {
        let (t0, t1) = hemisphere_interval(rec, normal, o, d);
        if t0 < t_max && t_max <= t1 {
            let t = if t0.is_finite() {
                t0 + T_REL * t0.abs()
            } else {
                t0
            };
            best = best.min(t);
        }
    }
    best.max(t_min)
}
