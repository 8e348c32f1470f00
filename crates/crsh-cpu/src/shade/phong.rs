//! Phong shading with attenuation and shadows (seed 000 eq. 3.17-3.19), and path-vertex
//! resolution.
//!
//! # Direct light ([`Phong::shade_direct`])
//!
//! For every surface record that holds a hit, and every light that is visible from it, eq.
//! 3.19 weighted by the light's visibility. The visibility of a light from a surface is the
//! mean over its shadow rays (one for hard shadows, several for sampled soft shadows) of 1 for
//! a ray that found no occluder, 0 for an any-hit ray that found one (as in the thesis, any
//! occluder blocks the light fully, transparent ones included) and `1 − occlusion` for an
//! edge-width ray (seed 003 §5, eq. 5.1, [`crsh_core::HitMode::EdgeWidth`]). A light without a
//! shadow ray (ray generation culled it) contributes nothing. With one any-hit ray per light
//! the visibility is 0 or 1 and the image is exactly the hard-shadow one:
//!
//! ```text
//! l     = (light − p) / |light − p|                        (3.19a)
//! dist  = |light − p|                                      (3.19b)
//! att   = 1 / (c + dist · lin + dist² · quad)              (3.19c)
//! v     = incident direction of the ray that found p       (3.19d)
//! h     = (l − v) / |l − v|                                (3.19e)
//! fd    = clamp(l · n, 0, 1)                               (3.19f)
//! fs    = clamp(max(0, h · n)^shininess, 0, 1)             (3.19g)
//! color += diffuse  · light_color · fd · intensity · att   (3.19h)
//! color += specular · light_color · fs · intensity · att   (3.19i)
//! ```
//!
//! with `n` the interpolated shading normal (eq. 3.17-3.18, facing the incoming ray). For a
//! primary surface the incident direction is the camera ray, so `v` is exactly eq. 3.19d; for
//! deeper path vertices it is the reflection / refraction ray that arrived.
//!
//! Two conventions the thesis leaves open, both standard:
//! - A light on or behind the plane of the **geometric** normal lights nothing (it would be
//!   self-shadowed by the triangle itself). This makes the ray generator's `cull_backfacing`
//!   a pure optimisation: culled or not, the image is the same.
//! - The specular term is zero when `fd = 0` (Blinn-Phong convention: no highlight from a light
//!   below the shading horizon).
//!
//! The local colour is then `ambient · diffuse + Σ lights`, where `ambient` is a parameter
//! (default 0.05: a little fill light so that shadowed regions are not black; set it to 0 for
//! the thesis's formula exactly). It is weighted by the record's throughput and the material's
//! local weight `max(0, 1 − reflectivity − transparency)`: the rest of the energy is carried
//! by the reflection and refraction rays, whose throughput holds those weights. A surface whose
//! material has an emission colour (MTL `Ke`, e.g. the Cornell box's lamp panel, which is not
//! itself a light) also shows `emission × throughput`, unweighted (not in the thesis, which has
//! no emitters; zero for ordinary materials). A background
//! record (a pixel or ray that saw nothing) adds `background` (a grey level, default 0) × its
//! throughput.
//!
//! # Accumulation
//!
//! The image is linear HDR RGBA; alpha is set to 1 for every pixel any record (hit or
//! background) was shaded for. Contributions are computed in parallel, one per record, and
//! then added to their pixels sequentially in record order, so the result does not depend on
//! the thread count.
//!
//! # Resolution ([`Phong::resolve`])
//!
//! A reflection or refraction ray and its nearest hit become the next path vertex through
//! [`crate::surface::surface_from_hit`] (barycentric normal interpolation, eq. 3.17-3.18), with
//! the ray's pixel, throughput and depth; a miss becomes a background record.

use std::sync::Arc;

use crsh_core::glam::Vec3;
use crsh_core::{
    CoreError, Hit, HitMode, ParamInfo, Ray, Registry, Result, Shader, StageKind, StageSpec,
    StageVariantInfo, Stats, Surface,
};
use crsh_scene::Scene;
use rayon::prelude::*;

use crate::backend::Cpu;

/// The per-material data shading needs.
#[derive(Clone, Copy, Debug)]
struct MatShade {
    diffuse: Vec3,
    specular: Vec3,
    shininess: f32,
    local_weight: f32,
    emission: Vec3,
}

/// The per-light data shading needs.
#[derive(Clone, Copy, Debug)]
struct LightShade {
    position: Vec3,
    /// `color × intensity`.
    radiance: Vec3,
    attenuation: [f32; 3],
}

/// The light one point light adds at a surface point (eq. 3.19a-i), before the throughput and
/// local weights: `diffuse · light_color · fd · intensity · att + specular · light_color · fs ·
/// intensity · att`, or zero when the light is on or behind the geometric normal's plane.
///
/// `incident` is the unit direction of the ray that arrived at `p` (the view vector of eq.
/// 3.19d), `normal` the unit shading normal and `geo_normal` the unit face normal, both on the
/// side the ray came from.
#[allow(clippy::too_many_arguments)]
pub fn phong_light(
    p: Vec3,
    normal: Vec3,
    geo_normal: Vec3,
    incident: Vec3,
    diffuse: Vec3,
    specular: Vec3,
    shininess: f32,
    light: &crsh_scene::Light,
) -> Vec3 {
    let l = LightShade {
        position: light.position,
        radiance: light.color * light.intensity,
        attenuation: light.attenuation,
    };
    let m = MatShade {
        diffuse,
        specular,
        shininess,
        local_weight: 1.0,
        emission: Vec3::ZERO,
    };
    light_term(p, normal, geo_normal, incident, &m, &l)
}

/// The attenuation factor of eq. 3.19c, `1 / (c + d·lin + d²·quad)`; zero when it would not be
/// finite (a light with all-zero coefficients at its own position).
fn attenuation(coeffs: [f32; 3], d: f32) -> f32 {
    let [c, lin, quad] = coeffs;
    let a = 1.0 / (c + d * lin + d * d * quad);
    if a.is_finite() {
        a
    } else {
        0.0
    }
}

fn light_term(p: Vec3, n: Vec3, n_geo: Vec3, incident: Vec3, m: &MatShade, l: &LightShade) -> Vec3 {
    let to_light = l.position - p;
    let dist = to_light.length(); // 3.19b
    if dist <= 0.0 || !dist.is_finite() {
        return Vec3::ZERO;
    }
    let ldir = to_light / dist; // 3.19a
    if ldir.dot(n_geo) <= 0.0 {
        return Vec3::ZERO;
    }
    let att = attenuation(l.attenuation, dist); // 3.19c
    let fd = ldir.dot(n).clamp(0.0, 1.0); // 3.19f
    let fs = if fd > 0.0 {
        let h = (ldir - incident).normalize_or_zero(); // 3.19d-e
        h.dot(n).max(0.0).powf(m.shininess).clamp(0.0, 1.0) // 3.19g
    } else {
        0.0
    };
    (m.diffuse * fd + m.specular * fs) * l.radiance * att // 3.19h-i
}

/// The Phong shader (seed 000 eq. 3.17-3.19). See the module docs.
#[derive(Clone, Debug)]
pub struct Phong {
    scene: Arc<Scene>,
    materials: Vec<MatShade>,
    lights: Vec<LightShade>,
    ambient: f32,
    background: f32,
    model: Model,
}

/// The local reflection model of [`Phong::shade`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Model {
    /// Eq. 3.19 with ambient fill, weighted by the material's local weight (the `phong`
    /// shader).
    Phong,
    /// A Lambertian BRDF `diffuse / π` under each visible light (eq. 3.19h divided by π,
    /// no specular, no ambient, every material opaque): the direct light of a diffuse path
    /// vertex (the `diffuse` shader).
    Lambert,
}

/// The catalogue entry of the `phong` shader.
pub fn info() -> StageVariantInfo {
    StageVariantInfo::new(
        StageKind::Shade,
        "phong",
        "Phong with attenuation and shadows, barycentric normals, reflection and refraction \
         weighted by the material, seed 000 eq. 3.17-3.19",
    )
    .param(
        ParamInfo::float(
            "ambient",
            0.05,
            "ambient fill as a fraction of the diffuse colour (0: the thesis exactly)",
        )
        .range(0.0, f64::INFINITY),
    )
    .param(
        ParamInfo::float(
            "background",
            0.0,
            "grey level that rays missing the scene see",
        )
        .range(0.0, f64::INFINITY),
    )
}

/// Registers `phong` ([`info`], [`Phong::new`]).
pub fn register(registry: &mut Registry<Cpu>) -> Result<()> {
    registry.add_shader(info(), |ctx, spec| {
        Ok(Box::new(Phong::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

impl Phong {
    /// A shader for `scene` with the parameters of a resolved `spec`: `ambient` (≥ 0, fraction
    /// of the diffuse colour added everywhere) and `background` (≥ 0, grey level of what rays
    /// that miss everything see).
    pub fn new(scene: &Arc<Scene>, spec: &StageSpec) -> Result<Self> {
        let nonneg = |key: &str| -> Result<f32> {
            let v = spec.f64(key)?;
            if v.is_finite() && v >= 0.0 {
                Ok(v as f32)
            } else {
                Err(CoreError::InvalidParam {
                    key: format!("shade.{key}"),
                    reason: format!("{v} must be a finite number ≥ 0"),
                })
            }
        };
        let ambient = nonneg("ambient")?;
        let background = nonneg("background")?;
        let mut materials = Vec::with_capacity(scene.materials.len());
        for m in &scene.materials {
            let finite = m.diffuse.is_finite()
                && m.specular.is_finite()
                && m.shininess.is_finite()
                && m.emission.is_finite();
            if !finite {
                return Err(CoreError::InvalidInput(format!(
                    "material `{}` has non-finite colours or shininess",
                    m.name
                )));
            }
            materials.push(MatShade {
                diffuse: m.diffuse,
                specular: m.specular,
                shininess: m.shininess,
                local_weight: (1.0 - m.reflectivity - m.transparency).max(0.0),
                emission: m.emission,
            });
        }
        let mut lights = Vec::with_capacity(scene.lights.len());
        for (i, l) in scene.lights.iter().enumerate() {
            let ok = l.position.is_finite()
                && l.color.is_finite()
                && l.intensity.is_finite()
                && l.attenuation.iter().all(|a| a.is_finite() && *a >= 0.0);
            if !ok {
                return Err(CoreError::InvalidInput(format!(
                    "light {i} has non-finite values or negative attenuation coefficients"
                )));
            }
            lights.push(LightShade {
                position: l.position,
                radiance: l.color * l.intensity,
                attenuation: l.attenuation,
            });
        }
        Ok(Phong {
            scene: scene.clone(),
            materials,
            lights,
            ambient,
            background,
            model: Model::Phong,
        })
    }

    /// The same shader with the reflection model `model`.
    pub fn with_model(mut self, model: Model) -> Self {
        self.model = model;
        self
    }

    /// The scene shaded.
    pub fn scene(&self) -> &Arc<Scene> {
        &self.scene
    }

    /// The radiance record `s` adds to its pixel, given the visibility (in `[0, 1]`) of each
    /// light from it.
    fn contribution(&self, s: &Surface, visible: impl Fn(usize) -> f32) -> Vec3 {
        if !s.is_hit() {
            return s.throughput * self.background;
        }
        let m = &self.materials[s.material as usize];
        let emitted = m.emission * s.throughput;
        if self.model == Model::Lambert {
            let lambert = MatShade {
                diffuse: m.diffuse * std::f32::consts::FRAC_1_PI,
                specular: Vec3::ZERO,
                ..*m
            };
            let mut color = Vec3::ZERO;
            for (li, l) in self.lights.iter().enumerate() {
                let f = visible(li);
                if f > 0.0 {
                    color +=
                        light_term(s.position, s.normal, s.geo_normal, s.incident, &lambert, l) * f;
                }
            }
            return emitted + color * s.throughput;
        }
        if m.local_weight <= 0.0 {
            return emitted;
        }
        let mut color = m.diffuse * self.ambient;
        for (li, l) in self.lights.iter().enumerate() {
            let f = visible(li);
            if f > 0.0 {
                color += light_term(s.position, s.normal, s.geo_normal, s.incident, m, l) * f;
            }
        }
        emitted + color * m.local_weight * s.throughput
    }

    /// Adds the direct light of `surfaces` to `image` (see the module docs) for shadow rays
    /// traced with any-hit queries: [`Phong::shade_mode`] with [`HitMode::Any`].
    pub fn shade(
        &self,
        surfaces: &[Surface],
        shadow_rays: &[Ray],
        shadow_hits: &[Hit],
        image: &mut [[f32; 4]],
    ) -> Result<()> {
        self.shade_mode(surfaces, shadow_rays, shadow_hits, HitMode::Any, image)
    }

    /// Adds the direct light of `surfaces` to `image` (see the module docs): the shadow rays
    /// with their hits, traced with `mode` ([`HitMode::Any`] or [`HitMode::EdgeWidth`]), give
    /// each light's visibility from each ray's source surface.
    pub fn shade_mode(
        &self,
        surfaces: &[Surface],
        shadow_rays: &[Ray],
        shadow_hits: &[Hit],
        mode: HitMode,
        image: &mut [[f32; 4]],
    ) -> Result<()> {
        if mode == HitMode::Closest {
            return Err(CoreError::Unsupported {
                stage: "shade",
                variant: "phong".into(),
                what: "shadow rays traced for their nearest hit (visibility needs any-hit or \
                       edge-width queries)"
                    .into(),
            });
        }
        crsh_core::ray::check_hits_per_ray("shadow rays", shadow_rays.len(), shadow_hits.len())?;
        if let Some(s) = crate::position_first(surfaces, |s| {
            s.pixel as usize >= image.len()
                || (s.is_hit() && s.material as usize >= self.materials.len())
        })
        .map(|i| &surfaces[i])
        {
            return Err(CoreError::InvalidInput(format!(
                "surface record for pixel {} (material {}) does not fit an image of {} pixels \
                 and {} materials",
                s.pixel,
                s.material,
                image.len(),
                self.materials.len()
            )));
        }
        // Visibility per (surface, light): the sum over its shadow rays, in ray order (so the
        // result does not depend on the thread count), and their number.
        let nl = self.lights.len();
        let mut lit = vec![0f32; surfaces.len() * nl];
        let mut rays = vec![0u32; surfaces.len() * nl];
        for (r, h) in shadow_rays.iter().zip(shadow_hits) {
            let (src, li) = (r.source as usize, r.light as usize);
            if src >= surfaces.len() || li >= nl {
                return Err(CoreError::InvalidInput(format!(
                    "shadow ray for surface {src} and light {li} does not match {} surfaces and \
                     {nl} lights",
                    surfaces.len()
                )));
            }
            let k = src * nl + li;
            lit[k] += match mode {
                HitMode::EdgeWidth(_) => 1.0 - crsh_core::edge_width::occlusion(h),
                _ => f32::from(u8::from(!h.is_hit())),
            };
            rays[k] += 1;
        }
        let contributions: Vec<Vec3> = surfaces
            .par_iter()
            .enumerate()
            .map(|(i, s)| {
                self.contribution(s, |li| {
                    let k = i * nl + li;
                    match rays[k] {
                        0 => 0.0,
                        1 => lit[k],
                        n => lit[k] / n as f32,
                    }
                })
            })
            .collect();
        for (s, c) in surfaces.iter().zip(&contributions) {
            let px = &mut image[s.pixel as usize];
            px[0] += c.x;
            px[1] += c.y;
            px[2] += c.z;
            px[3] = 1.0;
        }
        Ok(())
    }

    /// The next path vertices for reflection / refraction `rays` and their nearest `hits`
    /// (one per ray, same order).
    pub fn next_surfaces(&self, rays: &[Ray], hits: &[Hit]) -> Result<Vec<Surface>> {
        crate::surface::next_surfaces(&self.scene, rays, hits)
    }
}

impl Shader<Cpu> for Phong {
    fn name(&self) -> &str {
        "phong"
    }

    fn shade_direct(
        &self,
        _backend: &Cpu,
        surfaces: &Vec<Surface>,
        shadow_rays: &Vec<Ray>,
        shadow_hits: &Vec<Hit>,
        mode: HitMode,
        image: &mut Vec<[f32; 4]>,
        _stats: &mut Stats,
    ) -> Result<()> {
        self.shade_mode(surfaces, shadow_rays, shadow_hits, mode, image)
    }

    fn resolve(
        &self,
        _backend: &Cpu,
        rays: &Vec<Ray>,
        hits: &Vec<Hit>,
        _stats: &mut Stats,
    ) -> Result<Vec<Surface>> {
        self.next_surfaces(rays, hits)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raygen::whitted::tests::{light, quad_scene, surface};
    use crsh_core::{ParamValue, RayKind};
    use crsh_scene::Material;

    fn spec(ambient: f64, background: f64) -> StageSpec {
        let mut s = StageSpec::new("phong");
        s.params
            .insert("ambient".into(), ParamValue::Float(ambient));
        s.params
            .insert("background".into(), ParamValue::Float(background));
        s
    }

    fn shadow(source: u32, light: u32) -> Ray {
        Ray {
            origin: Vec3::ZERO,
            t_min: 0.0,
            dir: Vec3::Z,
            t_max: 1.0,
            throughput: Vec3::ONE,
            kind: RayKind::Shadow as u32,
            pixel: 0,
            light,
            depth: 1,
            source,
        }
    }

    const OCCLUDED: Hit = Hit {
        t: 0.5,
        tri: 1,
        u: 0.0,
        v: 0.0,
    };

    #[test]
    fn visibility_comes_from_the_shadow_rays() {
        let lights = vec![
            light(Vec3::new(0.0, 0.0, 1.0)),
            light(Vec3::new(0.0, 0.0, 2.0)),
        ];
        let mat = Material {
            diffuse: Vec3::new(1.0, 0.5, 0.25),
            ..Material::default()
        };
        let scene = quad_scene(vec![mat], lights);
        let sh = Phong::new(&scene, &spec(0.0, 0.0)).unwrap();
        let s = [surface(Vec3::ZERO, 0, 0), surface(Vec3::ZERO, 1, 0)];
        let mut img = vec![[0.0f32; 4]; 3];
        // Surface 0 sees light 0 only (light 1 occluded); surface 1 has no shadow rays at all.
        let rays = [shadow(0, 0), shadow(0, 1)];
        sh.shade(&s, &rays, &[Hit::MISS, OCCLUDED], &mut img)
            .unwrap();
        // Head-on, distance 1, no attenuation: the diffuse colour exactly.
        assert_eq!(img[0], [1.0, 0.5, 0.25, 1.0]);
        assert_eq!(img[1], [0.0, 0.0, 0.0, 1.0]);
        assert_eq!(img[2], [0.0; 4]);
        // Accumulates across calls.
        sh.shade(&s[..1], &rays[..1], &[Hit::MISS], &mut img)
            .unwrap();
        assert_eq!(img[0], [2.0, 1.0, 0.5, 1.0]);
    }

    #[test]
    fn visibility_is_the_mean_over_a_light_s_shadow_rays() {
        let mat = Material {
            diffuse: Vec3::new(1.0, 0.5, 0.25),
            ..Material::default()
        };
        let scene = quad_scene(vec![mat], vec![light(Vec3::new(0.0, 0.0, 1.0))]);
        let sh = Phong::new(&scene, &spec(0.0, 0.0)).unwrap();
        let s = [surface(Vec3::ZERO, 0, 0)];
        // Sampled soft shadows: 3 of 4 any-hit rays unoccluded.
        let rays = [shadow(0, 0); 4];
        let mut img = vec![[0.0f32; 4]; 1];
        sh.shade(
            &s,
            &rays,
            &[Hit::MISS, OCCLUDED, Hit::MISS, Hit::MISS],
            &mut img,
        )
        .unwrap();
        assert_eq!(img[0], [0.75, 0.375, 0.1875, 1.0]);
        // Edge width (seed 003 eq. 5.1): occlusion u = 0.25 leaves 3/4 of the light; a miss
        // all of it; a full occlusion none.
        let partial = Hit {
            u: 0.25,
            v: 0.1,
            ..OCCLUDED
        };
        for (hit, want) in [
            (partial, 0.75),
            (Hit::MISS, 1.0),
            (Hit { u: 1.0, ..OCCLUDED }, 0.0),
        ] {
            let mut img = vec![[0.0f32; 4]; 1];
            sh.shade_mode(
                &s,
                &rays[..1],
                &[hit],
                HitMode::EdgeWidth(Default::default()),
                &mut img,
            )
            .unwrap();
            assert_eq!(img[0], [want, 0.5 * want, 0.25 * want, 1.0], "{hit:?}");
        }
        // Any-hit shading reads an edge-width hit as a full occlusion; nearest hits are refused.
        let mut img = vec![[0.0f32; 4]; 1];
        sh.shade(&s, &rays[..1], &[partial], &mut img).unwrap();
        assert_eq!(img[0], [0.0, 0.0, 0.0, 1.0]);
        assert!(sh
            .shade_mode(&s, &rays[..1], &[partial], HitMode::Closest, &mut img)
            .is_err());
    }

    #[test]
    fn ambient_background_and_local_weight() {
        let mat = Material {
            diffuse: Vec3::new(0.8, 0.4, 0.2),
            reflectivity: 0.25,
            transparency: 0.25,
            ..Material::default()
        };
        let scene = quad_scene(vec![mat], vec![]);
        let sh = Phong::new(&scene, &spec(0.5, 0.25)).unwrap();
        let mut s = surface(Vec3::ZERO, 0, 0);
        s.throughput = Vec3::new(1.0, 0.5, 2.0);
        let bg = Surface::background(1, Vec3::Z, Vec3::new(0.5, 1.0, 2.0), 1);
        let mut img = vec![[0.0f32; 4]; 2];
        sh.shade(&[s, bg], &[], &[], &mut img).unwrap();
        // ambient · diffuse · local weight (0.5) · throughput
        assert_eq!(img[0], [0.2, 0.05, 0.1, 1.0]);
        assert_eq!(img[1], [0.125, 0.25, 0.5, 1.0]);
    }

    #[test]
    fn light_behind_the_geometric_normal_lights_nothing() {
        let m = Material {
            specular: Vec3::ONE,
            shininess: 4.0,
            ..Material::default()
        };
        let l = light(Vec3::new(0.0, 0.0, -1.0));
        let c = phong_light(
            Vec3::ZERO,
            Vec3::Z,
            Vec3::Z,
            -Vec3::Z,
            m.diffuse,
            m.specular,
            4.0,
            &l,
        );
        assert_eq!(c, Vec3::ZERO);
        // In front of the face but behind a tilted shading normal: no diffuse, no highlight.
        let l = light(Vec3::new(1.0, 0.0, 0.1));
        let n = Vec3::new(-1.0, 0.0, 0.2).normalize();
        let c = phong_light(
            Vec3::ZERO,
            n,
            Vec3::Z,
            -Vec3::Z,
            m.diffuse,
            m.specular,
            4.0,
            &l,
        );
        assert_eq!(c, Vec3::ZERO);
    }

    #[test]
    fn bad_input_is_an_error() {
        let scene = quad_scene(vec![Material::default()], vec![light(Vec3::Z)]);
        assert!(Phong::new(&scene, &spec(-0.1, 0.0)).is_err());
        assert!(Phong::new(&scene, &spec(0.0, f64::INFINITY)).is_err());
        let sh = Phong::new(&scene, &spec(0.0, 0.0)).unwrap();
        let s = [surface(Vec3::ZERO, 0, 0)];
        let mut img = vec![[0.0f32; 4]; 1];
        assert!(sh.shade(&s, &[shadow(0, 0)], &[], &mut img).is_err());
        assert!(sh
            .shade(&s, &[shadow(1, 0)], &[Hit::MISS], &mut img)
            .is_err());
        assert!(sh
            .shade(&s, &[shadow(0, 3)], &[Hit::MISS], &mut img)
            .is_err());
        assert!(sh
            .shade(&[surface(Vec3::ZERO, 5, 0)], &[], &[], &mut img)
            .is_err());
        let bad_hit = Hit {
            t: 1.0,
            tri: 9,
            u: 0.0,
            v: 0.0,
        };
        assert!(sh.next_surfaces(&[shadow(0, 0)], &[bad_hit]).is_err());
        assert!(sh.next_surfaces(&[shadow(0, 0)], &[]).is_err());
    }

    #[test]
    fn resolve_keeps_pixel_throughput_and_depth() {
        let scene = quad_scene(vec![Material::default()], vec![]);
        let sh = Phong::new(&scene, &spec(0.0, 0.0)).unwrap();
        let mut r = shadow(0, u32::MAX);
        r.kind = RayKind::Reflection as u32;
        r.origin = Vec3::new(0.25, -0.5, 1.0);
        r.dir = -Vec3::Z;
        r.pixel = 42;
        r.depth = 2;
        r.throughput = Vec3::new(0.5, 0.25, 0.125);
        // Triangle 0 is (-1,-1), (1,-1), (1,1): the point (0.25, -0.5) has u = 0.375, v = 0.25.
        let hit = Hit {
            t: 1.0,
            tri: 0,
            u: 0.375,
            v: 0.25,
        };
        let out = sh.next_surfaces(&[r, r], &[hit, Hit::MISS]).unwrap();
        assert_eq!(out[0].position, Vec3::new(0.25, -0.5, 0.0));
        assert_eq!(out[0].normal, Vec3::Z);
        assert!(out[0].front_face());
        assert!(!out[1].is_hit());
        for s in &out {
            assert_eq!((s.pixel, s.depth, s.throughput), (42, 2, r.throughput));
            assert_eq!(s.incident, -Vec3::Z);
        }
    }
}
