//! Rays, hits and surface records: the data that flows between stages.
//!
//! All three are `#[repr(C)]` and [`bytemuck::Pod`] so they upload to device buffers as they
//! are; every field is 4 bytes and each `Vec3` is followed by a scalar so the layouts match
//! WGSL `vec3<f32>` + scalar packing (16-byte rows).

use bytemuck::{Pod, Zeroable};
use glam::Vec3;
use serde::{Deserialize, Serialize};

/// Triangle id of a miss (in [`Hit::tri`] and [`Surface::tri`]).
pub const NO_HIT: u32 = u32::MAX;

/// Triangle id of an any hit whose triangle the intersector does not report (an occlusion
/// query such as Embree's `rtcOccluded` says only that something lies in the segment): a hit,
/// but no triangle of the scene ([`Hit::occluded`]).
pub const UNKNOWN_TRI: u32 = u32::MAX - 1;

/// The kinds of rays the pipelines trace: a Whitted pipeline's (seed 000 §3.2.3), and the
/// ambient-occlusion and diffuse rays of seed 001's measurements.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
#[repr(u32)]
pub enum RayKind {
    /// Camera rays (only traced by the ray-cast primary variant).
    Primary = 0,
    /// Shadow rays between a shaded point and a light.
    Shadow = 1,
    /// Mirror reflection rays (eq. 3.3-3.4).
    Reflection = 2,
    /// Refraction rays (eq. 3.5-3.7).
    Refraction = 3,
    /// Ambient-occlusion rays: cosine-weighted, of a fixed length, any hit (seed 001 §4).
    Ao = 4,
    /// Diffuse bounce rays: cosine-weighted, nearest hit (seed 001 §4).
    Diffuse = 5,
}

impl RayKind {
    /// Every kind, in the order the driver processes batches.
    pub const ALL: [RayKind; 6] = [
        RayKind::Primary,
        RayKind::Shadow,
        RayKind::Reflection,
        RayKind::Refraction,
        RayKind::Ao,
        RayKind::Diffuse,
    ];

    /// Lower-case name as used in stats keys.
    pub fn name(self) -> &'static str {
        match self {
            RayKind::Primary => "primary",
            RayKind::Shadow => "shadow",
            RayKind::Reflection => "reflection",
            RayKind::Refraction => "refraction",
            RayKind::Ao => "ao",
            RayKind::Diffuse => "diffuse",
        }
    }

    /// The kind stored in [`Ray::kind`], if valid.
    pub fn from_u32(v: u32) -> Option<RayKind> {
        match v {
            0 => Some(RayKind::Primary),
            1 => Some(RayKind::Shadow),
            2 => Some(RayKind::Reflection),
            3 => Some(RayKind::Refraction),
            4 => Some(RayKind::Ao),
            5 => Some(RayKind::Diffuse),
            _ => None,
        }
    }

    /// The hit query this kind needs: any hit for shadow and ambient-occlusion rays, nearest
    /// for the others.
    pub fn hit_mode(self) -> HitMode {
        match self {
            RayKind::Shadow | RayKind::Ao => HitMode::Any,
            _ => HitMode::Closest,
        }
    }
}

/// Which hit an intersector must report.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum HitMode {
    /// The nearest hit in `(t_min, t_max)`; ties on `t` go to the lowest triangle id.
    Closest,
    /// Any hit in `(t_min, t_max)` (occlusion); which triangle is unspecified.
    Any,
    /// Edge-width occlusion of the shadow segment `(t_min, t_max)` (seed 003 §5, eq. 5.1 and
    /// listing 5.1 with its errata fixed) by the scene, for the light [`Ray::light`] of radius
    /// `R` (the scene light's radius). Every crossing of a triangle in the open interval is
    /// gathered once, sorted by `t` (ties by triangle id) and paired entry/exit (1st-2nd,
    /// 3rd-4th, ...); a pair's edge width is `exit t − entry t` (world units: ray directions
    /// are unit). The scan ([`crate::edge_width::EdgeWidthScan`]) stops at the first pair of
    /// width `≥ R`; an unpaired entry at the end (odd count) occludes fully; otherwise the
    /// occlusion is `clamp(max width / R, 0, 1)` (eq. 5.1). With `R = 0` any crossing occludes
    /// fully (hard shadows).
    ///
    /// The [`Hit`] encodes the answer: a miss ([`NO_HIT`]) when the occlusion is 0 (no
    /// crossing, or only zero-width pairs); otherwise `tri` and `t` are the entry crossing of
    /// the widest pair scanned (of the stopping pair, of the unpaired entry, or with `R = 0`
    /// the first crossing), `u` the occlusion in `(0, 1]` and `v` the widest width scanned
    /// (`f32::INFINITY` for an unpaired entry and for `R = 0`). Intersectors that do not
    /// implement it return [`crate::CoreError::Unsupported`]; those that do replace the stored
    /// hit (the query is not merged across calls).
    ///
    /// The [`EdgePairing`](crate::edge_width::EdgePairing) says which entry and exit form a
    /// pair: any consecutive two, or only triangles sharing a vertex (the thesis's light-leak
    /// fix, fig. 5.10; any other pair has an infinite width).
    EdgeWidth(crate::edge_width::EdgePairing),
}

impl HitMode {
    /// Whether this is an edge-width query (with either pairing rule).
    pub fn is_edge_width(self) -> bool {
        matches!(self, HitMode::EdgeWidth(_))
    }

    /// Lower-case name for messages (`closest`, `any`, `edge_width`).
    pub fn name(self) -> &'static str {
        match self {
            HitMode::Closest => "closest",
            HitMode::Any => "any",
            HitMode::EdgeWidth(_) => "edge_width",
        }
    }

    /// The error of an intersector (stage `intersect`, variant `variant`) that does not answer
    /// this mode (edge-width queries on the backends and traversals that lack them).
    pub fn unsupported(self, variant: &str) -> crate::CoreError {
        crate::CoreError::Unsupported {
            stage: "intersect",
            variant: variant.into(),
            what: format!(
                "{} hit queries (edge-width soft shadows are implemented by the CPU `brute`, \
                 `bvh` and `kdtree` intersectors on whole-scene queries)",
                self.name()
            ),
        }
    }
}

/// A ray with its payload (64 bytes).
///
/// The valid interval is the open range `(t_min, t_max)` along `dir`. `dir` need not be unit
/// length for intersection, but every ray generator in crsh emits unit directions so that `t`
/// is a distance.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct Ray {
    /// Origin. For shadow rays in the thesis convention this is the light position (eq. 3.1).
    pub origin: Vec3,
    /// Start of the valid interval.
    pub t_min: f32,
    /// Direction.
    pub dir: Vec3,
    /// End of the valid interval.
    pub t_max: f32,
    /// Radiance weight carried to the pixel (product of material weights along the path).
    pub throughput: Vec3,
    /// [`RayKind`] as `u32`.
    pub kind: u32,
    /// Pixel index (`y * width + x`) the ray contributes to.
    pub pixel: u32,
    /// Light index for shadow rays; the sample index (the `s` of the random-number key
    /// (pixel, sample, bounce)) for ambient-occlusion and diffuse rays; [`u32::MAX`] for other
    /// kinds.
    pub light: u32,
    /// Bounce depth: 0 for primary rays and for rays spawned from primary hits' surfaces
    /// counts as 1, and so on.
    pub depth: u32,
    /// Index of the [`Surface`] (in the batch that spawned this ray) the ray belongs to.
    pub source: u32,
}

impl Ray {
    /// A ray of `kind` from `origin` along `dir` over `(t_min, t_max)`, with the payload of a
    /// ray spawned from the first surface of a batch: throughput one, pixel and source 0,
    /// no light or sample ([`u32::MAX`]), depth 1. Set the other fields with struct update
    /// syntax: `Ray { pixel: 7, light: 0, ..Ray::new(RayKind::Shadow, o, d, 0.0, 1.0) }`.
    pub fn new(kind: RayKind, origin: Vec3, dir: Vec3, t_min: f32, t_max: f32) -> Ray {
        Ray {
            origin,
            t_min,
            dir,
            t_max,
            throughput: Vec3::ONE,
            kind: kind as u32,
            pixel: 0,
            light: u32::MAX,
            depth: 1,
            source: 0,
        }
    }

    /// The kind of this ray; panics only if the field was corrupted.
    pub fn ray_kind(&self) -> RayKind {
        RayKind::from_u32(self.kind).expect("corrupt ray kind")
    }

    /// Point at parameter `t`.
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + self.dir * t
    }

    /// True when origin, direction and interval are usable: [`is_valid_segment`] of its fields.
    #[inline]
    pub fn is_valid(&self) -> bool {
        is_valid_segment(self.origin, self.dir, self.t_min, self.t_max)
    }
}

/// `Ok` when a batch of `rays` rays comes with as many hits; else the error every stage gives
/// for a mismatch (`what`: what the rays are, e.g. `"rays"` or `"shadow rays"`).
pub fn check_hits_per_ray(what: &str, rays: usize, hits: usize) -> crate::Result<()> {
    if rays == hits {
        Ok(())
    } else {
        Err(crate::CoreError::InvalidInput(format!(
            "{rays} {what} but {hits} hits"
        )))
    }
}

/// Whether a ray with these fields is usable: finite origin and direction, a non-zero
/// direction, and interval ends that are not NaN (infinite ends are allowed). [`Ray::is_valid`],
/// for code that keeps only these fields of a ray.
#[inline]
pub fn is_valid_segment(origin: Vec3, dir: Vec3, t_min: f32, t_max: f32) -> bool {
    origin.is_finite()
        && dir.is_finite()
        && dir.length_squared() > 0.0
        && !t_min.is_nan()
        && !t_max.is_nan()
}

/// The result of intersecting one ray (16 bytes).
///
/// Barycentrics follow Möller-Trumbore: the hit point is `(1-u-v)·a + u·b + v·c` for the
/// triangle's vertices `a, b, c`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct Hit {
    /// Ray parameter of the hit; `f32::INFINITY` for a miss.
    pub t: f32,
    /// Triangle id in the scene's triangle order, or [`NO_HIT`].
    pub tri: u32,
    /// Barycentric weight of vertex `b`.
    pub u: f32,
    /// Barycentric weight of vertex `c`.
    pub v: f32,
}

impl Hit {
    /// A miss.
    pub const MISS: Hit = Hit {
        t: f32::INFINITY,
        tri: NO_HIT,
        u: 0.0,
        v: 0.0,
    };

    /// An any hit of a segment ending at `t` whose triangle is unknown ([`UNKNOWN_TRI`]).
    pub fn occluded(t: f32) -> Hit {
        Hit {
            t,
            tri: UNKNOWN_TRI,
            u: 0.0,
            v: 0.0,
        }
    }

    /// Whether this records a hit.
    pub fn is_hit(&self) -> bool {
        self.tri != NO_HIT
    }

    /// Whether `self` should replace `best` as the closest hit: smaller `t`, ties to the lower
    /// triangle id. Every closest-hit intersector uses this rule so that results are identical.
    pub fn closer_than(&self, best: &Hit) -> bool {
        self.t < best.t || (self.t == best.t && self.tri < best.tri)
    }

    /// Whether `self` and `other` (both hits of one closest-hit ray) name a different nearest
    /// hit: different triangles whose `t` differ by more than 1e-6 relative. A different
    /// triangle at (almost) the same `t` is a tie, not a mismatch. The one rule accuracy
    /// comparisons use ([`crate::pipeline::compare_hits`], the stability suite).
    pub fn nearest_differs(&self, other: &Hit) -> bool {
        self.tri != other.tri && (self.t - other.t).abs() > 1e-6 * self.t.abs().max(other.t.abs())
    }
}

/// A shaded point: one G-buffer texel after the primary pass, or one path vertex found by a
/// reflection / refraction ray (80 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct Surface {
    /// World-space position of the hit.
    pub position: Vec3,
    /// Triangle id, or [`NO_HIT`] when the ray (or the pixel) saw the background.
    pub tri: u32,
    /// Interpolated shading normal (eq. 3.17-3.18), unit length, on the side the ray came from.
    pub normal: Vec3,
    /// Material index.
    pub material: u32,
    /// Unit direction of the ray that arrived here (camera → point for primaries).
    pub incident: Vec3,
    /// Pixel index (`y * width + x`).
    pub pixel: u32,
    /// Radiance weight of this vertex.
    pub throughput: Vec3,
    /// Bounce depth (0 for primary surfaces).
    pub depth: u32,
    /// Geometric (face) normal, unit length, on the side the ray came from.
    pub geo_normal: Vec3,
    /// Bit flags: [`Surface::FRONT_FACE`]; bits 8-31 hold the sample index of a diffuse path
    /// vertex ([`Surface::sample`]).
    pub flags: u32,
}

impl Surface {
    /// Set when the arriving ray hit the triangle's front face (entering a transparent
    /// object); clear when it hit the back face (leaving it).
    pub const FRONT_FACE: u32 = 1;

    /// A background sample for `pixel`.
    pub fn background(pixel: u32, incident: Vec3, throughput: Vec3, depth: u32) -> Surface {
        Surface {
            position: Vec3::ZERO,
            tri: NO_HIT,
            normal: Vec3::ZERO,
            material: 0,
            incident,
            pixel,
            throughput,
            depth,
            geo_normal: Vec3::ZERO,
            flags: 0,
        }
    }

    /// Whether this record holds a surface hit.
    pub fn is_hit(&self) -> bool {
        self.tri != NO_HIT
    }

    /// The sample index of a diffuse path vertex (0 for other records): which of a pixel's
    /// paths it lies on, part of the random-number key.
    pub fn sample(&self) -> u32 {
        self.flags >> Self::SAMPLE_SHIFT
    }

    /// Where [`Surface::sample`] starts in [`Surface::flags`].
    pub const SAMPLE_SHIFT: u32 = 8;

    /// Whether the arriving ray hit the front face.
    pub fn front_face(&self) -> bool {
        self.flags & Self::FRONT_FACE != 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hits_per_ray_mismatch_is_one_invalid_input_message() {
        assert!(check_hits_per_ray("rays", 3, 3).is_ok());
        let e = check_hits_per_ray("shadow rays", 3, 2).unwrap_err();
        assert!(matches!(e, crate::CoreError::InvalidInput(_)), "{e:?}");
        assert!(e.to_string().contains("3 shadow rays but 2 hits"), "{e}");
    }

    #[test]
    fn layouts_are_gpu_friendly() {
        assert_eq!(std::mem::size_of::<Ray>(), 64);
        assert_eq!(std::mem::size_of::<Hit>(), 16);
        assert_eq!(std::mem::size_of::<Surface>(), 80);
    }

    #[test]
    fn closest_tie_breaks_on_triangle_id() {
        let a = Hit {
            t: 1.0,
            tri: 3,
            u: 0.0,
            v: 0.0,
        };
        let b = Hit {
            t: 1.0,
            tri: 5,
            u: 0.0,
            v: 0.0,
        };
        assert!(a.closer_than(&b));
        assert!(!b.closer_than(&a));
        assert!(a.closer_than(&Hit::MISS));
    }
}
