//! `raster`: a CPU z-buffer rasterizer writing the G-buffer (seed 000 §3.1).
//!
//! The thesis rasterizes the first hit with OpenGL and reads fragment positions and normals
//! from render targets. Here the rasterizer decides *visibility* (which triangle each pixel
//! sees) and the surface is then resolved exactly, visibility-buffer style: the pixel-centre
//! camera ray ([`camera_ray`], shared with the ray caster) is intersected with the plane of
//! the visible triangle by the crate's one triangle solve ([`PreparedTriangle::plane_hit`]),
//! and [`surface_from_hit`] builds the record. Where raster and ray cast see the same
//! triangle, their G-buffer texels are therefore identical bit for bit.
//!
//! # Pipeline
//!
//! 1. **Setup** (parallel over triangles): vertices go to camera space in f64, then to
//!    homogeneous clip space `(x, y, w)` with `w` the depth along the view axis. Polygons are
//!    clipped (Sutherland-Hodgman) against the near plane `w >= near` (`near` = 1e-6 of the
//!    scene's bounding-box diagonal; geometry closer to the eye than that is not drawn) and
//!    against a guard band `|x|, |y| <= G·w` that keeps screen coordinates within ±2²⁰ pixels,
//!    so triangles crossing the near plane or lying partly behind the camera are drawn
//!    correctly. The clipped polygon is fanned into triangles, projected, and snapped to
//!    fixed point with 8 sub-pixel bits. Zero-area (degenerate, or edge-on) triangles are not
//!    rasterized.
//! 2. **Binning**: each screen triangle is listed, in triangle-id order, in the bands of
//!    [`BAND_ROWS`] rows its bounding box touches.
//! 3. **Raster** (parallel over bands, each band owning its rows of the z-buffer): coverage at
//!    pixel centres with exact integer edge functions and the **top-left fill rule** (a pixel
//!    centre on an edge belongs to the triangle for which that edge is a top or left edge), so
//!    triangles sharing an edge neither overlap nor leave cracks. The depth of a covered pixel
//!    is the distance `t` along its camera ray to the triangle's plane; a fragment replaces
//!    the stored one by [`Hit::closer_than`] (nearer, **ties to the lower triangle id**), the
//!    very rule of the ray caster's closest hit. Bands never share pixels, so the result is
//!    the same for any thread count.
//! 4. **Resolve** (parallel over pixels): [`surface_from_hit`] with the stored `t, u, v`.
//!    Background pixels get [`Surface::background`] with the camera ray's direction.
//!
//! Differences from the ray caster remain only where the pixel-centre ray passes within about
//! 1/256 pixel of a triangle edge (snapping, and the rasterizer's coverage decided by edge
//! functions rather than by Möller-Trumbore barycentrics), or for geometry nearer than
//! `near`. The stage records no test counts (it traces no rays).

use std::sync::Arc;

use crsh_core::glam::{DVec3, Vec3};
use crsh_core::{
    CoreError, Hit, PrimaryVisibility, Registry, Result, StageKind, StageSpec, StageVariantInfo,
    Stats, Surface,
};
use crsh_scene::Scene;
use rayon::prelude::*;

use crate::backend::Cpu;
use crate::primary::raycast::{camera_ray, check_view};
use crate::surface::surface_from_hit;
use crate::triangle::{PreparedTriangle, RayPre, TriangleSet};

/// Rows per band (the unit of parallel work and of binning).
pub const BAND_ROWS: u32 = 8;

/// Sub-pixel precision of the snapped vertex coordinates.
const SUBPIXEL_BITS: u32 = 8;

/// Near plane distance as a fraction of the scene's bounding-box diagonal.
const NEAR_FRACTION: f64 = 1e-6;

/// A projected, snapped, consistently oriented screen triangle.
#[derive(Clone, Copy, Debug)]
struct ScreenTri {
    /// Scene triangle id.
    id: u32,
    /// Vertices in fixed point (`SUBPIXEL_BITS` fractional bits), positive area.
    v: [[i64; 2]; 3],
    /// Inclusive pixel bounding box `[x0, y0, x1, y1]`, clamped to the image.
    bbox: [u32; 4],
}

/// The rasterizer (variant `raster`, no parameters).
pub struct Raster {
    scene: Arc<Scene>,
    tris: TriangleSet,
}

/// The catalogue entry of the `raster` primary stage.
pub fn info() -> StageVariantInfo {
    StageVariantInfo::new(
        StageKind::Primary,
        "raster",
        "z-buffer rasterizer writing the G-buffer (position, normals, material, triangle \
         id), seed 000 §3.1",
    )
}

/// Registers `raster` ([`info`], [`Raster::new`]).
pub fn register(registry: &mut Registry<Cpu>) -> Result<()> {
    registry.add_primary(info(), |ctx, spec| {
        Ok(Box::new(Raster::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

impl Raster {
    /// Prepares `scene`'s triangles. `spec` has no parameters to read.
    pub fn new(scene: &Arc<Scene>, spec: &StageSpec) -> Result<Raster, CoreError> {
        let _ = spec;
        Ok(Raster {
            scene: Arc::clone(scene),
            tris: TriangleSet::new(scene),
        })
    }

    /// The visible triangle per pixel as a [`Hit`] on the pixel-centre camera ray (row-major,
    /// `y = 0` the top row; [`Hit::MISS`] for the background).
    pub fn visibility(&self, width: u32, height: u32) -> Result<Vec<Hit>> {
        check_view(&self.scene.camera, width, height)?;
        let rays: Vec<RayPre> = (0..width * height)
            .into_par_iter()
            .map(|p| {
                let (o, d) = camera_ray(&self.scene.camera, p % width, p / width, width, height);
                RayPre::new(o, d)
            })
            .collect();
        let setup = Setup::new(&self.scene, width, height);
        let screen: Vec<ScreenTri> = (0..self.scene.triangle_count())
            .into_par_iter()
            .filter(|&t| !self.tris.triangles()[t].is_degenerate())
            .flat_map_iter(|t| setup.project(&self.scene, t as u32))
            .collect();

        // Bin by bands, in triangle-id order.
        let bands = height.div_ceil(BAND_ROWS) as usize;
        let mut counts = vec![0usize; bands + 1];
        for s in &screen {
            for b in (s.bbox[1] / BAND_ROWS)..=(s.bbox[3] / BAND_ROWS) {
                counts[b as usize + 1] += 1;
            }
        }
        for b in 0..bands {
            counts[b + 1] += counts[b];
        }
        let mut fill = counts.clone();
        let mut binned = vec![0u32; counts[bands]];
        for (i, s) in screen.iter().enumerate() {
            for b in (s.bbox[1] / BAND_ROWS)..=(s.bbox[3] / BAND_ROWS) {
                binned[fill[b as usize]] = i as u32;
                fill[b as usize] += 1;
            }
        }

        let w = width as usize;
        let mut zbuf = vec![Hit::MISS; w * height as usize];
        let prepared = self.tris.triangles();
        zbuf.par_chunks_mut(w * BAND_ROWS as usize)
            .enumerate()
            .for_each(|(band, rows)| {
                let y_start = band as u32 * BAND_ROWS;
                let y_end = (y_start + BAND_ROWS).min(height) - 1;
                for &i in &binned[counts[band]..counts[band + 1]] {
                    let s = &screen[i as usize];
                    raster_into(
                        s,
                        &prepared[s.id as usize],
                        &rays,
                        rows,
                        width,
                        y_start,
                        y_end,
                    );
                }
            });
        Ok(zbuf)
    }
}

/// Rasterizes `s` into the band `rows` (rows `y_start..=y_end` of the image).
fn raster_into(
    s: &ScreenTri,
    tri: &PreparedTriangle,
    rays: &[RayPre],
    rows: &mut [Hit],
    width: u32,
    y_start: u32,
    y_end: u32,
) {
    let [x0, y0, x1, y1] = s.bbox;
    let (ya, yb) = (y0.max(y_start), y1.min(y_end));
    let half = 1i64 << (SUBPIXEL_BITS - 1);
    let edges = [(0usize, 1usize), (1, 2), (2, 0)].map(|(a, b)| {
        let (pa, pb) = (s.v[a], s.v[b]);
        let (dx, dy) = (pb[0] - pa[0], pb[1] - pa[1]);
        // Top edge: horizontal, pointing +x; left edge: pointing up (y grows downwards).
        let top_left = (dy == 0 && dx > 0) || dy < 0;
        (pa, dx, dy, top_left)
    });
    for y in ya..=yb {
        let py = ((y as i64) << SUBPIXEL_BITS) + half;
        for x in x0..=x1 {
            let px = ((x as i64) << SUBPIXEL_BITS) + half;
            let covered = edges.iter().all(|&(pa, dx, dy, top_left)| {
                let e = dx * (py - pa[1]) - dy * (px - pa[0]);
                e > 0 || (e == 0 && top_left)
            });
            if !covered {
                continue;
            }
            let pixel = (y * width + x) as usize;
            let Some((t, u, v)) = tri.plane_hit(&rays[pixel]) else {
                continue;
            };
            if !(t > 0.0 && t < f32::INFINITY) {
                continue;
            }
            let cand = Hit { t, tri: s.id, u, v };
            let slot = &mut rows[((y - y_start) * width + x) as usize];
            if cand.closer_than(slot) {
                *slot = cand;
            }
        }
    }
}

/// The view transform and clipping setup of one frame.
struct Setup {
    eye: DVec3,
    right: DVec3,
    up: DVec3,
    forward: DVec3,
    /// `1 / (tan(fov/2)·aspect)` and `1 / tan(fov/2)`.
    scale: [f64; 2],
    near: f64,
    guard: f64,
    width: u32,
    height: u32,
}

impl Setup {
    fn new(scene: &Scene, width: u32, height: u32) -> Setup {
        let cam = &scene.camera;
        let (r, u, f) = cam.basis();
        let aspect = width as f64 / height as f64;
        let tan_half = (cam.vfov_deg.to_radians() * 0.5).tan() as f64;
        let diag = scene.bounds.diagonal() as f64;
        Setup {
            eye: cam.eye.as_dvec3(),
            right: r.as_dvec3(),
            up: u.as_dvec3(),
            forward: f.as_dvec3(),
            scale: [1.0 / (tan_half * aspect), 1.0 / tan_half],
            near: (diag * NEAR_FRACTION).max(f64::MIN_POSITIVE),
            guard: (1u64 << 21) as f64 / width.max(height) as f64,
            width,
            height,
        }
    }

    /// Homogeneous clip coordinates `(x, y, w)` of `p`.
    fn clip(&self, p: Vec3) -> [f64; 3] {
        let rel = p.as_dvec3() - self.eye;
        [
            rel.dot(self.right) * self.scale[0],
            rel.dot(self.up) * self.scale[1],
            rel.dot(self.forward),
        ]
    }

    /// The screen triangles of scene triangle `id` after clipping (0 to 6 of them).
    fn project(&self, scene: &Scene, id: u32) -> Vec<ScreenTri> {
        let [a, b, c] = scene.triangle(id as usize);
        let mut poly = vec![self.clip(a), self.clip(b), self.clip(c)];
        let (g, n) = (self.guard, self.near);
        // Planes as `(a, b, c, d)`: inside where `a·x + b·y + c·w + d >= 0`.
        let planes = [
            [0.0, 0.0, 1.0, -n],
            [-1.0, 0.0, g, 0.0],
            [1.0, 0.0, g, 0.0],
            [0.0, -1.0, g, 0.0],
            [0.0, 1.0, g, 0.0],
        ];
        for plane in planes {
            poly = clip_polygon(&poly, &plane);
            if poly.len() < 3 {
                return Vec::new();
            }
        }
        let sub = (1u64 << SUBPIXEL_BITS) as f64;
        let (w2, h2) = (self.width as f64 * 0.5, self.height as f64 * 0.5);
        let snapped: Vec<[i64; 2]> = poly
            .iter()
            .map(|v| {
                let sx = (v[0] / v[2] + 1.0) * w2;
                let sy = (1.0 - v[1] / v[2]) * h2;
                [(sx * sub).round() as i64, (sy * sub).round() as i64]
            })
            .collect();
        (1..snapped.len() - 1)
            .filter_map(|k| self.screen_tri(id, [snapped[0], snapped[k], snapped[k + 1]]))
            .collect()
    }

    /// An oriented screen triangle with its pixel bounding box, or `None` when it has zero
    /// area or covers no pixel centre's bounding box.
    fn screen_tri(&self, id: u32, mut v: [[i64; 2]; 3]) -> Option<ScreenTri> {
        let area =
            (v[1][0] - v[0][0]) * (v[2][1] - v[0][1]) - (v[1][1] - v[0][1]) * (v[2][0] - v[0][0]);
        if area == 0 {
            return None;
        }
        if area < 0 {
            v.swap(1, 2);
        }
        let half = 1i64 << (SUBPIXEL_BITS - 1);
        let min = |k: usize| v.iter().map(|p| p[k]).min().unwrap_or(0);
        let max = |k: usize| v.iter().map(|p| p[k]).max().unwrap_or(0);
        // Pixel x has its centre at x·2^S + half: first centre >= min, last centre <= max.
        let first = |m: i64| (m - half + (1 << SUBPIXEL_BITS) - 1).div_euclid(1 << SUBPIXEL_BITS);
        let last = |m: i64| (m - half).div_euclid(1 << SUBPIXEL_BITS);
        let (x0, x1) = (
            first(min(0)).max(0),
            last(max(0)).min(self.width as i64 - 1),
        );
        let (y0, y1) = (
            first(min(1)).max(0),
            last(max(1)).min(self.height as i64 - 1),
        );
        if x0 > x1 || y0 > y1 {
            return None;
        }
        Some(ScreenTri {
            id,
            v,
            bbox: [x0 as u32, y0 as u32, x1 as u32, y1 as u32],
        })
    }
}

/// Sutherland-Hodgman: the part of polygon `poly` (vertices `(x, y, w)`) where
/// `a·x + b·y + c·w + d >= 0` for `plane = (a, b, c, d)`.
fn clip_polygon(poly: &[[f64; 3]], plane: &[f64; 4]) -> Vec<[f64; 3]> {
    let dist = |v: &[f64; 3]| plane[0] * v[0] + plane[1] * v[1] + plane[2] * v[2] + plane[3];
    let mut out = Vec::with_capacity(poly.len() + 1);
    for i in 0..poly.len() {
        let (p, q) = (&poly[i], &poly[(i + 1) % poly.len()]);
        let (dp, dq) = (dist(p), dist(q));
        if dp >= 0.0 {
            out.push(*p);
        }
        if (dp >= 0.0) != (dq >= 0.0) {
            let s = dp / (dp - dq);
            out.push([
                p[0] + (q[0] - p[0]) * s,
                p[1] + (q[1] - p[1]) * s,
                p[2] + (q[2] - p[2]) * s,
            ]);
        }
    }
    out
}

impl PrimaryVisibility<Cpu> for Raster {
    fn name(&self) -> &str {
        "raster"
    }

    fn gbuffer(
        &self,
        _backend: &Cpu,
        width: u32,
        height: u32,
        _stats: &mut Stats,
    ) -> Result<Vec<Surface>> {
        let vis = self.visibility(width, height)?;
        let scene = &*self.scene;
        Ok(vis
            .par_iter()
            .enumerate()
            .map(|(p, hit)| {
                let p = p as u32;
                let (o, d) = camera_ray(&scene.camera, p % width, p / width, width, height);
                surface_from_hit(scene, o, d, hit, p, Vec3::ONE, 0)
            })
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::primary::raycast::RayCast;
    use crate::surface::tests::raw_scene;
    use crsh_core::{ParamValue, NO_HIT};
    use crsh_scene::Camera;

    fn raster(scene: &Arc<Scene>) -> Raster {
        Raster::new(scene, &StageSpec::new("raster")).unwrap()
    }

    fn raycast(scene: &Arc<Scene>) -> RayCast {
        let mut s = StageSpec::new("raycast");
        s.params
            .insert("accel".into(), ParamValue::Str("bvh".into()));
        RayCast::new(scene, &s).unwrap()
    }

    /// Distance (f64) from the pixel-centre ray's crossing of triangle `tri`'s plane to the
    /// triangle's nearest edge, relative to the crossing distance (an angle), and that distance.
    fn edge_angle_and_t(scene: &Scene, o: Vec3, d: Vec3, tri: u32) -> Option<(f64, f64)> {
        let [a, b, c] = scene.triangle(tri as usize).map(|v| v.as_dvec3());
        let (o, d) = (o.as_dvec3(), d.as_dvec3().normalize());
        let n = (b - a).cross(c - a);
        let denom = n.dot(d);
        if denom == 0.0 {
            return Some((0.0, f64::INFINITY));
        }
        let t = n.dot(a - o) / denom;
        let p = o + d * t;
        let seg = |x: DVec3, y: DVec3| {
            let e = y - x;
            let s = ((p - x).dot(e) / e.length_squared()).clamp(0.0, 1.0);
            (x + e * s - p).length()
        };
        let dist = seg(a, b).min(seg(b, c)).min(seg(c, a));
        Some((dist / t.abs().max(1e-300), t))
    }

    /// Compares raster and ray-cast G-buffers pixel by pixel: texels agree bit for bit where
    /// both see the same triangle; every other pixel must be explained by an edge passing
    /// within `edge_tol` (radians) of the pixel-centre ray, or by a depth tie, and there may be
    /// at most `max_fraction` of them. Returns the number of mismatches.
    fn compare_at_most(scene: &Arc<Scene>, width: u32, height: u32, max_fraction: f64) -> usize {
        let mut stats = Stats::default();
        let gr = raster(scene)
            .gbuffer(&Cpu, width, height, &mut stats)
            .unwrap();
        let gc = raycast(scene)
            .gbuffer(&Cpu, width, height, &mut stats)
            .unwrap();
        // One pixel subtends about 2·tan(fov/2)/height; snapping moves edges by 1/512 pixel.
        let pixel_angle =
            2.0 * (scene.camera.vfov_deg.to_radians() as f64 * 0.5).tan() / height as f64;
        let edge_tol = pixel_angle * 0.02;
        let mut mismatches = 0;
        let mut hits = 0;
        for (p, (r, c)) in gr.iter().zip(&gc).enumerate() {
            hits += c.is_hit() as usize;
            if r.tri == c.tri {
                assert_eq!(r, c, "pixel {p}: same triangle, different texel");
                continue;
            }
            mismatches += 1;
            let (o, d) = camera_ray(
                &scene.camera,
                p as u32 % width,
                p as u32 / width,
                width,
                height,
            );
            let info = |tri: u32| {
                (tri != NO_HIT)
                    .then(|| edge_angle_and_t(scene, o, d, tri))
                    .flatten()
            };
            let (ir, ic) = (info(r.tri), info(c.tri));
            let near_edge = [ir, ic]
                .iter()
                .flatten()
                .any(|&(angle, _)| angle <= edge_tol);
            let depth_tie = matches!((ir, ic), (Some((_, tr)), Some((_, tc))) if (tr - tc).abs() <= 1e-5 * tr.abs().max(tc.abs()));
            assert!(
                near_edge || depth_tie,
                "pixel {p} ({}, {}): raster sees {} ({ir:?}), ray cast {} ({ic:?}); tolerance {edge_tol}",
                p as u32 % width,
                p as u32 / width,
                r.tri,
                c.tri
            );
        }
        assert!(
            hits > (width * height / 10) as usize,
            "the view must show geometry: {hits} hits"
        );
        let fraction = mismatches as f64 / (width * height) as f64;
        assert!(
            fraction <= max_fraction,
            "{mismatches} mismatches ({fraction})"
        );
        mismatches
    }

    /// [`compare_at_most`] allowing mismatches on 0.5% of the pixels.
    fn compare(scene: &Arc<Scene>, width: u32, height: u32) -> usize {
        compare_at_most(scene, width, height, 0.005)
    }

    /// A few boxes and a ground quad built with the scene builder, seen from `eye`.
    fn boxes(eye: Vec3, target: Vec3, vfov: f32) -> Arc<Scene> {
        let mut b = crsh_scene::SceneBuilder::new("boxes");
        let m = b.material(crsh_scene::Material::default());
        let quad = |b: &mut crsh_scene::SceneBuilder, name: &str, p: [Vec3; 4]| {
            b.mesh(name, &p, None, &[[0, 1, 2], [0, 2, 3]], m);
        };
        quad(
            &mut b,
            "ground",
            [
                Vec3::new(-5.0, 0.0, -5.0),
                Vec3::new(-5.0, 0.0, 5.0),
                Vec3::new(5.0, 0.0, 5.0),
                Vec3::new(5.0, 0.0, -5.0),
            ],
        );
        for (i, (c, h)) in [
            (Vec3::new(-1.0, 0.0, 0.0), 1.0f32),
            (Vec3::new(1.2, 0.0, -0.5), 2.0),
            (Vec3::new(0.3, 0.0, 1.5), 0.6),
        ]
        .into_iter()
        .enumerate()
        {
            let s = 0.5;
            let v = |x: f32, y: f32, z: f32| c + Vec3::new(x * s, y * h, z * s);
            let corners = [
                v(-1.0, 0.0, -1.0),
                v(1.0, 0.0, -1.0),
                v(1.0, 0.0, 1.0),
                v(-1.0, 0.0, 1.0),
                v(-1.0, 1.0, -1.0),
                v(1.0, 1.0, -1.0),
                v(1.0, 1.0, 1.0),
                v(-1.0, 1.0, 1.0),
            ];
            let faces: [[u32; 3]; 12] = [
                [0, 2, 1],
                [0, 3, 2],
                [4, 5, 6],
                [4, 6, 7],
                [0, 1, 5],
                [0, 5, 4],
                [1, 2, 6],
                [1, 6, 5],
                [2, 3, 7],
                [2, 7, 6],
                [3, 0, 4],
                [3, 4, 7],
            ];
            b.mesh(format!("box{i}"), &corners, None, &faces, m);
        }
        b.camera(Camera {
            eye,
            target,
            up: Vec3::Y,
            vfov_deg: vfov,
            aspect: None,
        });
        Arc::new(b.build("test boxes").unwrap())
    }

    #[test]
    fn raster_matches_raycast_on_boxes() {
        let scene = boxes(Vec3::new(3.0, 2.5, 5.0), Vec3::new(0.0, 0.5, 0.0), 50.0);
        compare(&scene, 96, 64);
    }

    #[test]
    fn raster_matches_raycast_with_geometry_behind_and_crossing_the_camera() {
        // The eye sits inside the ground's extent, low, looking across it: the ground and the
        // boxes cross the near plane and extend behind the camera.
        let scene = boxes(Vec3::new(0.0, 0.3, 2.5), Vec3::new(0.0, 0.3, -3.0), 90.0);
        compare(&scene, 64, 48);
        let scene = boxes(Vec3::new(0.3, 0.3, 1.5), Vec3::new(1.0, 0.5, -3.0), 100.0);
        compare(&scene, 48, 48);
    }

    #[test]
    fn raster_matches_raycast_on_builtin_scenes() {
        for name in ["cornell-mirrors", "office-boxes"] {
            let scene = match crsh_scene::builtin::build(name) {
                Ok(s) => Arc::new(s),
                Err(e) => panic!("built-in scene {name}: {e}"),
            };
            let n = compare(&scene, 80, 60);
            println!("{name}: {n} explained edge mismatches of {}", 80 * 60);
        }
    }

    #[test]
    fn top_left_rule_shares_edges_exactly() {
        // A grid of unit quads (two triangles each) seen head-on at half a unit per pixel:
        // pixel centres fall exactly on grid lines, vertices and diagonals, and each must be
        // covered exactly once, nothing missed, nothing drawn twice.
        let n = 8u32;
        let mut positions = Vec::new();
        let mut indices = Vec::new();
        for j in 0..n {
            for i in 0..n {
                let b = positions.len() as u32;
                let (x, y) = (i as f32 - 3.75, j as f32 - 3.75);
                positions.extend([
                    Vec3::new(x, y, 0.0),
                    Vec3::new(x + 1.0, y, 0.0),
                    Vec3::new(x + 1.0, y + 1.0, 0.0),
                    Vec3::new(x, y + 1.0, 0.0),
                ]);
                indices.extend([[b, b + 1, b + 2], [b, b + 2, b + 3]]);
            }
        }
        let np = positions.len();
        let mut scene = raw_scene(positions, vec![Vec3::Z; np], indices);
        // The view spans [-5, 5]² at z = 0 in 20 pixels: pixel centres at -4.75 + 0.5·k.
        scene.camera = Camera {
            eye: Vec3::new(0.0, 0.0, 1000.0),
            target: Vec3::ZERO,
            up: Vec3::Y,
            vfov_deg: 2.0 * (5.0f64 / 1000.0).atan().to_degrees() as f32,
            aspect: None,
        };
        let scene = Arc::new(scene);
        let vis = raster(&scene).visibility(20, 20).unwrap();
        // The grid spans [-3.75, 4.25]²: columns 2..18 (the left edge at x = -3.75 is
        // included, the right one at 4.25 is not) and, as screen y grows downwards, rows
        // 1..17 (the top edge at world y = 4.25 included, the bottom one excluded).
        let mut covered = 0;
        for y in 0..20u32 {
            for x in 0..20u32 {
                let h = vis[(y * 20 + x) as usize];
                let inside = (2..18).contains(&x) && (1..17).contains(&y);
                assert_eq!(h.is_hit(), inside, "pixel ({x}, {y})");
                covered += h.is_hit() as usize;
            }
        }
        assert_eq!(covered, 16 * 16);
        // Every pixel centre lies on an edge here, so the ray caster's inclusive
        // Möller-Trumbore may pick the other triangle of an edge anywhere; all such
        // differences must still be explained by the edge.
        compare_at_most(&scene, 20, 20, 1.0);
    }

    #[test]
    fn same_result_for_any_thread_count() {
        let scene = boxes(Vec3::new(3.0, 2.5, 5.0), Vec3::new(0.0, 0.5, 0.0), 50.0);
        let r = raster(&scene);
        let a = crate::with_threads(1, || {
            r.gbuffer(&Cpu, 50, 37, &mut Stats::default()).unwrap()
        })
        .unwrap();
        let b = crate::with_threads(3, || {
            r.gbuffer(&Cpu, 50, 37, &mut Stats::default()).unwrap()
        })
        .unwrap();
        assert_eq!(a, b);
    }

    #[test]
    fn depth_ties_go_to_the_lower_id() {
        // The same quad twice (ids 0-1 and 2-3), then a nearer one covering the left half.
        let p = vec![
            Vec3::new(-1.0, -1.0, 0.0),
            Vec3::new(1.0, -1.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(-1.0, 1.0, 0.0),
            Vec3::new(-1.0, -1.0, 0.5),
            Vec3::new(0.0, -1.0, 0.5),
            Vec3::new(0.0, 1.0, 0.5),
            Vec3::new(-1.0, 1.0, 0.5),
        ];
        let idx = vec![
            [0, 1, 2],
            [0, 2, 3],
            [0, 1, 2],
            [0, 2, 3],
            [4, 5, 6],
            [4, 6, 7],
        ];
        let mut scene = raw_scene(p, vec![Vec3::Z; 8], idx);
        scene.camera.vfov_deg = 20.0;
        let scene = Arc::new(scene);
        let vis = raster(&scene).visibility(32, 32).unwrap();
        assert!(vis.iter().all(|h| h.tri != 2 && h.tri != 3));
        assert!(vis.iter().any(|h| h.tri == 4 || h.tri == 5));
        assert!(vis.iter().any(|h| h.tri == 0 || h.tri == 1));
        compare(&scene, 32, 32);
    }

    #[test]
    fn bad_sizes_and_cameras_are_errors() {
        let scene = boxes(Vec3::new(3.0, 2.5, 5.0), Vec3::ZERO, 50.0);
        let r = raster(&scene);
        assert!(r.gbuffer(&Cpu, 0, 4, &mut Stats::default()).is_err());
        let mut bad = (*scene).clone();
        bad.camera.up = (bad.camera.target - bad.camera.eye).normalize();
        assert!(raster(&Arc::new(bad))
            .gbuffer(&Cpu, 4, 4, &mut Stats::default())
            .is_err());
    }
}
