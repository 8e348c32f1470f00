//! Minimal bounding spheres of scene geometry.
//!
//! The thesis culls whole meshes and single triangles against ray-space nodes with bounding
//! spheres (seed 000 §3.2.1, citing Welzl's algorithm as its ref. 10, and §3.2.8). Tighter
//! spheres mean fewer false candidates, so these are the *exact minimal* spheres:
//!
//! - [`min_sphere`]: Welzl's randomized algorithm ("Smallest enclosing disks (balls and
//!   ellipsoids)", 1991) in its iterative form: the recursion on the point set becomes one loop
//!   per support-set size (at most four nested loops in 3-D), so there is no recursion depth
//!   problem for any number of points; expected linear time after a deterministic shuffle
//!   (fixed seed, so the same input always gives the same sphere).
//! - [`triangle_sphere`]: the minimal sphere of a triangle in closed form (circumsphere for an
//!   acute triangle, longest-edge diametral sphere for a right or obtuse one).
//!
//! All arithmetic runs in `f64` on coordinates re-centred on the input's bounding box, and the
//! final radius is re-measured from the `f32` centre to every input point and rounded *up*, so
//! the returned sphere always contains every input point in `f32` (no tolerance needed by the
//! user), while being minimal up to rounding. Degenerate inputs (one point, coincident,
//! collinear or coplanar points) are handled: a support set that has no circumscribed sphere
//! falls back to the smallest sphere enclosing it.

use crsh_core::{f32_up, Sphere};
use glam::{DVec3, Vec3};

use crate::rng::SplitMix64;

/// Seed of the shuffle in [`min_sphere`] (fixed: the result depends only on the input).
const SHUFFLE_SEED: u64 = 0x5EED_0000_C0DE_0010;

/// Relative size below which a triangle or tetrahedron spanned by support points counts as
/// flat (collinear / coplanar): `|u×v| ≤ EPS·|u||v|`, `|u·(v×t)| ≤ EPS·|u||v||t|`.
const FLAT_EPS: f64 = 1e-10;

/// Containment slack of the inner loops, relative to the size of the input (only decides
/// whether a point triggers a basis change; the final radius is measured exactly).
const CONTAIN_EPS: f64 = 1e-10;

/// A ball during the computation, in re-centred `f64` coordinates.
#[derive(Clone, Copy, Debug)]
struct Ball {
    center: DVec3,
    radius: f64,
}

impl Ball {
    fn point(p: DVec3) -> Ball {
        Ball {
            center: p,
            radius: 0.0,
        }
    }

    /// The ball with segment `ab` as diameter.
    fn diametral(a: DVec3, b: DVec3) -> Ball {
        Ball {
            center: (a + b) * 0.5,
            radius: a.distance(b) * 0.5,
        }
    }

    fn contains(&self, p: DVec3, slack: f64) -> bool {
        self.center.distance(p) <= self.radius + slack
    }

    /// This ball grown (around the same centre) to contain all of `pts`.
    fn grown_to(self, pts: &[DVec3]) -> Ball {
        let r = pts
            .iter()
            .fold(self.radius, |r, p| r.max(self.center.distance(*p)));
        Ball {
            center: self.center,
            radius: r,
        }
    }
}

/// The smallest ball with `a`, `b`, `c` on its boundary (centre in their plane), or `None`
/// when they are (numerically) collinear.
fn circumball3(a: DVec3, b: DVec3, c: DVec3) -> Option<Ball> {
    let u = b - a;
    let v = c - a;
    let w = u.cross(v);
    let w2 = w.length_squared();
    if w2 <= (FLAT_EPS * FLAT_EPS) * u.length_squared() * v.length_squared() || w2 == 0.0 {
        return None;
    }
    // Circumcentre relative to a: (|u|² (v × w) + |v|² (w × u)) / (2 |w|²).
    let rel = (v.cross(w) * u.length_squared() + w.cross(u) * v.length_squared()) / (2.0 * w2);
    Some(Ball {
        center: a + rel,
        radius: rel.length(),
    })
}

/// The ball with `a`, `b`, `c`, `d` on its boundary, or `None` when they are (numerically)
/// coplanar.
fn circumball4(a: DVec3, b: DVec3, c: DVec3, d: DVec3) -> Option<Ball> {
    let u = b - a;
    let v = c - a;
    let t = d - a;
    let det = u.dot(v.cross(t));
    let scale = u.length() * v.length() * t.length();
    if det.abs() <= FLAT_EPS * scale || det == 0.0 {
        return None;
    }
    // Solve 2 [u v t]ᵀ x = (|u|², |v|², |t|²) by Cramer's rule.
    let rel = (v.cross(t) * u.length_squared()
        + t.cross(u) * v.length_squared()
        + u.cross(v) * t.length_squared())
        / (2.0 * det);
    Some(Ball {
        center: a + rel,
        radius: rel.length(),
    })
}

/// The smallest ball enclosing up to four points, by trying every support subset (used when a
/// support set is degenerate). Always returns a ball containing all of `pts`.
fn small_enclosing(pts: &[DVec3]) -> Ball {
    let n = pts.len();
    let mut best: Option<Ball> = None;
    let mut consider = |b: Ball| {
        let g = b.grown_to(pts);
        if best.is_none_or(|cur| g.radius < cur.radius) {
            best = Some(g);
        }
    };
    consider(Ball::point(pts[0]));
    for i in 0..n {
        for j in i + 1..n {
            consider(Ball::diametral(pts[i], pts[j]));
            for k in j + 1..n {
                if let Some(b) = circumball3(pts[i], pts[j], pts[k]) {
                    consider(b);
                }
                for l in k + 1..n {
                    if let Some(b) = circumball4(pts[i], pts[j], pts[k], pts[l]) {
                        consider(b);
                    }
                }
            }
        }
    }
    best.unwrap_or(Ball::point(pts[0]))
}

/// Support set of three points: their circumscribed ball, or the enclosing ball if collinear.
fn basis3(a: DVec3, b: DVec3, c: DVec3) -> Ball {
    circumball3(a, b, c).unwrap_or_else(|| small_enclosing(&[a, b, c]))
}

/// Support set of four points: their circumsphere, or the enclosing ball if coplanar.
fn basis4(a: DVec3, b: DVec3, c: DVec3, d: DVec3) -> Ball {
    circumball4(a, b, c, d).unwrap_or_else(|| small_enclosing(&[a, b, c, d]))
}

/// Welzl with `q1, q2, q3` on the boundary, over `pts`.
fn mb3(pts: &[DVec3], q1: DVec3, q2: DVec3, q3: DVec3, slack: f64) -> Ball {
    let mut b = basis3(q1, q2, q3);
    for &p in pts {
        if !b.contains(p, slack) {
            b = basis4(q1, q2, q3, p);
        }
    }
    b
}

/// Welzl with `q1, q2` on the boundary, over `pts`.
fn mb2(pts: &[DVec3], q1: DVec3, q2: DVec3, slack: f64) -> Ball {
    let mut b = Ball::diametral(q1, q2);
    for (k, &p) in pts.iter().enumerate() {
        if !b.contains(p, slack) {
            b = mb3(&pts[..k], q1, q2, p, slack);
        }
    }
    b
}

/// Welzl with `q` on the boundary, over `pts`.
fn mb1(pts: &[DVec3], q: DVec3, slack: f64) -> Ball {
    let mut b = Ball::point(q);
    for (j, &p) in pts.iter().enumerate() {
        if !b.contains(p, slack) {
            b = mb2(&pts[..j], q, p, slack);
        }
    }
    b
}

/// Welzl over all of `pts` (already shuffled).
fn mb0(pts: &[DVec3], slack: f64) -> Ball {
    let mut b = Ball::point(pts[0]);
    for (i, &p) in pts.iter().enumerate().skip(1) {
        if !b.contains(p, slack) {
            b = mb1(&pts[..i], p, slack);
        }
    }
    b
}

/// Rounds a ball back to `f32` so that it contains every point of `points` exactly: the
/// centre is rounded, then the radius is the largest distance (in `f64`) from the rounded
/// centre to a point, rounded up to the next `f32`.
fn to_sphere(center: DVec3, points: impl IntoIterator<Item = Vec3>) -> Sphere {
    let c32 = center.as_vec3();
    let c64 = c32.as_dvec3();
    let r64 = points
        .into_iter()
        .fold(0.0f64, |r, p| r.max(c64.distance(p.as_dvec3())));
    Sphere::new(c32, f32_up(r64))
}

/// The exact minimal bounding sphere of `points` (Welzl's algorithm, seed 000 §3.2.1 ref. 10).
///
/// Deterministic: the points are shuffled with a fixed seed, so equal inputs give equal
/// spheres. Expected `O(n)` time; no recursion on the number of points. The result contains
/// every point (its radius is measured from the rounded centre and rounded up) and is minimal
/// up to floating-point rounding. An empty slice gives the zero sphere at the origin. Points
/// must be finite (the scene builder checks this); non-finite input gives a non-finite radius,
/// never a panic.
pub fn min_sphere(points: &[Vec3]) -> Sphere {
    if points.is_empty() {
        return Sphere::new(Vec3::ZERO, 0.0);
    }
    let bounds = crsh_core::Aabb::from_points(points.iter().copied());
    let origin = bounds.center().as_dvec3();
    let size = (bounds.max.as_dvec3() - bounds.min.as_dvec3()).length();
    let slack = CONTAIN_EPS * if size.is_finite() { size } else { 0.0 };
    let mut pts: Vec<DVec3> = points.iter().map(|p| p.as_dvec3() - origin).collect();
    SplitMix64::new(SHUFFLE_SEED).shuffle(&mut pts);
    let ball = mb0(&pts, slack);
    to_sphere(ball.center + origin, points.iter().copied())
}

/// The minimal bounding sphere of the triangle `a, b, c`: its circumsphere (centre in the
/// triangle's plane) when the triangle is acute, else the sphere whose diameter is the longest
/// edge (right, obtuse and degenerate triangles). Contains all three vertices exactly in `f32`.
pub fn triangle_sphere(a: Vec3, b: Vec3, c: Vec3) -> Sphere {
    let (pa, pb, pc) = (a.as_dvec3(), b.as_dvec3(), c.as_dvec3());
    // Squared edge lengths opposite each vertex.
    let ea = pb.distance_squared(pc);
    let eb = pc.distance_squared(pa);
    let ec = pa.distance_squared(pb);
    let center = if ea >= eb + ec {
        (pb + pc) * 0.5
    } else if eb >= ec + ea {
        (pc + pa) * 0.5
    } else if ec >= ea + eb {
        (pa + pb) * 0.5
    } else {
        match circumball3(pa, pb, pc) {
            Some(ball) => ball.center,
            // Numerically flat yet "acute": cannot happen for exact input, but stay safe.
            None => small_enclosing(&[pa, pb, pc]).center,
        }
    };
    to_sphere(center, [a, b, c])
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DMat3;

    fn rand_points(seed: u64, n: usize, spread: f32) -> Vec<Vec3> {
        let mut r = SplitMix64::new(seed);
        (0..n)
            .map(|_| {
                Vec3::new(
                    r.range_f32(-spread, spread),
                    r.range_f32(-spread, spread),
                    r.range_f32(-spread, spread),
                )
            })
            .collect()
    }

    fn assert_contains_all(s: &Sphere, pts: &[Vec3]) {
        for p in pts {
            // Exact containment is promised; `contains` with zero relative slack still has an
            // absolute floor, so check the raw distance in f64 too.
            assert!(
                s.center.as_dvec3().distance(p.as_dvec3()) <= s.radius as f64,
                "{p} outside {s:?}"
            );
        }
    }

    fn close(a: f32, b: f32, rel: f32) -> bool {
        (a - b).abs() <= rel * a.abs().max(b.abs()).max(1e-6)
    }

    /// Brute-force minimal ball: the smallest of all balls determined by 1-4 point support
    /// sets (diametral, circumcircle, circumsphere — solved here by a matrix inverse, not by
    /// the code under test) that contains every point.
    fn brute_force(pts: &[Vec3]) -> (DVec3, f64) {
        let p: Vec<DVec3> = pts.iter().map(|v| v.as_dvec3()).collect();
        let n = p.len();
        let mut best = (p[0], f64::INFINITY);
        let mut try_ball = |c: DVec3| {
            let r = p.iter().map(|q| q.distance(c)).fold(0.0, f64::max);
            if r < best.1 {
                best = (c, r);
            }
        };
        for i in 0..n {
            try_ball(p[i]);
            for j in i + 1..n {
                try_ball((p[i] + p[j]) * 0.5);
                for k in j + 1..n {
                    // Centre x in the plane of i, j, k equidistant from all three.
                    let u = p[j] - p[i];
                    let v = p[k] - p[i];
                    let w = u.cross(v);
                    let m = DMat3::from_cols(u, v, w).transpose();
                    if m.determinant().abs() > 1e-12 {
                        let rhs =
                            DVec3::new(u.length_squared() / 2.0, v.length_squared() / 2.0, 0.0);
                        try_ball(p[i] + m.inverse() * rhs);
                    }
                    for l in k + 1..n {
                        let t = p[l] - p[i];
                        let m = DMat3::from_cols(u, v, t).transpose();
                        if m.determinant().abs() > 1e-12 {
                            let rhs = DVec3::new(
                                u.length_squared(),
                                v.length_squared(),
                                t.length_squared(),
                            ) / 2.0;
                            try_ball(p[i] + m.inverse() * rhs);
                        }
                    }
                }
            }
        }
        best
    }

    #[test]
    fn empty_single_and_coincident_points() {
        assert_eq!(min_sphere(&[]).radius, 0.0);
        let p = Vec3::new(1.5, -2.0, 3.25);
        let s = min_sphere(&[p]);
        assert_eq!(s.center, p);
        assert_eq!(s.radius, 0.0);
        let s = min_sphere(&[p; 1000]);
        assert_eq!(s.center, p);
        assert_eq!(s.radius, 0.0);
    }

    #[test]
    fn two_points_give_the_diametral_sphere() {
        let s = min_sphere(&[Vec3::new(-1.0, 0.0, 0.0), Vec3::new(3.0, 0.0, 0.0)]);
        assert!(s.center.distance(Vec3::new(1.0, 0.0, 0.0)) < 1e-6);
        assert!(close(s.radius, 2.0, 1e-6));
    }

    #[test]
    fn regular_tetrahedron() {
        let pts = [
            Vec3::new(1.0, 1.0, 1.0),
            Vec3::new(1.0, -1.0, -1.0),
            Vec3::new(-1.0, 1.0, -1.0),
            Vec3::new(-1.0, -1.0, 1.0),
        ];
        let s = min_sphere(&pts);
        assert!(s.center.length() < 1e-6, "{s:?}");
        assert!(close(s.radius, 3f32.sqrt(), 1e-6), "{s:?}");
        assert_contains_all(&s, &pts);
    }

    #[test]
    fn cube_corners_with_interior_points() {
        let mut pts = Vec::new();
        for i in 0..8 {
            let f = |b: i32| if i & b != 0 { 1.0 } else { -1.0 };
            pts.push(Vec3::new(f(1), f(2), f(4)) * 2.0 + Vec3::new(10.0, -5.0, 7.0));
        }
        pts.extend(
            rand_points(1, 200, 1.9)
                .iter()
                .map(|p| *p + Vec3::new(10.0, -5.0, 7.0)),
        );
        let s = min_sphere(&pts);
        assert!(
            s.center.distance(Vec3::new(10.0, -5.0, 7.0)) < 1e-5,
            "{s:?}"
        );
        assert!(close(s.radius, 2.0 * 3f32.sqrt(), 1e-6), "{s:?}");
        assert_contains_all(&s, &pts);
    }

    #[test]
    fn points_on_a_tilted_circle() {
        // Coplanar and cocircular: every 4-point support set is degenerate.
        let c = Vec3::new(1.0, 2.0, 3.0);
        let (u, v) = (
            Vec3::new(1.0, 1.0, 0.0).normalize(),
            Vec3::new(-1.0, 1.0, 2.0).normalize(),
        );
        let pts: Vec<Vec3> = (0..360)
            .map(|i| {
                let a = (i as f32).to_radians();
                c + (u * a.cos() + v * a.sin()) * 2.0
            })
            .collect();
        let s = min_sphere(&pts);
        assert!(s.center.distance(c) < 1e-5, "{s:?}");
        assert!(close(s.radius, 2.0, 1e-5), "{s:?}");
        assert_contains_all(&s, &pts);
    }

    #[test]
    fn collinear_points() {
        let pts: Vec<Vec3> = (0..1000)
            .map(|i| Vec3::new(1.0, 2.0, 3.0) * (i as f32 * 0.01 - 3.0))
            .collect();
        let s = min_sphere(&pts);
        let (a, b) = (pts[0], pts[999]);
        assert!(s.center.distance((a + b) * 0.5) < 1e-5, "{s:?}");
        assert!(close(s.radius, a.distance(b) * 0.5, 1e-6), "{s:?}");
        assert_contains_all(&s, &pts);
    }

    #[test]
    fn coplanar_grid() {
        let mut pts = Vec::new();
        for i in 0..20 {
            for j in 0..20 {
                pts.push(Vec3::new(i as f32, j as f32, 5.0));
            }
        }
        let s = min_sphere(&pts);
        assert!(s.center.distance(Vec3::new(9.5, 9.5, 5.0)) < 1e-5, "{s:?}");
        assert!(
            close(s.radius, (2.0f32 * 19.0 * 19.0).sqrt() / 2.0, 1e-6),
            "{s:?}"
        );
        assert_contains_all(&s, &pts);
    }

    #[test]
    fn matches_brute_force_on_small_random_sets() {
        for seed in 0..60u64 {
            let n = 1 + (seed as usize % 9);
            let pts = rand_points(seed + 100, n, 3.0);
            let s = min_sphere(&pts);
            let (c, r) = brute_force(&pts);
            assert_contains_all(&s, &pts);
            assert!(
                (s.radius as f64 - r).abs() <= 1e-5 * r.max(1e-3),
                "seed {seed}: {} vs brute force {r}",
                s.radius
            );
            assert!(
                s.center.as_dvec3().distance(c) <= 1e-4 * r.max(1e-3),
                "seed {seed}"
            );
        }
    }

    #[test]
    fn large_sets_are_contained_and_deterministic() {
        // 120k points on and inside a sphere: many points lie (numerically) on the boundary.
        let mut r = SplitMix64::new(9);
        let mut pts = Vec::with_capacity(120_000);
        for i in 0..120_000 {
            let d = Vec3::new(
                r.range_f32(-1.0, 1.0),
                r.range_f32(-1.0, 1.0),
                r.range_f32(-1.0, 1.0),
            )
            .normalize_or(Vec3::X);
            let len = if i % 2 == 0 {
                5.0
            } else {
                r.range_f32(0.0, 5.0)
            };
            pts.push(Vec3::new(100.0, 200.0, -50.0) + d * len);
        }
        let s = min_sphere(&pts);
        assert_contains_all(&s, &pts);
        assert!(close(s.radius, 5.0, 1e-4), "{s:?}");
        assert_eq!(min_sphere(&pts), s, "deterministic");
        let mut rev = pts.clone();
        rev.reverse();
        assert!(close(min_sphere(&rev).radius, s.radius, 1e-5));
    }

    #[test]
    fn sorted_input_is_not_a_problem() {
        // A sorted spiral is the worst case of the unshuffled algorithm.
        let pts: Vec<Vec3> = (0..100_000)
            .map(|i| {
                let a = i as f32 * 0.001;
                Vec3::new(a.cos() * (1.0 + a), a.sin() * (1.0 + a), a * 0.1)
            })
            .collect();
        let s = min_sphere(&pts);
        assert_contains_all(&s, &pts);
        // Same ball from another order (the shuffle permutes a different sequence).
        let mut rev = pts.clone();
        rev.reverse();
        let t = min_sphere(&rev);
        assert!(close(s.radius, t.radius, 1e-5) && s.center.distance(t.center) < 1e-3);
        // Minimal: the outermost spiral point and the one opposite it bound the radius below.
        let far = pts[99_999];
        let opposite = pts.iter().map(|p| p.distance(far)).fold(0.0f32, f32::max);
        assert!(s.radius >= opposite * 0.5 * (1.0 - 1e-6));
        assert!(s.radius <= opposite * 0.5 * 1.16, "{s:?} vs {opposite}");
    }

    #[test]
    fn triangle_spheres() {
        // Acute (equilateral): circumsphere, centre at the centroid.
        let (a, b, c) = (
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(2.0, 0.0, 0.0),
            Vec3::new(1.0, 3f32.sqrt(), 0.0),
        );
        let s = triangle_sphere(a, b, c);
        assert!(s.center.distance((a + b + c) / 3.0) < 1e-6);
        assert!(close(s.radius, 2.0 / 3f32.sqrt(), 1e-6));
        // Obtuse: midpoint of the longest edge.
        let (a, b, c) = (
            Vec3::ZERO,
            Vec3::new(4.0, 0.0, 0.0),
            Vec3::new(1.0, 0.5, 0.0),
        );
        let s = triangle_sphere(a, b, c);
        assert!(s.center.distance(Vec3::new(2.0, 0.0, 0.0)) < 1e-6);
        assert!(close(s.radius, 2.0, 1e-6));
        // Right: hypotenuse midpoint (also the circumcentre).
        let s = triangle_sphere(
            Vec3::ZERO,
            Vec3::new(3.0, 0.0, 0.0),
            Vec3::new(0.0, 4.0, 0.0),
        );
        assert!(s.center.distance(Vec3::new(1.5, 2.0, 0.0)) < 1e-6);
        assert!(close(s.radius, 2.5, 1e-6));
        // Degenerate (collinear) and a point triangle.
        let s = triangle_sphere(
            Vec3::ZERO,
            Vec3::new(1.0, 1.0, 1.0),
            Vec3::new(3.0, 3.0, 3.0),
        );
        assert!(s.center.distance(Vec3::splat(1.5)) < 1e-6);
        let s = triangle_sphere(Vec3::ONE, Vec3::ONE, Vec3::ONE);
        assert_eq!((s.center, s.radius), (Vec3::ONE, 0.0));
    }

    #[test]
    fn triangle_sphere_matches_min_sphere_and_brute_force() {
        for seed in 0..200u64 {
            let p = rand_points(seed + 1000, 3, 10.0);
            let t = triangle_sphere(p[0], p[1], p[2]);
            let m = min_sphere(&p);
            let (_, r) = brute_force(&p);
            assert_contains_all(&t, &p);
            assert!((t.radius as f64 - r).abs() <= 1e-5 * r, "seed {seed}");
            assert!(close(t.radius, m.radius, 1e-5), "seed {seed}");
        }
    }
}
