//! Whitted secondary rays: shadow, reflection and refraction (seed 000 §3.2.3, eq. 3.1-3.7).
//!
//! Rays are created from the [`Surface`] records of the previous pass (the G-buffer after
//! primary visibility, or the path vertices found by the last reflection / refraction batch).
//! Background records spawn nothing. The output is compacted and in surface order; shadow rays
//! are light-major (every ray of light 0 in surface order, then light 1, ...), so that rays of
//! one light, which share an origin in the thesis's convention, stay together for a ray-space
//! hierarchy built in generation order (RAH). [`Ray::source`] indexes the surface buffer, so
//! the shader can find the surface each ray belongs to.
//!
//! # Ray kinds
//!
//! - **Shadow** (eq. 3.1-3.2): one ray per light for every shaded point. With
//!   `shadow_origin = light` (the thesis's convention, the default) the ray starts at the light
//!   and points at the surface (`o = l`, `d = (p − o)/|p − o|`), so all shadow rays of a light
//!   share their origin, which is what the thesis's shadow-ray hash exploits. With
//!   `shadow_origin = surface` it starts at the (offset) surface point and points at the light.
//!   Both conventions test the same segment, so the image is the same; only coherence differs.
//!   With `cull_backfacing = true` (default) no ray is made when the light lies on or behind
//!   the plane of the surface's geometric normal: the shader gives such a light no contribution
//!   whatever the ray finds (see [`crate::shade::phong`]), so culling changes no pixel.
//!   [`Ray::light`] holds the light index.
//! - **Reflection** (eq. 3.3-3.4): `d = i − 2 n (n · i)` with the incident direction `i` and the
//!   interpolated shading normal `n`, for materials with reflectivity > 0; throughput is the
//!   surface's throughput × reflectivity.
//! - **Refraction** (eq. 3.5-3.7): `k = 1 − ri² (1 − (i · n)²)`,
//!   `d = ri i − n (ri (i · n) + √k)`, for materials with transparency > 0; `ri = 1 / ior` when
//!   the arriving ray hit the front face ([`Surface::FRONT_FACE`], entering the object) and
//!   `ri = ior` when it hit the back face (leaving it). When `k < 0` the ray is totally
//!   internally reflected: it takes the mirror direction of eq. 3.4 but **keeps the kind
//!   Refraction** (it carries the transparency weight and counts as a refraction ray);
//!   throughput is the surface's throughput × transparency.
//!
//! Every ray's depth is the surface's depth + 1, its pixel the surface's pixel.
//!
//! # Throughput culling
//!
//! A ray whose throughput's largest component is below `min_throughput` (default 1e-3) is not
//! spawned. A shadow ray's throughput is the weight its light's contribution gets in the image:
//! the surface's throughput × the material's local weight `max(0, 1 − reflectivity −
//! transparency)`, so a perfect mirror or a perfectly clear surface casts no shadow rays (the
//! shader gives them no direct light anyway).
//!
//! # Epsilon policy
//!
//! A secondary ray must not find the surface it leaves. With `off = epsilon × |scene bounding
//! box diagonal|` (param `epsilon`, default 1e-5, relative so that it scales with the scene):
//! - the origin of a reflection or refraction ray is the hit point moved by `off` along the
//!   geometric normal, to the side the ray leaves into (the sign of `d · n_geo`), and its
//!   interval starts at `t_min = off`;
//! - a shadow ray's surface end point is the hit point moved by `off` along the geometric
//!   normal towards the light; the interval is `(off, |segment| − off)`, so it excludes both the
//!   light and the surface by the same distance (a light sitting on a wall does not shadow
//!   itself). When the light is closer than `2 off` the interval is empty and the light is
//!   seen.
//!
//! The offset moves along the *geometric* normal because the shading normal may tilt away from
//! the face; the distance is relative so that one default serves a Cornell box (size ~2) and
//! Sponza (size ~4000). A reflection direction computed from a tilted shading normal may point
//! slightly below the face; it is followed as eq. 3.4 gives it (the origin then moves to the
//! back side), not bent.
//!
//! The policy lives in one function, [`epsilon_segment`].

use std::sync::Arc;
use std::time::Instant;

use crsh_core::glam::Vec3;
use crsh_core::{CoreError, Ray, RayGen, RayKind, Result, StageSpec, Stats, Surface};
use crsh_scene::Scene;
use rayon::prelude::*;

use crate::backend::Cpu;
use crate::trim::trim;

/// Surfaces per parallel work item.
const CHUNK: usize = 4096;

/// Where shadow rays start.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ShadowOrigin {
    /// At the light, pointing at the surface (the thesis's convention, eq. 3.1-3.2).
    Light,
    /// At the surface point, pointing at the light.
    Surface,
}

/// The per-material data ray generation needs.
#[derive(Clone, Copy, Debug)]
struct MatRays {
    reflectivity: f32,
    transparency: f32,
    ior: f32,
}

impl MatRays {
    fn local_weight(&self) -> f32 {
        (1.0 - self.reflectivity - self.transparency).max(0.0)
    }
}

/// The Whitted ray generator (seed 000 §3.2.3, eq. 3.1-3.7). See the module docs for the
/// conventions and the epsilon policy.
#[derive(Clone, Debug)]
pub struct Whitted {
    lights: Vec<Vec3>,
    materials: Vec<MatRays>,
    shadow_origin: ShadowOrigin,
    cull_backfacing: bool,
    min_throughput: f32,
    offset: f32,
}

/// Where a secondary ray goes, relative to the surface point it belongs to.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Leg {
    /// Away from the surface along a direction, unbounded (reflection, refraction).
    Along(Vec3),
    /// From the surface to a point (a shadow ray with `shadow_origin = surface`).
    To(Vec3),
    /// From a point to the surface (a shadow ray with `shadow_origin = light`, eq. 3.1-3.2).
    From(Vec3),
}

/// A ray's origin, unit direction and open interval `(t_min, t_max)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Segment {
    /// Origin.
    pub origin: Vec3,
    /// Unit direction.
    pub dir: Vec3,
    /// Start of the interval.
    pub t_min: f32,
    /// End of the interval (infinite for [`Leg::Along`]).
    pub t_max: f32,
}

/// The epsilon policy, in one function (see the module docs): the segment of the ray `leg`
/// from or to the surface point `p` with unit geometric normal `geo_normal`, where `off` is
/// `epsilon × scene diagonal`. The surface end is `p` moved by `off` along `geo_normal` to the
/// side the ray leaves into (the front side for a ray parallel to the surface); `t_min = off`,
/// and a bounded segment also stops `off` short of its far end (`t_max ≥ t_min`). `None` when
/// the direction is zero or not finite (a light at the surface point).
pub fn epsilon_segment(p: Vec3, geo_normal: Vec3, leg: Leg, off: f32) -> Option<Segment> {
    let leaving = match leg {
        Leg::Along(d) => d,
        Leg::To(q) | Leg::From(q) => q - p,
    };
    let side = if leaving.dot(geo_normal) < 0.0 {
        -off
    } else {
        off
    };
    let start = p + geo_normal * side;
    let (origin, seg, bounded) = match leg {
        Leg::Along(d) => (start, d, false),
        Leg::To(q) => (start, q - start, true),
        Leg::From(q) => (q, start - q, true),
    };
    let dir = seg.normalize_or_zero();
    if dir == Vec3::ZERO || !dir.is_finite() {
        return None;
    }
    let t_max = if bounded {
        (seg.length() - off).max(off)
    } else {
        f32::INFINITY
    };
    Some(Segment {
        origin,
        dir,
        t_min: off,
        t_max,
    })
}

/// Mirror reflection of the incident direction `i` about the normal `n` (eq. 3.4):
/// `i − 2 n (n · i)`.
pub fn reflect(i: Vec3, n: Vec3) -> Vec3 {
    i - 2.0 * n * n.dot(i)
}

/// Refraction of the unit incident direction `i` through the unit normal `n` (on the incident
/// side, `n · i ≤ 0`) with the ratio of indices `ri = η_from / η_to` (eq. 3.6-3.7):
/// `k = 1 − ri² (1 − (i · n)²)`, `d = ri i − n (ri (i · n) + √k)`. `None` when `k < 0` (total
/// internal reflection).
pub fn refract(i: Vec3, n: Vec3, ri: f32) -> Option<Vec3> {
    let cos_i = i.dot(n);
    let k = 1.0 - ri * ri * (1.0 - cos_i * cos_i);
    if k < 0.0 {
        None
    } else {
        Some(i * ri - n * (ri * cos_i + k.sqrt()))
    }
}

/// The refraction direction of a Whitted refraction ray: eq. 3.7 with `ri = 1 / ior` through a
/// front face and `ri = ior` through a back face, or the mirror direction (eq. 3.4) under total
/// internal reflection. The result is unit length (or zero for degenerate input).
pub fn refraction_direction(incident: Vec3, normal: Vec3, ior: f32, front_face: bool) -> Vec3 {
    let ri = if front_face { 1.0 / ior } else { ior };
    refract(incident, normal, ri)
        .unwrap_or_else(|| reflect(incident, normal))
        .normalize_or_zero()
}

impl Whitted {
    /// A generator for `scene` with the parameters of a resolved `spec`: `shadow_origin`
    /// (`light`|`surface`), `cull_backfacing` (bool), `min_throughput` (≥ 0) and `epsilon`
    /// (relative to the scene's bounding-box diagonal, in `[0, 0.1]`).
    pub fn new(scene: &Arc<Scene>, spec: &StageSpec) -> Result<Self> {
        let shadow_origin = match spec.str("shadow_origin")? {
            "light" => ShadowOrigin::Light,
            "surface" => ShadowOrigin::Surface,
            other => {
                return Err(CoreError::InvalidParam {
                    key: "raygen.shadow_origin".into(),
                    reason: format!("`{other}` is not one of light, surface"),
                })
            }
        };
        let cull_backfacing = spec.bool("cull_backfacing")?;
        let min_throughput = spec.f64("min_throughput")?;
        if !min_throughput.is_finite() || min_throughput < 0.0 {
            return Err(CoreError::InvalidParam {
                key: "raygen.min_throughput".into(),
                reason: format!("{min_throughput} must be a finite number ≥ 0"),
            });
        }
        let epsilon = spec.f64("epsilon")?;
        if !epsilon.is_finite() || !(0.0..=0.1).contains(&epsilon) {
            return Err(CoreError::InvalidParam {
                key: "raygen.epsilon".into(),
                reason: format!("{epsilon} is outside 0..=0.1 (a fraction of the scene diagonal)"),
            });
        }
        let diagonal = scene.bounds.diagonal();
        if !diagonal.is_finite() {
            return Err(CoreError::InvalidInput(format!(
                "scene `{}` has non-finite bounds",
                scene.name
            )));
        }
        let mut materials = Vec::with_capacity(scene.materials.len());
        for m in &scene.materials {
            if m.transparency > 0.0 && !(m.ior.is_finite() && m.ior > 0.0) {
                return Err(CoreError::InvalidInput(format!(
                    "material `{}` is transparent with index of refraction {}",
                    m.name, m.ior
                )));
            }
            if !(m.reflectivity.is_finite() && m.transparency.is_finite()) {
                return Err(CoreError::InvalidInput(format!(
                    "material `{}` has non-finite reflectivity or transparency",
                    m.name
                )));
            }
            materials.push(MatRays {
                reflectivity: m.reflectivity,
                transparency: m.transparency,
                ior: m.ior,
            });
        }
        let lights = scene.lights.iter().map(|l| l.position).collect::<Vec<_>>();
        if let Some(l) = lights.iter().find(|p| !p.is_finite()) {
            return Err(CoreError::InvalidInput(format!(
                "light at {l} is not finite"
            )));
        }
        Ok(Whitted {
            lights,
            materials,
            shadow_origin,
            cull_backfacing,
            min_throughput: min_throughput as f32,
            offset: (epsilon * diagonal as f64) as f32,
        })
    }

    /// The absolute offset distance of the epsilon policy (`epsilon × scene diagonal`).
    pub fn offset(&self) -> f32 {
        self.offset
    }

    fn keeps(&self, throughput: Vec3) -> bool {
        throughput.max_element() >= self.min_throughput && throughput.is_finite()
    }

    /// The shadow ray from surface `s` (index `source`) to light `light`, if one is needed.
    fn shadow_ray(&self, source: u32, s: &Surface, m: &MatRays, light: u32) -> Option<Ray> {
        let l = self.lights[light as usize];
        let to_light = l - s.position;
        if self.cull_backfacing && to_light.dot(s.geo_normal) <= 0.0 {
            return None;
        }
        let throughput = s.throughput * m.local_weight();
        if !self.keeps(throughput) {
            return None;
        }
        let leg = match self.shadow_origin {
            ShadowOrigin::Light => Leg::From(l),
            ShadowOrigin::Surface => Leg::To(l),
        };
        // `None`: the light sits on the surface point; nothing can lie in between.
        let seg = epsilon_segment(s.position, s.geo_normal, leg, self.offset)?;
        Some(Ray {
            origin: seg.origin,
            t_min: seg.t_min,
            dir: seg.dir,
            t_max: seg.t_max,
            throughput,
            kind: RayKind::Shadow as u32,
            pixel: s.pixel,
            light,
            depth: s.depth + 1,
            source,
        })
    }

    /// The reflection (eq. 3.3-3.4) or refraction (eq. 3.5-3.7) ray from surface `s`.
    fn bounce_ray(&self, source: u32, s: &Surface, m: &MatRays, kind: RayKind) -> Option<Ray> {
        let (weight, dir) = match kind {
            RayKind::Reflection if m.reflectivity > 0.0 => (
                m.reflectivity,
                reflect(s.incident, s.normal).normalize_or_zero(),
            ),
            RayKind::Refraction if m.transparency > 0.0 => (
                m.transparency,
                refraction_direction(s.incident, s.normal, m.ior, s.front_face()),
            ),
            _ => return None,
        };
        let throughput = s.throughput * weight;
        if !self.keeps(throughput) {
            return None;
        }
        let seg = epsilon_segment(s.position, s.geo_normal, Leg::Along(dir), self.offset)?;
        Some(Ray {
            origin: seg.origin,
            t_min: seg.t_min,
            dir: seg.dir,
            t_max: seg.t_max,
            throughput,
            kind: kind as u32,
            pixel: s.pixel,
            light: u32::MAX,
            depth: s.depth + 1,
            source,
        })
    }

    /// The rays of `kind` spawned by `surfaces`, compacted, in surface order, light-major for
    /// shadow rays (see the module docs): [`Whitted::slots`], then [`crate::trim::trim`].
    /// Primary rays are not made here: asking for them is an error.
    pub fn rays(&self, surfaces: &[Surface], kind: RayKind) -> Result<Vec<Ray>> {
        let (slots, flags) = self.slots(surfaces, kind)?;
        trim(&slots, &flags)
    }

    /// Ray creation before trimming (§3.2.3): one slot per surface (per light and surface,
    /// light-major, for shadow rays) and its head flag, 1 where the slot holds a ray and 0
    /// where the surface spawns none (background, culled light, absorbed bounce); empty
    /// slots hold a zeroed ray.
    pub fn slots(&self, surfaces: &[Surface], kind: RayKind) -> Result<(Vec<Ray>, Vec<u32>)> {
        if kind == RayKind::Primary {
            return Err(CoreError::Unsupported {
                stage: "raygen",
                variant: "whitted".into(),
                what: "primary rays (primary visibility makes those)".into(),
            });
        }
        let per_surface = if kind == RayKind::Shadow {
            self.lights.len()
        } else {
            1
        };
        let total = surfaces.len().checked_mul(per_surface);
        if surfaces.len() > u32::MAX as usize || total.is_none_or(|t| t > u32::MAX as usize) {
            return Err(CoreError::InvalidInput(format!(
                "{} surfaces × {per_surface} rays do not fit 32-bit ray indices",
                surfaces.len()
            )));
        }
        if let Some(s) = surfaces
            .par_iter()
            .find_first(|s| s.is_hit() && s.material as usize >= self.materials.len())
        {
            return Err(CoreError::InvalidInput(format!(
                "surface of pixel {} has material {} but the scene has {}",
                s.pixel,
                s.material,
                self.materials.len()
            )));
        }
        let n = surfaces.len();
        let mut slots = vec![<Ray as bytemuck::Zeroable>::zeroed(); n * per_surface];
        let mut flags = vec![0u32; n * per_surface];
        slots
            .par_chunks_mut(CHUNK)
            .zip(flags.par_chunks_mut(CHUNK))
            .enumerate()
            .for_each(|(c, (rays, heads))| {
                for (j, (ray, head)) in rays.iter_mut().zip(heads.iter_mut()).enumerate() {
                    let slot = c * CHUNK + j;
                    let (source, light) = (slot % n, slot / n);
                    let s = &surfaces[source];
                    if !s.is_hit() {
                        continue;
                    }
                    let m = &self.materials[s.material as usize];
                    let made = if kind == RayKind::Shadow {
                        self.shadow_ray(source as u32, s, m, light as u32)
                    } else {
                        self.bounce_ray(source as u32, s, m, kind)
                    };
                    if let Some(r) = made {
                        *ray = r;
                        *head = 1;
                    }
                }
            });
        Ok((slots, flags))
    }
}

impl RayGen<Cpu> for Whitted {
    fn name(&self) -> &str {
        "whitted"
    }

    fn generate(
        &self,
        _backend: &Cpu,
        surfaces: &Vec<Surface>,
        kind: RayKind,
        stats: &mut Stats,
    ) -> Result<Vec<Ray>> {
        let (slots, flags) = self.slots(surfaces, kind)?;
        let t = Instant::now();
        let rays = trim(&slots, &flags)?;
        stats.add_time("trimming", t.elapsed());
        Ok(rays)
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crsh_core::{ParamValue, NO_HIT};
    use crsh_scene::{Camera, Light, Material, SceneBuilder};

    /// A one-quad scene (the square `[-1, 1]²` at z = 0, normal +z) made with
    /// [`SceneBuilder`], with the given materials (the quad uses material 0) and lights. The
    /// builder validates them: a test of a stage's own checks on a material or light the
    /// builder refuses sets it on the built scene.
    pub(crate) fn quad_scene(materials: Vec<Material>, lights: Vec<Light>) -> Arc<Scene> {
        let positions = [
            Vec3::new(-1.0, -1.0, 0.0),
            Vec3::new(1.0, -1.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(-1.0, 1.0, 0.0),
        ];
        let mut b = SceneBuilder::new("quad");
        for m in materials {
            b.material(m);
        }
        for l in lights {
            b.light(l);
        }
        b.camera(Camera {
            eye: Vec3::new(0.0, 0.0, 5.0),
            target: Vec3::ZERO,
            up: Vec3::Y,
            vfov_deg: 45.0,
            aspect: None,
        });
        b.mesh(
            "quad",
            &positions,
            Some(&[Vec3::Z; 4]),
            &[[0, 1, 2], [0, 2, 3]],
            0,
        );
        Arc::new(b.build("quad test scene").unwrap())
    }

    pub(crate) fn light(position: Vec3) -> Light {
        Light {
            position,
            color: Vec3::ONE,
            intensity: 1.0,
            attenuation: [1.0, 0.0, 0.0],
        }
    }

    /// A front-facing surface record on the quad at `p`, seen along -z.
    pub(crate) fn surface(p: Vec3, pixel: u32, material: u32) -> Surface {
        Surface {
            position: p,
            tri: 0,
            normal: Vec3::Z,
            material,
            incident: -Vec3::Z,
            pixel,
            throughput: Vec3::ONE,
            depth: 0,
            geo_normal: Vec3::Z,
            flags: Surface::FRONT_FACE,
        }
    }

    fn spec(params: &[(&str, ParamValue)]) -> StageSpec {
        let mut s = StageSpec::new("whitted");
        s.params
            .insert("shadow_origin".into(), ParamValue::Str("light".into()));
        s.params
            .insert("cull_backfacing".into(), ParamValue::Bool(true));
        s.params
            .insert("min_throughput".into(), ParamValue::Float(1e-3));
        s.params.insert("epsilon".into(), ParamValue::Float(1e-5));
        for (k, v) in params {
            s.params.insert(k.to_string(), v.clone());
        }
        s
    }

    fn mirror(reflectivity: f32, transparency: f32) -> Material {
        Material {
            reflectivity,
            transparency,
            ior: 1.5,
            ..Material::default()
        }
    }

    #[test]
    fn shadow_rays_are_compacted_light_major_in_surface_order() {
        let lights = vec![
            light(Vec3::new(0.0, 0.0, 2.0)),
            light(Vec3::new(0.0, 0.0, -2.0)), // behind the quad: culled
            light(Vec3::new(1.0, 1.0, 3.0)),
        ];
        let scene = quad_scene(vec![Material::default()], lights);
        let g = Whitted::new(&scene, &spec(&[])).unwrap();
        let mut bg = Surface::background(1, -Vec3::Z, Vec3::ONE, 0);
        bg.material = 99; // ignored: background records spawn nothing
        let surfaces = [
            surface(Vec3::ZERO, 0, 0),
            bg,
            surface(Vec3::new(0.5, 0.5, 0.0), 2, 0),
        ];
        let rays = g.rays(&surfaces, RayKind::Shadow).unwrap();
        let ids: Vec<(u32, u32, u32)> = rays.iter().map(|r| (r.source, r.light, r.pixel)).collect();
        assert_eq!(ids, vec![(0, 0, 0), (2, 0, 2), (0, 2, 0), (2, 2, 2)]);
        for r in &rays {
            assert_eq!(r.ray_kind(), RayKind::Shadow);
            assert_eq!(r.depth, 1);
            assert!((r.dir.length() - 1.0).abs() < 1e-6);
            assert_eq!(r.origin, scene.lights[r.light as usize].position);
        }
        // Without culling the light behind the quad gets its ray too.
        let g = Whitted::new(
            &scene,
            &spec(&[("cull_backfacing", ParamValue::Bool(false))]),
        )
        .unwrap();
        let rays = g.rays(&surfaces, RayKind::Shadow).unwrap();
        assert_eq!(rays.len(), 6);
        // Its surface end point is offset to the light's side (below the quad).
        let r = rays.iter().find(|r| r.light == 1 && r.source == 0).unwrap();
        assert!(r.at(r.t_max).z < 0.0);
    }

    #[test]
    fn both_shadow_conventions_test_the_same_segment() {
        let scene = quad_scene(
            vec![Material::default()],
            vec![light(Vec3::new(0.3, -0.4, 1.2))],
        );
        let s = [surface(Vec3::new(0.1, 0.2, 0.0), 0, 0)];
        let a = Whitted::new(&scene, &spec(&[]))
            .unwrap()
            .rays(&s, RayKind::Shadow)
            .unwrap()[0];
        let b = Whitted::new(
            &scene,
            &spec(&[("shadow_origin", ParamValue::Str("surface".into()))]),
        )
        .unwrap()
        .rays(&s, RayKind::Shadow)
        .unwrap()[0];
        assert!((a.at(a.t_min) - b.at(b.t_max)).length() < 1e-6);
        assert!((a.at(a.t_max) - b.at(b.t_min)).length() < 1e-6);
        assert!((a.dir + b.dir).length() < 1e-6);
    }

    #[test]
    fn throughput_culling_and_weights() {
        let lights = vec![light(Vec3::new(0.0, 0.0, 2.0))];
        let mats = vec![mirror(1.0, 0.0), mirror(0.5, 0.3), mirror(0.0005, 0.0)];
        let scene = quad_scene(mats, lights);
        let g = Whitted::new(&scene, &spec(&[])).unwrap();
        let s = [
            surface(Vec3::ZERO, 0, 0),
            surface(Vec3::ZERO, 1, 1),
            surface(Vec3::ZERO, 2, 2),
        ];
        // A perfect mirror has no local weight: no shadow ray.
        let shadow = g.rays(&s, RayKind::Shadow).unwrap();
        assert_eq!(
            shadow.iter().map(|r| r.source).collect::<Vec<_>>(),
            vec![1, 2]
        );
        assert!((shadow[0].throughput - Vec3::splat(0.2)).length() < 1e-6);
        // Reflectivity 0.0005 is below min_throughput.
        let refl = g.rays(&s, RayKind::Reflection).unwrap();
        assert_eq!(
            refl.iter().map(|r| r.source).collect::<Vec<_>>(),
            vec![0, 1]
        );
        assert_eq!(refl[1].throughput, Vec3::splat(0.5));
        let refr = g.rays(&s, RayKind::Refraction).unwrap();
        assert_eq!(refr.len(), 1);
        assert!((refr[0].throughput - Vec3::splat(0.3)).length() < 1e-6);
        assert_eq!(refr[0].light, u32::MAX);
        // Refraction rays leave below the surface, reflection rays above.
        assert!(refr[0].origin.z < 0.0 && refl[0].origin.z > 0.0);
        assert_eq!(refl[0].t_min, g.offset());
        assert!((g.offset() - 1e-5 * 8f32.sqrt()).abs() < 1e-9);
    }

    #[test]
    fn epsilon_segments() {
        let (p, n, off) = (Vec3::new(1.0, 2.0, 3.0), Vec3::Y, 0.01);
        let l = Vec3::new(1.0, 7.0, 3.0);
        let to = epsilon_segment(p, n, Leg::To(l), off).unwrap();
        assert_eq!(to.origin, Vec3::new(1.0, 2.01, 3.0));
        assert_eq!((to.dir, to.t_min), (Vec3::Y, off));
        assert!((to.t_max - (4.99 - off)).abs() < 1e-5);
        let from = epsilon_segment(p, n, Leg::From(l), off).unwrap();
        assert_eq!((from.origin, from.dir), (l, -Vec3::Y));
        assert!((from.t_max - to.t_max).abs() < 1e-5);
        // Leaving through the back: the origin moves below.
        let down = epsilon_segment(p, n, Leg::Along(-Vec3::Y), off).unwrap();
        assert_eq!(down.origin, Vec3::new(1.0, 1.99, 3.0));
        assert_eq!(down.t_max, f32::INFINITY);
        // A light closer than 2·off: empty interval (nothing between), not a negative one.
        let near = epsilon_segment(p, n, Leg::To(p + Vec3::Y * 0.015), off).unwrap();
        assert_eq!(near.t_max, near.t_min);
        assert!(epsilon_segment(p, n, Leg::From(p + n * off), off).is_none());
        assert!(epsilon_segment(p, n, Leg::Along(Vec3::ZERO), off).is_none());
    }

    #[test]
    fn bad_input_is_an_error() {
        let scene = quad_scene(vec![Material::default()], vec![light(Vec3::Z)]);
        for bad in [
            ("epsilon", ParamValue::Float(-1.0)),
            ("epsilon", ParamValue::Float(0.5)),
            ("min_throughput", ParamValue::Float(f64::NAN)),
            ("shadow_origin", ParamValue::Str("moon".into())),
            ("cull_backfacing", ParamValue::Int(1)),
        ] {
            assert!(
                Whitted::new(&scene, &spec(std::slice::from_ref(&bad))).is_err(),
                "{bad:?}"
            );
        }
        let g = Whitted::new(&scene, &spec(&[])).unwrap();
        let mut s = surface(Vec3::ZERO, 0, 0);
        s.material = 7;
        assert!(g.rays(&[s], RayKind::Shadow).is_err());
        assert!(g.rays(&[], RayKind::Primary).is_err());
        let glass = Material {
            transparency: 1.0,
            ior: 0.0,
            ..Material::default()
        };
        // The scene builder refuses an index of refraction of 0 (`Material::validate`): put
        // the material on a built scene to reach the stage's own check.
        let mut scene = (*quad_scene(vec![Material::default()], vec![])).clone();
        scene.materials[0] = glass;
        assert!(Whitted::new(&Arc::new(scene), &spec(&[])).is_err());
        assert_eq!(NO_HIT, Surface::background(0, Vec3::Z, Vec3::ONE, 0).tri);
    }
}
