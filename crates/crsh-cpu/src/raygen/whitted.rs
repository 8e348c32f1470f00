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
//!
//!   Soft shadows (seed 003 §5, param `shadow`, the light's radius `R` from the scene:
//!   `Light::radius`): `hard` (the default) makes the one ray to the light's centre above;
//!   `samples` makes `shadow_samples` rays per (surface, light) to stratified points of the
//!   light's disc of radius `R` facing the surface point (the disc through the centre, normal
//!   to the centre-to-surface direction: what a sphere light shows the point): `√N × √N`
//!   strata when `N` is a square, else `1 × N`, each point `c + R·√u1·(cos 2πu2·t + sin 2πu2·b)`
//!   jittered inside its stratum by the counter-based generator ([`crsh_core::rng`]) keyed by
//!   (pixel, sample, surface depth, light), so the rays do not depend on the thread count;
//!   slots are light-major, then sample-major, then in surface order. With `R = 0` every
//!   sample is the centre and the image is the hard one. `edge_width` makes the hard ray and
//!   asks the driver to trace it with [`HitMode::EdgeWidth`] ([`RayGen::visibility_mode`]):
//!   eq. 5.1's occlusion from one ray; `edge_pairing = shared_vertex` pairs only crossings of
//!   triangles sharing a vertex (§5.4's light-leak fix, [`crsh_core::edge_width`]). Back-face culling and the throughput are decided with
//!   the light's centre for every variant. Generators that reuse these shadow rays without
//!   declaring the params (`diffuse`) get `hard`.
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
//! # Offset policy (self-intersection)
//!
//! A secondary ray must not find the surface it leaves. How it avoids it is the param `offset`
//! ([`OffsetPolicy`]), with `off = epsilon × |scene bounding box diagonal|` (param `epsilon`,
//! default 1e-5, relative so that it scales with the scene):
//! - `normal` (default): the origin of a reflection or refraction ray is the hit point moved
//!   by `off` along the geometric normal, to the side the ray leaves into (the sign of
//!   `d · n_geo`), and its interval starts at `t_min = off`; a shadow ray's surface end point
//!   is the hit point moved by `off` along the geometric normal towards the light; the
//!   interval is `(off, |segment| − off)`, so it excludes both the light and the surface by the
//!   same distance (a light sitting on a wall does not shadow itself). When the light is
//!   closer than `2 off` the interval is empty and the light is seen.
//! - `scaled`: no offset; the ray starts at the hit point itself and only its interval moves:
//!   `t_min = off`, and a bounded (shadow) segment also stops `off` short of its far end, so it
//!   excludes the light by the same distance, as with `normal`.
//! - `fixed`: as `scaled`, with the absolute distance `fixed_epsilon` (default 1e-4, in scene
//!   units) instead of `off`: the classic constant, which is too small for a large or
//!   translated scene (where `t ≈ fixed_epsilon` is below the rounding error of the hit
//!   point) and too large for a small one. Kept for comparison.
//! - `wachter`: Wächter & Binder, "A Fast and Robust Method for Avoiding Self-Intersection",
//!   Ray Tracing Gems ch. 6 (2019), [`offset_ray`]: the surface end point moves a fixed number
//!   of units in the last place (ULPs) of each coordinate along the geometric normal (flipped
//!   to the side the ray leaves into), or a fixed distance near the origin, so the offset
//!   grows with the magnitude of the coordinates and not with the scene's size. A ray leaving
//!   the surface starts at the offset point with the open interval `t_min = 0`. A shadow
//!   segment from the light (`shadow_origin = light`) ends at the offset point less
//!   [`WACHTER_T_ULPS`] ULPs of its length: there the intersector's `t` carries the rounding
//!   error of a point `|segment|` away from the ray's origin, which the offset does not cover
//!   (measured: ending exactly at the offset point leaves acne where the light is steep above
//!   the surface, one ray in 4096 on a plane lit from 89° at distance 20). At the *light* end
//!   the segment excludes the distance [`offset_ray`] would move the light along the segment
//!   (a few hundred ULPs of the light's coordinates, or 1/65536 near the origin), not 0: a
//!   light sitting on a wall starts its shadow rays inside the wall's plane, where the open
//!   interval alone would let rounding report the wall at `t` just above 0 and shadow
//!   everything (measured: with `t_min = 0` there, 7 of 16 lights placed on a tilted wall
//!   shadowed the whole floor in front of it). A surface crossing the segment closer to the
//!   light than that gap is missed; put lights further from geometry than that (any light off
//!   a surface by more than ~1e-4 of its coordinates is).
//!
//! The offsets move along the *geometric* normal because the shading normal may tilt away
//! from the face. A reflection direction computed from a tilted shading normal may point
//! slightly below the face; it is followed as eq. 3.4 gives it (the origin then moves to the
//! back side), not bent.
//!
//! The policy lives in one function, [`offset_segment`].

use std::sync::Arc;
use std::time::Instant;

use crsh_core::edge_width::EdgePairing;
use crsh_core::glam::Vec3;
use crsh_core::rng::{basis, unit, RngKey};
use crsh_core::{
    CoreError, HitMode, ParamInfo, Ray, RayGen, RayKind, Registry, Result, StageKind, StageSpec,
    StageVariantInfo, Stats, Surface,
};
use crsh_scene::Scene;

use crate::backend::Cpu;
use crate::raygen::offsets::{self, Offsets};
use crate::trim::{self, concat_in_order, trim};

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

/// How shadow rays sample a light (param `shadow`; see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ShadowMode {
    /// One any-hit ray to the light's centre (hard shadows).
    Hard,
    /// This many any-hit rays to stratified points of the light's disc.
    Samples(u32),
    /// One ray to the centre, traced for its edge-width occlusion (seed 003 §5, eq. 5.1),
    /// pairing crossings by the rule (param `edge_pairing`).
    EdgeWidth(EdgePairing),
}

impl ShadowMode {
    /// The param value naming this mode (`hard`, `samples`, `edge_width`).
    pub fn name(&self) -> &'static str {
        match self {
            ShadowMode::Hard => "hard",
            ShadowMode::Samples(_) => "samples",
            ShadowMode::EdgeWidth(_) => "edge_width",
        }
    }

    /// Shadow rays per (surface, light).
    pub fn rays_per_light(&self) -> u32 {
        match self {
            ShadowMode::Samples(n) => *n,
            _ => 1,
        }
    }

    /// The `shadow`, `shadow_samples` and `edge_pairing` params of a resolved `spec`; `hard`
    /// when the spec does not declare them (a generator that reuses Whitted's shadow rays).
    pub fn from_spec(spec: &StageSpec) -> Result<ShadowMode> {
        if !spec.params.contains_key("shadow") {
            return Ok(ShadowMode::Hard);
        }
        match spec.str("shadow")? {
            "hard" => Ok(ShadowMode::Hard),
            "edge_width" => {
                let name = spec.str("edge_pairing")?;
                EdgePairing::from_name(name)
                    .map(ShadowMode::EdgeWidth)
                    .ok_or_else(|| CoreError::InvalidParam {
                        key: "raygen.edge_pairing".into(),
                        reason: format!("`{name}` is not one of {}", EdgePairing::NAMES.join(", ")),
                    })
            }
            "samples" => Ok(ShadowMode::Samples(
                spec.u32_in("shadow_samples", 1..=MAX_SHADOW_SAMPLES)
                    .map_err(|e| match e {
                        CoreError::InvalidParam { reason, .. } => CoreError::InvalidParam {
                            key: "raygen.shadow_samples".into(),
                            reason,
                        },
                        e => e,
                    })?,
            )),
            other => Err(CoreError::InvalidParam {
                key: "raygen.shadow".into(),
                reason: format!("`{other}` is not one of hard, samples, edge_width"),
            }),
        }
    }
}

/// The largest `shadow_samples`.
pub const MAX_SHADOW_SAMPLES: u32 = 1024;

/// The point of sample `sample` of `n` on a light disc of centre `c`, radius `radius` and unit
/// normal `w` (see the module docs: `√n × √n` strata for a square `n`, else `1 × n`, jittered
/// by the uniforms `xi`).
pub fn disc_sample(c: Vec3, radius: f32, w: Vec3, sample: u32, n: u32, xi: [f32; 2]) -> Vec3 {
    let m = (n as f64).sqrt().round() as u32;
    let (cols, rows) = if m * m == n { (m, m) } else { (n, 1) };
    let (i, k) = (sample % cols, sample / cols);
    let u1 = (i as f32 + xi[0]) / cols as f32;
    let u2 = (k as f32 + xi[1]) / rows as f32;
    let r = radius * u1.sqrt();
    let phi = std::f32::consts::TAU * u2;
    let (t, b) = basis(w);
    c + (t * phi.cos() + b * phi.sin()) * r
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
/// conventions and the offset policies.
#[derive(Clone, Debug)]
pub struct Whitted {
    lights: Vec<Vec3>,
    radii: Vec<f32>,
    shadow: ShadowMode,
    materials: Vec<MatRays>,
    shadow_origin: ShadowOrigin,
    cull_backfacing: bool,
    min_throughput: f32,
    offset: f32,
    policy: OffsetPolicy,
    offsets: Offsets,
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

impl Segment {
    /// The point at distance `t` along the segment's ray, `origin + t · dir`.
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + self.dir * t
    }
}

/// How a secondary ray avoids the surface it leaves (the `offset` param; see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum OffsetPolicy {
    /// Origin moved by this distance along the geometric normal, and `t_min` of the same size
    /// (the default, `epsilon × scene diagonal`).
    Normal(f32),
    /// Origin at the hit point, `t_min` = this distance (`epsilon × scene diagonal`).
    Scaled(f32),
    /// Origin at the hit point, `t_min` = this absolute distance (`fixed_epsilon`).
    Fixed(f32),
    /// Wächter & Binder's ULP offset ([`offset_ray`]), `t_min = 0` at the surface end.
    Wachter,
}

impl OffsetPolicy {
    /// The param value naming this policy (`normal`, `scaled`, `fixed`, `wachter`).
    pub fn name(&self) -> &'static str {
        match self {
            OffsetPolicy::Normal(_) => "normal",
            OffsetPolicy::Scaled(_) => "scaled",
            OffsetPolicy::Fixed(_) => "fixed",
            OffsetPolicy::Wachter => "wachter",
        }
    }
}

/// Coordinates closer to 0 than this move by a fixed distance in [`offset_ray`] (RTG ch. 6
/// `origin()`).
pub const WACHTER_ORIGIN: f32 = 1.0 / 32.0;
/// The fixed distance (times the normal component) near the origin (RTG ch. 6 `float_scale()`).
pub const WACHTER_FLOAT_SCALE: f32 = 1.0 / 65536.0;
/// The ULP count (times the normal component) elsewhere (RTG ch. 6 `int_scale()`).
pub const WACHTER_INT_SCALE: f32 = 256.0;

/// ULPs of the segment length by which a `wachter` shadow segment from the light
/// (`shadow_origin = light`) stops short of the offset surface point (see the module docs).
pub const WACHTER_T_ULPS: f32 = 32.0;

/// The unit in the last place of the finite `x ≥ 0` (the gap to the next float up).
fn ulp(x: f32) -> f32 {
    f32::from_bits(x.to_bits() + 1) - x
}

/// Wächter & Binder's `offset_ray(p, n)` (Ray Tracing Gems ch. 6, 2019): `p` moved off its
/// surface to the side of the unit normal `n`. Each coordinate `p_i` with `|p_i| ≥ 1/32`
/// moves by `⌊256 n_i⌋` units in the last place (added to the float's bit pattern, towards
/// `+∞` for `n_i > 0` whatever the sign of `p_i`); a coordinate closer to 0 moves by
/// `n_i / 65536`, since ULPs vanish there. The move is thus a fixed multiple of the rounding
/// error of the coordinates, which is what bounds the error of a computed hit point.
pub fn offset_ray(p: Vec3, n: Vec3) -> Vec3 {
    let component = |p: f32, n: f32| {
        if p.abs() < WACHTER_ORIGIN {
            p + WACHTER_FLOAT_SCALE * n
        } else {
            let ulps = (WACHTER_INT_SCALE * n) as i32;
            let bits = p.to_bits() as i32;
            let moved = if p < 0.0 {
                bits.wrapping_sub(ulps)
            } else {
                bits.wrapping_add(ulps)
            };
            f32::from_bits(moved as u32)
        }
    };
    Vec3::new(
        component(p.x, n.x),
        component(p.y, n.y),
        component(p.z, n.z),
    )
}

/// The offset policy, in one function (see the module docs): the segment of the ray `leg` from
/// or to the surface point `p` with unit geometric normal `geo_normal` under `policy`. "The
/// side the ray leaves into" is the side of `geo_normal` the direction (or the other end
/// point) lies on, the front side for a ray parallel to the surface. A bounded segment's
/// interval is never negative (`t_max ≥ t_min`: empty when the far end is closer than the
/// gaps). `None` when the direction is zero or not finite (a light at the surface point).
pub fn offset_segment(
    p: Vec3,
    geo_normal: Vec3,
    leg: Leg,
    policy: &OffsetPolicy,
) -> Option<Segment> {
    let leaving = match leg {
        Leg::Along(d) => d,
        Leg::To(q) | Leg::From(q) => q - p,
    };
    let n = if leaving.dot(geo_normal) < 0.0 {
        -geo_normal
    } else {
        geo_normal
    };
    // The surface end point, the gap excluded at the surface end and the gap at the far end
    // (`None`: Wächter's gap at the light, which depends on the segment's direction).
    let (start, near, far) = match *policy {
        OffsetPolicy::Normal(off) => (p + n * off, off, Some(off)),
        OffsetPolicy::Scaled(d) | OffsetPolicy::Fixed(d) => (p, d, Some(d)),
        OffsetPolicy::Wachter => (offset_ray(p, n), 0.0, None),
    };
    let (origin, seg, light) = match leg {
        Leg::Along(d) => (start, d, None),
        Leg::To(q) => (start, q - start, Some(q)),
        Leg::From(q) => (q, start - q, Some(q)),
    };
    let dir = seg.normalize_or_zero();
    if dir == Vec3::ZERO || !dir.is_finite() {
        return None;
    }
    let Some(q) = light else {
        return Some(Segment {
            origin,
            dir,
            t_min: near,
            t_max: f32::INFINITY,
        });
    };
    // Wächter's gap at the light end q: the distance offset_ray would move q along the
    // segment (the direction from the light to the surface in both conventions, so that both
    // test the same segment).
    let far = far.unwrap_or_else(|| {
        let towards_surface = if matches!(leg, Leg::From(_)) {
            dir
        } else {
            -dir
        };
        (offset_ray(q, towards_surface) - q).length()
    });
    let len = seg.length();
    let near = match (policy, leg) {
        // The surface end of a segment from the light: the intersector's `t` there carries
        // the rounding error of a distance `len` from the origin, which Wächter's offset
        // (relative to the surface point's coordinates) does not cover once the light is far
        // or the ray steep; stop a few ULPs of `len` short of the offset point.
        (OffsetPolicy::Wachter, Leg::From(_)) => WACHTER_T_ULPS * ulp(len),
        _ => near,
    };
    let (t_min, t_max) = match leg {
        Leg::From(_) => (far, (len - near).max(far)),
        _ => (near, (len - far).max(near)),
    };
    Some(Segment {
        origin,
        dir,
        t_min,
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

/// The catalogue entry of the `whitted` ray generator.
pub fn info() -> StageVariantInfo {
    offsets::offsets_param(surface_ray_params(StageVariantInfo::new(
        StageKind::Raygen,
        "whitted",
        "shadow, reflection and refraction rays with total internal reflection, seed 000 \
         §3.2.3 eq. 3.1-3.7; soft shadows by light samples or edge width (seed 003 §5)",
    )))
    .param(ParamInfo::choice(
        "shadow",
        "hard",
        &["hard", "samples", "edge_width"],
        "shadow rays: one to the light's centre (hard), shadow_samples to stratified points \
         of the light's disc (samples), or one traced for its edge-width occlusion, seed 003 \
         eq. 5.1 (edge_width); the light radius is the scene's",
    ))
    .param(ParamInfo::int(
        "shadow_samples",
        16,
        1,
        MAX_SHADOW_SAMPLES as i64,
        "shadow rays per light and surface for shadow = samples (√N×√N strata when N is a \
         square)",
    ))
    .param(ParamInfo::choice(
        "edge_pairing",
        "any",
        &EdgePairing::NAMES,
        "which crossings form an edge width for shadow = edge_width: any consecutive entry \
         and exit (listing 5.1), or only triangles sharing a vertex, any other pair occluding \
         fully (shared_vertex: the thesis's light-leak fix, seed 003 §5.4 fig. 5.10)",
    ))
}

/// The parameters of [`Whitted::new`] (`shadow_origin`, `cull_backfacing`, `min_throughput`
/// and [`offset_params`]), added to `info`: generators that make shadow rays the Whitted way
/// (`diffuse`) share them.
pub fn surface_ray_params(info: StageVariantInfo) -> StageVariantInfo {
    offset_params(
        info.param(ParamInfo::choice(
            "shadow_origin",
            "light",
            &["light", "surface"],
            "shadow rays start at the light (thesis, eq. 3.1-3.2) or at the surface",
        ))
        .param(ParamInfo::bool(
            "cull_backfacing",
            true,
            "no shadow ray to a light behind the geometric normal (it lights nothing)",
        ))
        .param(
            ParamInfo::float(
                "min_throughput",
                1e-3,
                "rays whose largest throughput component is below this are not spawned",
            )
            .range(0.0, f64::INFINITY),
        ),
    )
}

/// The self-intersection parameters every surface-leaving generator shares (`epsilon`,
/// `offset`, `fixed_epsilon`; see [`policy_from_spec`]), added to `info`.
pub fn offset_params(info: StageVariantInfo) -> StageVariantInfo {
    info.param(
        ParamInfo::float(
            "epsilon",
            1e-5,
            "the offset distance of the `normal` and `scaled` policies, as a fraction of the \
             scene's bounding-box diagonal",
        )
        .range(0.0, 0.1),
    )
    .param(ParamInfo::choice(
        "offset",
        "normal",
        &["normal", "scaled", "fixed", "wachter"],
        "self-intersection policy: origin moved along the geometric normal and t_min \
         (normal), t_min only (scaled: epsilon, fixed: fixed_epsilon), or Wächter & Binder's \
         ULP offset with t_min = 0 (wachter)",
    ))
    .param(
        ParamInfo::float(
            "fixed_epsilon",
            1e-4,
            "t_min of the `fixed` policy, an absolute distance in scene units",
        )
        .range(0.0, f64::INFINITY),
    )
}

/// The offset distance (`epsilon × scene diagonal`) and the self-intersection policy of a
/// resolved `spec` carrying [`offset_params`]: `epsilon` (relative to the scene's bounding-box
/// diagonal, in `[0, 0.1]`), `offset` (`normal`|`scaled`|`fixed`|`wachter`, see
/// [`OffsetPolicy`]) and `fixed_epsilon` (an absolute distance ≥ 0).
pub fn policy_from_spec(scene: &Scene, spec: &StageSpec) -> Result<(f32, OffsetPolicy)> {
    let epsilon = spec.f64("epsilon")?;
    if !epsilon.is_finite() || !(0.0..=0.1).contains(&epsilon) {
        return Err(CoreError::InvalidParam {
            key: "raygen.epsilon".into(),
            reason: format!("{epsilon} is outside 0..=0.1 (a fraction of the scene diagonal)"),
        });
    }
    let fixed_epsilon = spec.f64("fixed_epsilon")?;
    if !fixed_epsilon.is_finite() || fixed_epsilon < 0.0 {
        return Err(CoreError::InvalidParam {
            key: "raygen.fixed_epsilon".into(),
            reason: format!("{fixed_epsilon} must be a finite distance ≥ 0"),
        });
    }
    let diagonal = scene.bounds.diagonal();
    if !diagonal.is_finite() {
        return Err(CoreError::InvalidInput(format!(
            "scene `{}` has non-finite bounds",
            scene.name
        )));
    }
    let offset = (epsilon * diagonal as f64) as f32;
    let policy = match spec.str("offset")? {
        "normal" => OffsetPolicy::Normal(offset),
        "scaled" => OffsetPolicy::Scaled(offset),
        "fixed" => OffsetPolicy::Fixed(fixed_epsilon as f32),
        "wachter" => OffsetPolicy::Wachter,
        other => {
            return Err(CoreError::InvalidParam {
                key: "raygen.offset".into(),
                reason: format!("`{other}` is not one of normal, scaled, fixed, wachter"),
            })
        }
    };
    Ok((offset, policy))
}

/// The `min_throughput` parameter of a resolved `spec` (finite, ≥ 0), which every
/// surface-leaving generator declares.
pub fn min_throughput_param(spec: &StageSpec) -> Result<f32> {
    let v = spec.f64("min_throughput")?;
    if !v.is_finite() || v < 0.0 {
        return Err(CoreError::InvalidParam {
            key: "raygen.min_throughput".into(),
            reason: format!("{v} must be a finite number ≥ 0"),
        });
    }
    Ok(v as f32)
}

/// Registers `whitted` ([`info`], [`Whitted::new`]).
pub fn register(registry: &mut Registry<Cpu>) -> Result<()> {
    registry.add_raygen(info(), |ctx, spec| {
        Ok(Box::new(Whitted::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

impl Whitted {
    /// A generator for `scene` with the parameters of a resolved `spec`: `shadow_origin`
    /// (`light`|`surface`), `cull_backfacing` (bool), `min_throughput` (≥ 0), `epsilon`
    /// (relative to the scene's bounding-box diagonal, in `[0, 0.1]`), `offset`
    /// (`normal`|`scaled`|`fixed`|`wachter`, see [`OffsetPolicy`]) and `fixed_epsilon` (an
    /// absolute distance ≥ 0).
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
        let min_throughput = min_throughput_param(spec)?;
        let (offset, policy) = policy_from_spec(scene, spec)?;
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
        let radii = scene.lights.iter().map(|l| l.radius).collect::<Vec<_>>();
        if let Some(r) = radii.iter().find(|r| !(r.is_finite() && **r >= 0.0)) {
            return Err(CoreError::InvalidInput(format!(
                "light radius {r} is not a finite distance >= 0"
            )));
        }
        Ok(Whitted {
            lights,
            radii,
            shadow: ShadowMode::from_spec(spec)?,
            materials,
            shadow_origin,
            cull_backfacing,
            min_throughput,
            offset,
            policy,
            offsets: Offsets::from_spec(scene, spec)?,
        })
    }

    /// How shadow rays sample the lights (params `shadow`, `shadow_samples`).
    pub fn shadow(&self) -> ShadowMode {
        self.shadow
    }

    /// The same generator with origin offsets `offsets` ([`super::offsets`]).
    pub fn with_offsets(mut self, offsets: Offsets) -> Self {
        self.offsets = offsets;
        self
    }

    /// The origin offsets in use (param `offsets`).
    pub fn offsets(&self) -> &Offsets {
        &self.offsets
    }

    /// The same generator with every material treated as opaque and purely diffuse
    /// (reflectivity and transparency 0): shadow rays then carry the surface's whole
    /// throughput, as the diffuse path tracer (`raygen = diffuse`) needs.
    pub fn lambertian(mut self) -> Self {
        for m in &mut self.materials {
            m.reflectivity = 0.0;
            m.transparency = 0.0;
        }
        self
    }

    /// The relative policies' distance, `epsilon × scene diagonal` (whatever the policy).
    pub fn offset(&self) -> f32 {
        self.offset
    }

    /// The offset policy in use (param `offset`).
    pub fn policy(&self) -> OffsetPolicy {
        self.policy
    }

    fn keeps(&self, throughput: Vec3) -> bool {
        throughput.max_element() >= self.min_throughput && throughput.is_finite()
    }

    /// Shadow ray `sample` (of [`ShadowMode::rays_per_light`]) from surface `s` (index
    /// `source`) to light `light`, if one is needed.
    fn shadow_ray(
        &self,
        source: u32,
        s: &Surface,
        m: &MatRays,
        light: u32,
        sample: u32,
    ) -> Option<Ray> {
        let centre = self.lights[light as usize];
        let to_light = centre - s.position;
        if self.cull_backfacing && to_light.dot(s.geo_normal) <= 0.0 {
            return None;
        }
        let throughput = s.throughput * m.local_weight();
        if !self.keeps(throughput) {
            return None;
        }
        let l = match self.shadow {
            ShadowMode::Samples(n) => {
                let key = RngKey {
                    pixel: s.pixel,
                    sample,
                    bounce: s.depth,
                    seed: light,
                };
                let w = key.words();
                disc_sample(
                    centre,
                    self.radii[light as usize],
                    (s.position - centre).normalize_or_zero(),
                    sample,
                    n,
                    [unit(w[0]), unit(w[1])],
                )
            }
            _ => centre,
        };
        let leg = match self.shadow_origin {
            ShadowOrigin::Light => Leg::From(l),
            ShadowOrigin::Surface => Leg::To(l),
        };
        // `None`: the light sits on the surface point; nothing can lie in between.
        let seg = offset_segment(s.position, s.geo_normal, leg, &self.policy)?;
        let mut ray = Ray {
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
        };
        match self.shadow_origin {
            ShadowOrigin::Light => self.offsets.cut_end(s.tri, &mut ray),
            ShadowOrigin::Surface => self.offsets.apply(s.tri, &mut ray),
        };
        Some(ray)
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
        let seg = offset_segment(s.position, s.geo_normal, Leg::Along(dir), &self.policy)?;
        let mut ray = Ray {
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
        };
        self.offsets.apply(s.tri, &mut ray);
        Some(ray)
    }

    /// The rays of `kind` spawned by `surfaces`, compacted, in surface order, light-major for
    /// shadow rays (see the module docs): [`Whitted::slots`], then [`crate::trim::trim`].
    /// Primary rays are not made here: asking for them is an error.
    pub fn rays(&self, surfaces: &[Surface], kind: RayKind) -> Result<Vec<Ray>> {
        let (slots, flags) = self.slots(surfaces, kind)?;
        trim(&slots, &flags)
    }

    /// Ray creation before trimming (§3.2.3): one slot per surface (per light, sample and
    /// surface, light-major then sample-major, for shadow rays) and its head flag, 1 where the slot holds a ray and 0
    /// where the surface spawns none (background, culled light, absorbed bounce); empty
    /// slots hold a zeroed ray.
    pub fn slots(&self, surfaces: &[Surface], kind: RayKind) -> Result<(Vec<Ray>, Vec<u32>)> {
        self.slots_counted(surfaces, kind)
            .map(|(slots, flags, _)| (slots, flags))
    }

    /// [`Whitted::slots`], plus the number of rays whose interval the origin offsets emptied
    /// ([`super::offsets`]).
    pub fn slots_counted(
        &self,
        surfaces: &[Surface],
        kind: RayKind,
    ) -> Result<(Vec<Ray>, Vec<u32>, u64)> {
        let batch = self.batch(surfaces, kind)?;
        Ok(trim::fill_slot_arrays(batch.slots, CHUNK, |slot| {
            self.slot_ray(surfaces, kind, &batch, slot)
        }))
    }

    /// The rays of [`Whitted::slots`] compacted within each run of 4,096 slots as they are
    /// made (one vector per run, in slot order), and the count of rays the offsets emptied.
    /// Concatenated ([`crate::trim::concat_in_order`]), they are [`Whitted::rays`]; the full
    /// slot and flag arrays are never written, and a kind no surface spawns writes nothing.
    pub fn runs(&self, surfaces: &[Surface], kind: RayKind) -> Result<(Vec<Vec<Ray>>, u64)> {
        let batch = self.batch(surfaces, kind)?;
        if !self.may_spawn(kind) {
            return Ok((Vec::new(), 0));
        }
        Ok(trim::fill_runs(batch.slots, CHUNK, |slot| {
            self.slot_ray(surfaces, kind, &batch, slot)
        }))
    }

    /// Whether any surface could spawn a ray of `kind`: a light for shadow rays, a
    /// reflective or transparent material for reflection or refraction rays.
    fn may_spawn(&self, kind: RayKind) -> bool {
        match kind {
            RayKind::Shadow => !self.lights.is_empty(),
            RayKind::Reflection => self.materials.iter().any(|m| m.reflectivity > 0.0),
            RayKind::Refraction => self.materials.iter().any(|m| m.transparency > 0.0),
            _ => true,
        }
    }

    /// Checks a batch (see [`Whitted::slots`]'s errors) and sizes its slots.
    fn batch(&self, surfaces: &[Surface], kind: RayKind) -> Result<Batch> {
        if matches!(kind, RayKind::Primary | RayKind::Ao | RayKind::Diffuse) {
            return Err(CoreError::Unsupported {
                stage: "raygen",
                variant: "whitted".into(),
                what: format!(
                    "{} rays (primary visibility makes camera rays; raygen `ao` and `diffuse` the others)",
                    kind.name()
                ),
            });
        }
        let samples = self.shadow.rays_per_light() as usize;
        let per_surface = if kind == RayKind::Shadow {
            self.lights.len() * samples
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
        if let Some(s) = crate::position_first(surfaces, |s| {
            s.is_hit() && s.material as usize >= self.materials.len()
        })
        .map(|i| &surfaces[i])
        {
            return Err(CoreError::InvalidInput(format!(
                "surface of pixel {} has material {} but the scene has {}",
                s.pixel,
                s.material,
                self.materials.len()
            )));
        }
        Ok(Batch {
            surfaces: surfaces.len(),
            samples,
            slots: surfaces.len() * per_surface,
        })
    }

    /// The ray of slot `slot` of a checked batch and whether the origin offsets ended it
    /// (emptied its interval), if its surface spawns one.
    #[inline]
    fn slot_ray(
        &self,
        surfaces: &[Surface],
        kind: RayKind,
        b: &Batch,
        slot: usize,
    ) -> Option<(Ray, bool)> {
        let (source, light_sample) = (slot % b.surfaces, slot / b.surfaces);
        let (light, sample) = (light_sample / b.samples, light_sample % b.samples);
        let s = &surfaces[source];
        if !s.is_hit() {
            return None;
        }
        let m = &self.materials[s.material as usize];
        let r = if kind == RayKind::Shadow {
            self.shadow_ray(source as u32, s, m, light as u32, sample as u32)
        } else {
            self.bounce_ray(source as u32, s, m, kind)
        }?;
        Some((r, r.t_min >= r.t_max && self.offsets.is_some()))
    }
}

/// A checked batch of ray creation: its surfaces, shadow samples per light and slots.
struct Batch {
    surfaces: usize,
    samples: usize,
    slots: usize,
}

impl RayGen<Cpu> for Whitted {
    fn name(&self) -> &str {
        "whitted"
    }

    fn table_bytes(&self) -> u64 {
        self.offsets.table_bytes()
    }

    fn visibility_mode(&self) -> HitMode {
        match self.shadow {
            ShadowMode::EdgeWidth(p) => HitMode::EdgeWidth(p),
            _ => HitMode::Any,
        }
    }

    fn generate(
        &self,
        _backend: &Cpu,
        surfaces: &Vec<Surface>,
        kind: RayKind,
        stats: &mut Stats,
    ) -> Result<Vec<Ray>> {
        let (runs, ended) = self.runs(surfaces, kind)?;
        stats.add_offset_ended(kind, ended);
        let t = Instant::now();
        let rays = concat_in_order(runs);
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
            radius: 0.0,
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
        let mut s = info().defaults();
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

    /// The creation path `generate` takes (runs compacted as they are made, then concatenated)
    /// gives the slots-and-trim path's rays bit for bit and its ended counts, on the G-buffers
    /// and first bounces of the built-in scenes, for every kind, shadow mode and offset set,
    /// with 1 and 3 threads; a kind no material spawns writes nothing.
    #[test]
    fn chunked_creation_equals_slots_and_trim() {
        use crate::primary::raster::Raster;
        use crsh_core::PrimaryVisibility;
        for name in crsh_scene::builtin::NAMES {
            let scene = Arc::new(crsh_scene::builtin::build(name).unwrap());
            let raster = Raster::new(&scene, &StageSpec::new("raster")).unwrap();
            let primary = raster
                .gbuffer(&Cpu, 131, 97, &mut Stats::default())
                .unwrap();
            for params in [
                vec![],
                vec![("shadow", ParamValue::Str("samples".into()))],
                vec![
                    ("offset", ParamValue::Str("wachter".into())),
                    ("offsets", ParamValue::Str("center".into())),
                    ("shadow_origin", ParamValue::Str("surface".into())),
                ],
            ] {
                let g = Whitted::new(&scene, &spec(&params)).unwrap();
                let mut surfaces = primary.clone();
                for _depth in 0..3 {
                    let mut next = Vec::new();
                    for kind in [RayKind::Shadow, RayKind::Reflection, RayKind::Refraction] {
                        let (slots, flags, want_ended) = g.slots_counted(&surfaces, kind).unwrap();
                        let want = trim(&slots, &flags).unwrap();
                        for threads in [1, 3] {
                            let (chunks, ended) =
                                crate::with_threads(threads, || g.runs(&surfaces, kind).unwrap())
                                    .unwrap();
                            let got = concat_in_order(chunks);
                            assert_eq!(ended, want_ended, "{name} {params:?} {kind:?}");
                            assert_eq!(
                                bytemuck::cast_slice::<Ray, u8>(&got),
                                bytemuck::cast_slice::<Ray, u8>(&want),
                                "{name} {params:?} {kind:?} ({threads} threads)"
                            );
                        }
                        if kind != RayKind::Shadow {
                            // Bounce rays continue as surfaces a few units along.
                            next.extend(want.iter().map(|r| Surface {
                                position: r.at(r.t_min.max(1e-3) + 0.5),
                                depth: r.depth,
                                pixel: r.pixel,
                                ..surfaces[r.source as usize]
                            }));
                        }
                    }
                    if next.is_empty() {
                        break;
                    }
                    surfaces = next;
                }
            }
        }
        // No reflective or transparent material: nothing is made, nothing written.
        let scene = quad_scene(vec![Material::default()], vec![light(Vec3::Z)]);
        let g = Whitted::new(&scene, &spec(&[])).unwrap();
        let surfaces = [surface(Vec3::ZERO, 0, 0)];
        for kind in [RayKind::Reflection, RayKind::Refraction] {
            let (chunks, ended) = g.runs(&surfaces, kind).unwrap();
            assert!(chunks.is_empty() && ended == 0);
        }
        assert!(g.runs(&surfaces, RayKind::Primary).is_err());
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
        let to = offset_segment(p, n, Leg::To(l), &OffsetPolicy::Normal(off)).unwrap();
        assert_eq!(to.origin, Vec3::new(1.0, 2.01, 3.0));
        assert_eq!((to.dir, to.t_min), (Vec3::Y, off));
        assert!((to.t_max - (4.99 - off)).abs() < 1e-5);
        let from = offset_segment(p, n, Leg::From(l), &OffsetPolicy::Normal(off)).unwrap();
        assert_eq!((from.origin, from.dir), (l, -Vec3::Y));
        assert!((from.t_max - to.t_max).abs() < 1e-5);
        // Leaving through the back: the origin moves below.
        let down = offset_segment(p, n, Leg::Along(-Vec3::Y), &OffsetPolicy::Normal(off)).unwrap();
        assert_eq!(down.origin, Vec3::new(1.0, 1.99, 3.0));
        assert_eq!(down.t_max, f32::INFINITY);
        // A light closer than 2·off: empty interval (nothing between), not a negative one.
        let near = offset_segment(
            p,
            n,
            Leg::To(p + Vec3::Y * 0.015),
            &OffsetPolicy::Normal(off),
        )
        .unwrap();
        assert_eq!(near.t_max, near.t_min);
        assert!(offset_segment(p, n, Leg::From(p + n * off), &OffsetPolicy::Normal(off)).is_none());
        assert!(offset_segment(p, n, Leg::Along(Vec3::ZERO), &OffsetPolicy::Normal(off)).is_none());
    }

    #[test]
    fn scaled_fixed_and_wachter_segments() {
        let (p, n) = (Vec3::new(1.0, 2.0, 3.0), Vec3::Y);
        let l = Vec3::new(1.0, 7.0, 3.0);
        for policy in [OffsetPolicy::Scaled(0.01), OffsetPolicy::Fixed(0.01)] {
            // No offset: the ray starts at the hit point, only its interval moves.
            let to = offset_segment(p, n, Leg::To(l), &policy).unwrap();
            assert_eq!((to.origin, to.dir, to.t_min), (p, Vec3::Y, 0.01));
            assert!((to.t_max - 4.99).abs() < 1e-5);
            let from = offset_segment(p, n, Leg::From(l), &policy).unwrap();
            assert_eq!((from.origin, from.t_min), (l, 0.01));
            assert!((from.at(from.t_max) - to.at(to.t_min)).length() < 1e-5);
            let down = offset_segment(p, n, Leg::Along(-Vec3::Y), &policy).unwrap();
            assert_eq!(
                (down.origin, down.t_min, down.t_max),
                (p, 0.01, f32::INFINITY)
            );
        }
        let w = OffsetPolicy::Wachter;
        let up = offset_segment(p, n, Leg::Along(Vec3::Y), &w).unwrap();
        assert_eq!(up.t_min, 0.0);
        assert!(up.origin.y > p.y && up.origin.x == p.x && up.origin.z == p.z);
        // 256 ULPs of y = 2 (ULP 2^-22).
        assert_eq!(up.origin.y, 2.0 + 256.0 * 2f32.powi(-22));
        let down = offset_segment(p, n, Leg::Along(-Vec3::Y), &w).unwrap();
        assert!(down.origin.y < p.y);
        // Light convention: the segment runs towards the offset point; the light end
        // excludes Wächter's gap at the light (both conventions, same segment).
        let from = offset_segment(p, n, Leg::From(l), &w).unwrap();
        let to = offset_segment(p, n, Leg::To(l), &w).unwrap();
        assert_eq!(from.origin, l);
        assert_eq!(to.origin, up.origin);
        assert_eq!(to.t_min, 0.0);
        // ... stopping WACHTER_T_ULPS ULPs of its length short of the offset point.
        let len = (up.origin - l).length();
        assert_eq!(from.t_max, len - WACHTER_T_ULPS * ulp(len));
        assert!((from.at(len) - up.origin).length() <= 1e-6);
        assert!(from.t_min > 0.0 && from.t_min < 1e-3);
        assert!((from.t_min - (to.at(to.t_max) - l).length()).abs() < 1e-6);
        // Near the origin the move is 1/65536 along the normal.
        let o = offset_segment(Vec3::ZERO, n, Leg::Along(Vec3::Y), &w).unwrap();
        assert_eq!(o.origin, Vec3::new(0.0, 1.0 / 65536.0, 0.0));
        // Negative coordinates move towards +∞ for a positive normal component too.
        assert!(offset_ray(Vec3::splat(-5.0), Vec3::ONE.normalize())
            .cmpgt(Vec3::splat(-5.0))
            .all());
    }

    /// A deterministic splitmix64 stream of floats in `[0, 1)`.
    struct Mix(u64);

    impl Mix {
        fn next(&mut self) -> f64 {
            self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
            ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
        }

        fn unit(&mut self) -> Vec3 {
            loop {
                let v = Vec3::new(
                    (2.0 * self.next() - 1.0) as f32,
                    (2.0 * self.next() - 1.0) as f32,
                    (2.0 * self.next() - 1.0) as f32,
                );
                if (0.01..=1.0).contains(&v.length_squared()) {
                    return v.normalize();
                }
            }
        }
    }

    /// Signed distance (f64, exact inputs) of `q` from the plane of the f32 triangle `t`, in
    /// units of its f64 normal's length (the sign is all that matters).
    fn plane_side(t: &[Vec3; 3], q: Vec3) -> f64 {
        let d = |v: Vec3| [v.x as f64, v.y as f64, v.z as f64];
        let (a, b, c, q) = (d(t[0]), d(t[1]), d(t[2]), d(q));
        let e1 = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let e2 = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
        let n = [
            e1[1] * e2[2] - e1[2] * e2[1],
            e1[2] * e2[0] - e1[0] * e2[2],
            e1[0] * e2[1] - e1[1] * e2[0],
        ];
        (q[0] - a[0]) * n[0] + (q[1] - a[1]) * n[1] + (q[2] - a[2]) * n[2]
    }

    #[test]
    fn wachter_offset_leaves_the_plane_at_every_magnitude_and_fixed_does_not() {
        let mut rng = Mix(5);
        let mut fixed_failures = Vec::new();
        for exp in -3..=7 {
            let magnitude = 10f32.powi(exp);
            let extent = magnitude.min(10.0);
            let (mut tried, mut fixed_bad) = (0u32, 0u32);
            while tried < 2000 {
                // A triangle of size ~extent translated to ~magnitude from the origin.
                let centre = rng.unit() * magnitude;
                let t = [
                    centre + rng.unit() * extent,
                    centre + rng.unit() * extent,
                    centre + rng.unit() * extent,
                ];
                let geo = (t[1] - t[0]).cross(t[2] - t[0]).normalize_or_zero();
                if geo == Vec3::ZERO || plane_side(&t, t[0] + geo).abs() == 0.0 {
                    continue; // degenerate after rounding
                }
                // A point on it as a renderer computes it (f32 barycentric interpolation),
                // and a random side to leave into.
                let (mut u, mut v) = (rng.next() as f32, rng.next() as f32);
                if u + v > 1.0 {
                    (u, v) = (1.0 - u, 1.0 - v);
                }
                let p = t[0] + (t[1] - t[0]) * u + (t[2] - t[0]) * v;
                let side = if rng.next() < 0.5 { -1.0 } else { 1.0 };
                let n = geo * side;
                let w = offset_segment(p, geo, Leg::Along(n), &OffsetPolicy::Wachter).unwrap();
                let d = plane_side(&t, w.origin) * plane_side(&t, p + n).signum();
                assert!(
                    d > 0.0,
                    "wachter origin {} of {p} on the wrong side of {t:?} (magnitude {magnitude})",
                    w.origin
                );
                // `fixed`: the first point the ray may find, p + n·fixed_epsilon in f32.
                let f = offset_segment(p, geo, Leg::Along(n), &OffsetPolicy::Fixed(1e-4)).unwrap();
                let first = f.origin + f.dir * f.t_min;
                if plane_side(&t, first) * plane_side(&t, p + n).signum() <= 0.0 {
                    fixed_bad += 1;
                }
                tried += 1;
            }
            println!(
                "magnitude 1e{exp}: fixed_epsilon 1e-4 not off the plane for {fixed_bad}/2000"
            );
            fixed_failures.push((exp, fixed_bad));
        }
        // At 1e7 a ULP is 1, so p + 1e-4·n rounds back to p and lies in the plane or on
        // either side of it at random.
        assert!(fixed_failures.iter().any(|&(e, bad)| e == 7 && bad > 0));
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
            ("offset", ParamValue::Str("tiny".into())),
            ("fixed_epsilon", ParamValue::Float(-1e-4)),
            ("fixed_epsilon", ParamValue::Float(f64::INFINITY)),
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
