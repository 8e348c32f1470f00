//! Random triangle soups: the test scenes of seed 002 §5.1 (Ivson, Duarte and Celes 2009,
//! table 1, grid build time against triangle count).
//!
//! "The test scene consists of several triangles randomly distributed inside a box with
//! dimensions [-50, -50, -50] × [50, 50, 50]. Each triangle has a randomly determined size,
//! obtained by varying the radius of its enclosing bounding sphere from 0.2 to 1.0."
//!
//! [`triangle_soup`] builds that scene: per triangle, a radius `r` uniform in
//! [[`RADIUS_MIN`], [`RADIUS_MAX`]), a centre uniform in the box shrunk by `r` (so the sphere,
//! and the triangle, lie inside the box), and three vertices uniform on the sphere of radius
//! `r` around the centre (a random orientation; the sphere is the triangle's circumscribed
//! sphere, so it encloses it). Triangles thinner than [`MIN_AREA_REL`]·r² are drawn again, so
//! no triangle is degenerate. Everything comes from the crate's SplitMix64 generator seeded
//! with `seed`: the same `count` and `seed` give the same scene bit for bit on every machine.
//!
//! ```
//! let scene = crsh_scene::random::triangle_soup(1000, 7).unwrap();
//! assert_eq!((scene.triangle_count(), scene.meshes.len()), (1000, 1));
//! assert!(scene.bounds.min.min_element() >= -50.0 && scene.bounds.max.max_element() <= 50.0);
//! assert!(crsh_scene::random::triangle_soup(0, 7).is_err()); // an empty scene is an error
//! ```

use glam::{DVec3, Vec3};

use crate::error::SceneError;
use crate::model::{Camera, Light, Material, Scene, SceneBuilder, MAX_TRIANGLES};
use crate::rng::SplitMix64;

/// Half the side of the box the triangles lie in (§5.1: `[-50, 50]³`).
pub const BOX_HALF: f32 = 50.0;

/// Smallest radius of a triangle's enclosing sphere (§5.1).
pub const RADIUS_MIN: f32 = 0.2;

/// Largest radius of a triangle's enclosing sphere (§5.1).
pub const RADIUS_MAX: f32 = 1.0;

/// A triangle whose area is below this fraction of `r²` is drawn again (an equilateral
/// triangle inscribed in the sphere has `3√3/4·r² ≈ 1.3 r²`).
pub const MIN_AREA_REL: f64 = 0.05;

/// The seed `crsh grid-build` and the `grid_build` bench use.
pub const DEFAULT_SEED: u64 = 0x002_5EED;

/// A uniform direction on the unit sphere (Archimedes: `z` uniform, azimuth uniform).
fn unit_direction(rng: &mut SplitMix64) -> DVec3 {
    let z = 2.0 * rng.unit_f32() as f64 - 1.0;
    let phi = std::f64::consts::TAU * rng.unit_f32() as f64;
    let s = (1.0 - z * z).max(0.0).sqrt();
    DVec3::new(s * phi.cos(), s * phi.sin(), z)
}

/// One triangle of the soup: its vertices on a sphere of random radius and centre.
fn triangle(rng: &mut SplitMix64) -> [Vec3; 3] {
    let r = rng.range_f32(RADIUS_MIN, RADIUS_MAX);
    let half = BOX_HALF - r;
    let c = DVec3::new(
        rng.range_f32(-half, half) as f64,
        rng.range_f32(-half, half) as f64,
        rng.range_f32(-half, half) as f64,
    );
    let r = r as f64;
    // Rejection keeps the triangles well shaped; after 64 thin draws (probability far below
    // 1e-60), an equilateral triangle in a random plane ends the loop.
    for _ in 0..64 {
        let d = [0, 1, 2].map(|_| unit_direction(rng));
        let area = 0.5 * (d[1] - d[0]).cross(d[2] - d[0]).length();
        if area >= MIN_AREA_REL {
            return d.map(|d| (c + d * r).as_vec3());
        }
    }
    let n = unit_direction(rng);
    let u = n.any_orthonormal_vector();
    let v = n.cross(u);
    [0.0f64, 1.0, 2.0].map(|i| {
        let a = i * std::f64::consts::TAU / 3.0;
        (c + (u * a.cos() + v * a.sin()) * r).as_vec3()
    })
}

/// The `count` triangles of the soup with seed `seed`, as vertex triples (see the module doc).
pub fn soup_triangles(count: usize, seed: u64) -> Vec<[Vec3; 3]> {
    let mut rng = SplitMix64::new(seed);
    (0..count).map(|_| triangle(&mut rng)).collect()
}

/// The scene of seed 002 §5.1 with `count` triangles: one mesh `soup` (three vertices per
/// triangle, nothing shared), one light above the box and a camera in front of it that sees
/// the whole box. Validated by [`SceneBuilder`].
///
/// # Errors
/// [`SceneError::Invalid`] when `count` is 0 (an empty scene) or above [`MAX_TRIANGLES`].
pub fn triangle_soup(count: usize, seed: u64) -> Result<Scene, SceneError> {
    let name = format!("random-soup-{count}");
    if count == 0 || count > MAX_TRIANGLES {
        return Err(SceneError::invalid(
            &name,
            format!("a random soup needs 1..={MAX_TRIANGLES} triangles (got {count})"),
        ));
    }
    let tris = soup_triangles(count, seed);
    let positions: Vec<Vec3> = tris.iter().flatten().copied().collect();
    let indices: Vec<[u32; 3]> = (0..count as u32)
        .map(|t| [3 * t, 3 * t + 1, 3 * t + 2])
        .collect();
    let mut b = SceneBuilder::new(&name);
    let m = b.material(Material::default());
    b.mesh("soup", &positions, None, &indices, m);
    b.light(Light {
        position: Vec3::new(0.0, 3.0 * BOX_HALF, 3.0 * BOX_HALF),
        color: Vec3::ONE,
        intensity: 1.0,
        attenuation: [1.0, 0.0, 0.0],
        radius: 0.0,
    });
    b.camera(Camera {
        eye: Vec3::new(0.0, 0.0, 3.6 * BOX_HALF),
        target: Vec3::ZERO,
        up: Vec3::Y,
        vfov_deg: 45.0,
        aspect: None,
    });
    b.build(&name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn triangles_follow_section_5_1() {
        let tris = soup_triangles(20_000, DEFAULT_SEED);
        let (mut r_lo, mut r_hi) = (f64::MAX, 0.0f64);
        for t in &tris {
            let [a, b, c] = t.map(|v| v.as_dvec3());
            // The three vertices are equidistant from a centre inside the box shrunk by r:
            // the circumcentre of the triangle, in its plane.
            let n = (b - a).cross(c - a);
            let area = 0.5 * n.length();
            let cc = a
                + ((c - a).length_squared() * n.cross(b - a)
                    + (b - a).length_squared() * (c - a).cross(n))
                    / (2.0 * n.length_squared());
            let r = (a - cc).length();
            assert!(((b - cc).length() - r).abs() < 1e-4 && ((c - cc).length() - r).abs() < 1e-4);
            // The circumradius is at most the sphere's radius (equal when the centre is in
            // the plane); every vertex is in the box.
            assert!(r <= RADIUS_MAX as f64 + 1e-4, "radius {r}");
            r_lo = r_lo.min(r);
            r_hi = r_hi.max(r);
            assert!(area >= MIN_AREA_REL * 0.2 * 0.2 * 0.999, "area {area}");
            for v in [a, b, c] {
                assert!(v.abs().max_element() <= BOX_HALF as f64, "{v}");
            }
        }
        // The sizes span the range of §5.1.
        assert!(r_hi > 0.95 && r_lo < 0.25, "{r_lo} {r_hi}");
        // Spread over the whole box.
        let lo = tris.iter().flatten().fold(Vec3::MAX, |m, v| m.min(*v));
        let hi = tris.iter().flatten().fold(Vec3::MIN, |m, v| m.max(*v));
        assert!(
            lo.max_element() < -48.0 && hi.min_element() > 48.0,
            "{lo} {hi}"
        );
    }

    #[test]
    fn deterministic_and_seeded() {
        let a = soup_triangles(100, 1);
        assert_eq!(a, soup_triangles(100, 1));
        assert_ne!(a, soup_triangles(100, 2));
        // A longer soup starts with the shorter one.
        assert_eq!(&soup_triangles(150, 1)[..100], &a[..]);
    }

    #[test]
    fn scene_is_valid_and_bad_counts_are_errors() {
        let s = triangle_soup(500, 3).unwrap();
        assert_eq!(s.triangle_count(), 500);
        assert_eq!(s.degenerate_triangles, 0);
        assert_eq!(s.lights.len(), 1);
        assert_eq!(s.name, "random-soup-500");
        let e = triangle_soup(0, 3).unwrap_err().to_string();
        assert!(e.contains("1..="), "{e}");
        assert!(triangle_soup(MAX_TRIANGLES + 1, 3).is_err());
    }
}
