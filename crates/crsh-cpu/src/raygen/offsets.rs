//! The `offsets` parameter the surface-leaving ray generators share (`whitted`, `ao`,
//! `diffuse`): seed 001's origin offsets, applied to each ray as it is made.
//!
//! `offsets = none` (the default) leaves rays as they are. `center`, `vertex`, `median` and
//! `polygon` build that hemisphere set ([`super::origin_offset`], seed 001 §3.1-3.2) when the
//! stage is constructed, and then:
//! - an extension ray leaving triangle `T` (AO, diffuse, reflection, refraction, and shadow
//!   rays with `shadow_origin = surface`) gets `t_min` raised to the largest exit distance
//!   among `T`'s hemispheres that contain its start ([`Offsets::apply`]);
//! - a shadow ray that starts at the light and ends on `T` gets `t_max` cut back to where it
//!   enters `T`'s hemispheres ([`Offsets::cut_end`]).
//!
//! A ray whose interval the offset empties (`t_min ≥ t_max`) is kept with `t_min = t_max`:
//! it can hit nothing, the intersectors end it without traversal, and it still counts as a ray
//! of its batch.

use std::sync::Arc;

use crsh_core::{CoreError, ParamInfo, Ray, Result, StageSpec, StageVariantInfo};
use crsh_scene::Scene;

use crate::raygen::origin_offset::{HemisphereSet, SetKind};

/// The values `offsets` accepts.
pub const OFFSET_NAMES: [&str; 5] = ["none", "center", "vertex", "median", "polygon"];

/// `info` with the `offsets` parameter.
pub fn offsets_param(info: StageVariantInfo) -> StageVariantInfo {
    info.param(ParamInfo::choice(
        "offsets",
        "none",
        &OFFSET_NAMES,
        "seed 001 origin offsets: move extension-ray starts past the empty hemisphere set \
         `center`, `vertex`, `median` or `polygon` (§3.1) of the triangle they leave",
    ))
}

/// A generator's origin offsets: none, or a hemisphere set of the scene.
#[derive(Clone, Debug, Default)]
pub struct Offsets {
    set: Option<Arc<HemisphereSet>>,
}

impl Offsets {
    /// No offsets.
    pub fn none() -> Offsets {
        Offsets { set: None }
    }

    /// The offsets of a hemisphere set already built.
    pub fn with(set: Arc<HemisphereSet>) -> Offsets {
        Offsets { set: Some(set) }
    }

    /// The offsets param `offsets` of a resolved `spec` asks for, built over `scene`.
    pub fn from_spec(scene: &Scene, spec: &StageSpec) -> Result<Offsets> {
        let name = spec.str("offsets")?;
        if name == "none" {
            return Ok(Offsets::none());
        }
        let kind = SetKind::from_name(name).ok_or_else(|| CoreError::InvalidParam {
            key: "raygen.offsets".into(),
            reason: format!("`{name}` is not one of {}", OFFSET_NAMES.join(", ")),
        })?;
        Ok(Offsets::with(Arc::new(HemisphereSet::build(scene, kind))))
    }

    /// Whether a hemisphere set is in use.
    pub fn is_some(&self) -> bool {
        self.set.is_some()
    }

    /// Bytes of the hemisphere set's tables in the paper's record sizes (§3.2), plus the
    /// per-slot normals the query reads; 0 without offsets.
    pub fn table_bytes(&self) -> u64 {
        self.set
            .as_ref()
            .map_or(0, |s| (s.bytes() + s.normal_bytes()) as u64)
    }

    /// The hemisphere set, if any.
    pub fn hemispheres(&self) -> Option<&Arc<HemisphereSet>> {
        self.set.as_ref()
    }

    /// Raises `ray.t_min` past the hemispheres of triangle `tri` that the ray leaves
    /// (`tri` = [`crsh_core::NO_HIT`] or out of range: unchanged). Returns whether the interval
    /// is still non-empty; an emptied one is left as `t_min = t_max`.
    #[inline]
    pub fn apply(&self, tri: u32, ray: &mut Ray) -> bool {
        let Some(set) = &self.set else {
            return true;
        };
        let t = set.offset_t_min(tri, ray);
        if t >= ray.t_max {
            ray.t_min = ray.t_max;
            false
        } else {
            ray.t_min = ray.t_min.max(t);
            true
        }
    }

    /// Cuts `ray.t_max` back to where a segment arriving at triangle `tri` (a shadow ray from
    /// a light) enters its hemispheres. Returns whether the interval is still non-empty; an
    /// emptied one is left as `t_max = t_min`.
    #[inline]
    pub fn cut_end(&self, tri: u32, ray: &mut Ray) -> bool {
        let Some(set) = &self.set else {
            return true;
        };
        let t = set.cut_t_max(tri, ray);
        if t <= ray.t_min {
            ray.t_max = ray.t_min;
            false
        } else {
            ray.t_max = ray.t_max.min(t);
            true
        }
    }
}
