//! Turning a ray hit into a shaded-point record ([`Surface`]).
//!
//! Every stage that produces path vertices (the ray-cast and rasterized primaries, the
//! resolution of reflection / refraction hits) goes through [`surface_from_hit`], so a
//! G-buffer texel and a secondary-ray vertex that see the same point of the same triangle are
//! bit for bit the same record.
//!
//! # Conventions
//!
//! - **Position** is interpolated from the triangle's vertices with the hit's barycentrics,
//!   `(1-u-v)·a + u·b + v·c`, not `origin + t·dir`: the barycentric point lies on the
//!   triangle's plane up to one rounding per coordinate, whereas `origin + t·dir` drifts off the
//!   plane by an error proportional to `t`.
//! - **Shading normal** is the barycentric interpolation of the vertex normals, seed 000
//!   eq. 3.17-3.18. The thesis writes the weights as area ratios,
//!   `area(PBC)/area(ABC)` for `n_a`, `area(PCA)/area(ABC)` for `n_b` and the rest for `n_c`
//!   (eq. 3.17a-c); these ratios are exactly the Möller-Trumbore barycentrics
//!   `(1-u-v, u, v)` of the hit point `P` (see [`area_ratio_weights`], which the tests compare
//!   with them), so the MT weights are used directly and no cross product is spent per hit.
//! - **Geometric normal** is `normalize((b-a) × (c-a))`: it points out of the front face, the
//!   face whose vertices appear counter-clockwise to the viewer.
//! - **Facing**: the geometric normal is flipped to the side the ray came from; the shading
//!   normal is flipped (if needed) into the same hemisphere as that flipped geometric normal,
//!   so both are "on the side the ray came from" while the shading normal keeps its
//!   interpolated tilt (near silhouettes a smooth normal may lean slightly away from the
//!   viewer; it is not forced to face the ray, which would make it discontinuous).
//!   [`Surface::FRONT_FACE`] is set when the ray hit the front face (`dir · n_geo < 0`).
//! - If the interpolated normal vanishes (opposite vertex normals) or is not finite, the
//!   geometric normal is used.

use crsh_core::glam::Vec3;
use crsh_core::{CoreError, Hit, Ray, Result, Surface};
use crsh_scene::Scene;
use rayon::prelude::*;

/// The [`Surface`] record of `hit` for a ray from `ray_origin` along `ray_dir`.
///
/// `ray_origin` is kept in the signature for callers that record it; the position itself comes
/// from the barycentrics (see the module doc). `incident` is `ray_dir` normalized. A miss (or
/// a hit whose triangle id is not a triangle of `scene`, which no intersector of this crate
/// produces) yields [`Surface::background`] with the same pixel, throughput and depth.
pub fn surface_from_hit(
    scene: &Scene,
    ray_origin: Vec3,
    ray_dir: Vec3,
    hit: &Hit,
    pixel: u32,
    throughput: Vec3,
    depth: u32,
) -> Surface {
    let _ = ray_origin;
    let incident = ray_dir.normalize_or_zero();
    let tri = hit.tri as usize;
    if !hit.is_hit() || tri >= scene.indices.len() {
        return Surface::background(pixel, incident, throughput, depth);
    }
    let [ia, ib, ic] = scene.indices[tri];
    let (a, b, c) = (
        scene.positions[ia as usize],
        scene.positions[ib as usize],
        scene.positions[ic as usize],
    );
    let (u, v) = (hit.u, hit.v);
    let w = 1.0 - u - v;
    let position = a * w + b * u + c * v;

    // Geometric normal; front face = counter-clockwise seen from the ray.
    let face = (b - a).cross(c - a);
    let front = ray_dir.dot(face) < 0.0;
    let mut geo_normal = face.normalize_or_zero();
    if !front {
        geo_normal = -geo_normal;
    }

    // Shading normal, eq. 3.18 with the MT barycentrics as the eq. 3.17 area ratios.
    let normal_at = |i: u32| scene.normals.get(i as usize).copied().unwrap_or(Vec3::ZERO);
    let interpolated = normal_at(ia) * w + normal_at(ib) * u + normal_at(ic) * v;
    let mut normal = interpolated.normalize_or_zero();
    if normal == Vec3::ZERO {
        normal = geo_normal;
    } else if normal.dot(geo_normal) < 0.0 {
        normal = -normal;
    }

    let material = scene.tri_material.get(tri).copied().unwrap_or(0);
    Surface {
        position,
        tri: hit.tri,
        normal,
        material,
        incident,
        pixel,
        throughput,
        depth,
        geo_normal,
        flags: if front { Surface::FRONT_FACE } else { 0 },
    }
}

/// The weights of `n_a`, `n_b`, `n_c` for point `p` on triangle `a, b, c` in the area-ratio
/// form of seed 000 eq. 3.17-3.18: `area(PBC)/area(ABC)`, `area(PCA)/area(ABC)` and
/// `1 - (the other two)`.
///
/// The areas are unsigned (`|cross|/2`; the halves cancel), so the ratios equal the
/// barycentrics only for points inside the triangle, which is where hits are. Computed in f64
/// because the shading path does not use this form (it uses the identical Möller-Trumbore
/// weights, see the module doc); it exists to document and test that equivalence. Returns
/// `None` for a zero-area triangle.
pub fn area_ratio_weights(a: Vec3, b: Vec3, c: Vec3, p: Vec3) -> Option<[f64; 3]> {
    let (a, b, c, p) = (a.as_dvec3(), b.as_dvec3(), c.as_dvec3(), p.as_dvec3());
    // eq. 3.17a-c (as magnitudes).
    let area_abc = (b - a).cross(c - a).length();
    if area_abc == 0.0 || !area_abc.is_finite() {
        return None;
    }
    let area_pbc = (b - p).cross(c - p).length();
    let area_pca = (a - p).cross(c - p).length();
    let wa = area_pbc / area_abc;
    let wb = area_pca / area_abc;
    // eq. 3.18.
    Some([wa, wb, 1.0 - wa - wb])
}

/// The next path vertices of `rays` and their nearest `hits` (one per ray, same order):
/// [`surface_from_hit`] with each ray's pixel, throughput and depth; a miss becomes a
/// background record. What every shader's [`crsh_core::Shader::resolve`] does.
pub fn next_surfaces(scene: &Scene, rays: &[Ray], hits: &[Hit]) -> Result<Vec<Surface>> {
    crsh_core::ray::check_hits_per_ray("rays", rays.len(), hits.len())?;
    let ntri = scene.triangle_count();
    if let Some(h) =
        crate::position_first(hits, |h| h.is_hit() && h.tri as usize >= ntri).map(|i| &hits[i])
    {
        return Err(CoreError::InvalidInput(format!(
            "hit on triangle {} but the scene has {ntri}",
            h.tri
        )));
    }
    Ok(rays
        .par_iter()
        .zip(hits)
        .map(|(r, h)| surface_from_hit(scene, r.origin, r.dir, h, r.pixel, r.throughput, r.depth))
        .collect())
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crsh_core::NO_HIT;
    use crsh_scene::{Camera, Material, SceneBuilder};

    /// A scene made with [`SceneBuilder`] from raw arrays: one mesh holding all `indices`
    /// (in order) over `positions`, with per-vertex `normals` (unit length: the builder
    /// normalizes them again, which may move a component by an ulp), two default materials,
    /// no lights, and a camera at z = 5 looking at the origin.
    ///
    /// Triangle `i` uses material `i % 2`, so that material ids vary across a scene. The
    /// builder gives all the triangles of a mesh one material, and a mesh per triangle would
    /// renumber the vertices, so the ids are set after building: the one field not left to
    /// the builder.
    pub(crate) fn raw_scene(
        positions: Vec<Vec3>,
        normals: Vec<Vec3>,
        indices: Vec<[u32; 3]>,
    ) -> Scene {
        let mut b = SceneBuilder::new("raw");
        let m = b.material(Material::default());
        b.material(Material::default());
        b.camera(Camera {
            eye: Vec3::new(0.0, 0.0, 5.0),
            target: Vec3::ZERO,
            up: Vec3::Y,
            vfov_deg: 45.0,
            aspect: None,
        });
        b.mesh("all", &positions, Some(&normals), &indices, m);
        let mut scene = b.build("raw test scene").unwrap();
        for (i, id) in scene.tri_material.iter_mut().enumerate() {
            *id = i as u32 % 2;
        }
        scene
    }

    fn one_triangle(normals: [Vec3; 3]) -> Scene {
        raw_scene(
            vec![Vec3::ZERO, Vec3::X, Vec3::Y],
            normals.to_vec(),
            vec![[0, 1, 2]],
        )
    }

    #[test]
    fn area_ratios_equal_mt_barycentrics() {
        let (a, b, c) = (
            Vec3::new(0.3, -1.2, 0.7),
            Vec3::new(2.1, 0.4, -0.5),
            Vec3::new(-0.8, 1.9, 1.3),
        );
        for &(u, v) in &[
            (0.2f32, 0.3f32),
            (0.0, 0.0),
            (1.0, 0.0),
            (0.0, 1.0),
            (0.5, 0.5),
            (0.01, 0.9),
        ] {
            let p = a * (1.0 - u - v) + b * u + c * v;
            let w = area_ratio_weights(a, b, c, p).unwrap();
            let expect = [1.0 - u as f64 - v as f64, u as f64, v as f64];
            for k in 0..3 {
                assert!(
                    (w[k] - expect[k]).abs() < 1e-5,
                    "{u} {v}: {w:?} vs {expect:?}"
                );
            }
        }
        assert!(area_ratio_weights(a, a, c, a).is_none());
    }

    #[test]
    fn position_normal_and_facing() {
        let scene = one_triangle([Vec3::Z, Vec3::Z, Vec3::Z]);
        // From +z looking down -z: the triangle (0,0,0),(1,0,0),(0,1,0) is counter-clockwise.
        let hit = Hit {
            t: 2.0,
            tri: 0,
            u: 0.25,
            v: 0.5,
        };
        let s = surface_from_hit(
            &scene,
            Vec3::new(0.25, 0.5, 2.0),
            -Vec3::Z * 3.0,
            &hit,
            7,
            Vec3::ONE,
            1,
        );
        assert_eq!(s.position, Vec3::new(0.25, 0.5, 0.0));
        assert_eq!(s.tri, 0);
        assert_eq!(s.pixel, 7);
        assert_eq!(s.depth, 1);
        assert_eq!(s.material, 0);
        assert_eq!(s.incident, -Vec3::Z);
        assert_eq!(s.geo_normal, Vec3::Z);
        assert_eq!(s.normal, Vec3::Z);
        assert!(s.front_face());

        // From below: back face; both normals flipped towards the ray.
        let s = surface_from_hit(
            &scene,
            Vec3::new(0.25, 0.5, -2.0),
            Vec3::Z,
            &hit,
            0,
            Vec3::ONE,
            0,
        );
        assert!(!s.front_face());
        assert_eq!(s.geo_normal, -Vec3::Z);
        assert_eq!(s.normal, -Vec3::Z);
    }

    #[test]
    fn shading_normal_interpolates_eq_3_18() {
        let na = Vec3::new(0.0, 0.0, 1.0);
        let nb = Vec3::new(1.0, 0.0, 1.0).normalize();
        let nc = Vec3::new(0.0, 1.0, 1.0).normalize();
        let scene = one_triangle([na, nb, nc]);
        let (u, v) = (0.3f32, 0.6f32);
        let hit = Hit {
            t: 1.0,
            tri: 0,
            u,
            v,
        };
        let s = surface_from_hit(
            &scene,
            Vec3::new(0.3, 0.6, 1.0),
            -Vec3::Z,
            &hit,
            0,
            Vec3::ONE,
            0,
        );
        // eq. 3.17-3.18 with area ratios computed from the hit position.
        let [wa, wb, wc] = area_ratio_weights(Vec3::ZERO, Vec3::X, Vec3::Y, s.position).unwrap();
        let expect = (na.as_dvec3() * wa + nb.as_dvec3() * wb + nc.as_dvec3() * wc).normalize();
        assert!(
            (s.normal.as_dvec3() - expect).length() < 1e-6,
            "{:?} vs {expect:?}",
            s.normal
        );
        assert!((s.normal.length() - 1.0).abs() < 1e-6);
        assert_eq!(s.geo_normal, Vec3::Z);
    }

    #[test]
    fn vertex_normals_against_the_winding_are_flipped_with_the_face() {
        // Vertex normals point to -z although the winding says +z: the shading normal still
        // ends up in the geometric normal's hemisphere on the ray's side.
        let scene = one_triangle([-Vec3::Z; 3]);
        let hit = Hit {
            t: 1.0,
            tri: 0,
            u: 0.2,
            v: 0.2,
        };
        let s = surface_from_hit(
            &scene,
            Vec3::new(0.2, 0.2, 1.0),
            -Vec3::Z,
            &hit,
            0,
            Vec3::ONE,
            0,
        );
        assert_eq!(s.normal, Vec3::Z);
        // Opposite normals that cancel fall back to the geometric normal.
        let scene = one_triangle([Vec3::Z, -Vec3::Z, Vec3::Z]);
        let hit = Hit {
            t: 1.0,
            tri: 0,
            u: 0.5,
            v: 0.0,
        };
        let s = surface_from_hit(
            &scene,
            Vec3::new(0.5, 0.0, 1.0),
            -Vec3::Z,
            &hit,
            0,
            Vec3::ONE,
            0,
        );
        assert_eq!(s.normal, Vec3::Z);
    }

    #[test]
    fn misses_and_bad_ids_are_background() {
        let scene = one_triangle([Vec3::Z; 3]);
        let th = Vec3::new(0.5, 0.25, 1.0);
        let s = surface_from_hit(
            &scene,
            Vec3::ZERO,
            Vec3::new(0.0, 2.0, 0.0),
            &Hit::MISS,
            3,
            th,
            2,
        );
        assert!(!s.is_hit());
        assert_eq!(s.tri, NO_HIT);
        assert_eq!(s.incident, Vec3::Y);
        assert_eq!(s.throughput, th);
        assert_eq!((s.pixel, s.depth), (3, 2));
        let bad = Hit {
            t: 1.0,
            tri: 5,
            u: 0.0,
            v: 0.0,
        };
        assert!(!surface_from_hit(&scene, Vec3::ZERO, Vec3::Y, &bad, 0, th, 0).is_hit());
    }
}
