//! `embree`: Intel's Embree 3 (Wald et al. 2014, "Embree: a kernel framework for efficient
//! CPU ray tracing") through the `embree3` crate, the tracer CPU renderers use: the anchor
//! every other intersector is measured against.
//!
//! The scene's triangles go into one Embree triangle geometry (vertex and index buffers as
//! loaded; Embree skips degenerate triangles itself), committed with build quality
//! `quality` (`high` is Embree's spatial-split SBVH builder). Queries, by `mode`:
//!
//! - `single`: `rtcIntersect1` / `rtcOccluded1`, ray by ray;
//! - `packet4`, `packet8`, `packet16`: `rtcIntersectN` / `rtcOccludedN`, packets filled from
//!   consecutive rays of the batch in the pipeline's order (generation order, or the order a
//!   hash and sort gave them), lanes that need no query left invalid.
//!
//! `coherent` sets the intersect context's coherent flag (Embree's hint that the rays of a
//! query are coherent, which it uses for packets).
//!
//! # Hits
//!
//! Closest hits map to crsh's [`Hit`](crsh_core::Hit) unchanged: `primID` is the scene triangle id (one
//! geometry, triangles in scene order), `tfar` is `t`, Embree's `u`, `v` are the weights of
//! vertices `b` and `c`, as crsh's. They merge into the stored hits with [`Hit::closer_than`](crsh_core::Hit::closer_than).
//! Any-hit queries (`rtcOccluded*`) report only that something lies in the segment: the hit
//! stored is [`Hit::occluded`](crsh_core::Hit::occluded) (the segment's end as `t`, the triangle unknown), which
//! shading and accuracy read as a hit.
//!
//! Embree's ray-triangle test is its own (Plücker-style with a watertight edge test in
//! robust mode, Möller-Trumbore-like otherwise) and its interval is `[tnear, tfar]` where
//! crsh's is open, so hits can differ from brute force's where a ray grazes a shared edge
//! or meets two triangles at one `t` (Embree keeps whichever it reached first, crsh the
//! lower id; the accuracy report counts such a tie as agreement when the `t` agree).
//!
//! # Counting
//!
//! Embree does not count its box and triangle tests, so this variant reports them as
//! unknown ([`Stats::mark_tests_uncounted`](crsh_core::Stats::mark_tests_uncounted)): `null` in the stats JSON, "—" in tables,
//! never 0. Rays and stage times are counted by the frame driver as for every variant.
//!
//! Rays are traced in parallel with rayon in tasks of [`TASK`] rays (whole packets), each
//! ray's or packet's query independent of the others, so hits do not depend on the thread
//! count. Candidate queries and edge-width queries are unsupported.

use crsh_core::{CoreError, ParamInfo, Registry, Result, StageKind, StageSpec, StageVariantInfo};

use crate::backend::Cpu;

/// The query `mode` names.
pub const MODES: [&str; 4] = ["single", "packet4", "packet8", "packet16"];

/// The build `quality` names (Embree's `RTC_BUILD_QUALITY_LOW`, `_MEDIUM`, `_HIGH`).
pub const QUALITIES: [&str; 3] = ["low", "medium", "high"];

/// Rays per rayon task: a multiple of every packet width.
pub const TASK: usize = 256;

/// How rays are handed to Embree (parameter `mode`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// `rtcIntersect1` / `rtcOccluded1`.
    Single,
    /// 4-wide packets.
    Packet4,
    /// 8-wide packets.
    Packet8,
    /// 16-wide packets.
    Packet16,
}

impl Mode {
    /// The mode called `name` (one of [`MODES`]).
    pub fn from_name(name: &str) -> Option<Mode> {
        match name {
            "single" => Some(Mode::Single),
            "packet4" => Some(Mode::Packet4),
            "packet8" => Some(Mode::Packet8),
            "packet16" => Some(Mode::Packet16),
            _ => None,
        }
    }

    /// Its name.
    pub fn name(self) -> &'static str {
        MODES[self as usize]
    }
}

/// The Embree build quality (parameter `quality`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Quality {
    /// `RTC_BUILD_QUALITY_LOW`: Morton builder.
    Low,
    /// `RTC_BUILD_QUALITY_MEDIUM`: binned SAH.
    Medium,
    /// `RTC_BUILD_QUALITY_HIGH`: SAH with spatial splits.
    High,
}

impl Quality {
    /// The quality called `name` (one of [`QUALITIES`]).
    pub fn from_name(name: &str) -> Option<Quality> {
        match name {
            "low" => Some(Quality::Low),
            "medium" => Some(Quality::Medium),
            "high" => Some(Quality::High),
            _ => None,
        }
    }

    /// Its name.
    pub fn name(self) -> &'static str {
        QUALITIES[self as usize]
    }
}

/// The parameters of an `embree` stage spec: `(mode, coherent, quality)`.
pub fn params(spec: &StageSpec) -> Result<(Mode, bool, Quality)> {
    let invalid = |key: &str, name: &str, known: &[&str]| CoreError::InvalidParam {
        key: format!("embree.{key}"),
        reason: format!("`{name}` is not one of {}", known.join(", ")),
    };
    let mode = spec.str("mode")?;
    let mode = Mode::from_name(mode).ok_or_else(|| invalid("mode", mode, &MODES))?;
    let quality = spec.str("quality")?;
    let quality =
        Quality::from_name(quality).ok_or_else(|| invalid("quality", quality, &QUALITIES))?;
    Ok((mode, spec.bool("coherent")?, quality))
}

/// The catalogue entry of the `embree` intersector (listed in every build; constructed only
/// with the `embree` cargo feature).
pub fn info() -> StageVariantInfo {
    StageVariantInfo::new(
        StageKind::Intersect,
        "embree",
        "Intel Embree 3 (rtcIntersect/rtcOccluded, single rays or 4/8/16-wide packets of \
         consecutive rays), closest and any hit (Wald et al. 2014); its tests are not \
         counted",
    )
    .param(ParamInfo::choice(
        "mode",
        "single",
        &MODES,
        "`single`: rtcIntersect1/rtcOccluded1; `packetN`: N-wide packets of consecutive rays \
         of the batch, in the pipeline's order",
    ))
    .param(ParamInfo::bool(
        "coherent",
        false,
        "the intersect context's coherent flag (RTC_INTERSECT_CONTEXT_FLAG_COHERENT)",
    ))
    .param(ParamInfo::choice(
        "quality",
        "high",
        &QUALITIES,
        "Embree build quality: `low` (Morton), `medium` (binned SAH), `high` (SAH with \
         spatial splits)",
    ))
    .scene_only()
    .built_if(
        AVAILABLE,
        "not in this build: needs the `embree` cargo feature and Embree 3 (libembree-dev)",
    )
}

/// Registers `embree` ([`info`]; with the `embree` feature its constructor builds the Embree
/// scene, without it the constructor fails with [`CoreError::NotBuilt`]).
pub fn register(registry: &mut Registry<Cpu>) -> Result<()> {
    registry.add_intersector(info(), |ctx, spec| {
        let (mode, coherent, quality) = params(spec)?;
        build(ctx.scene, mode, coherent, quality)
    })?;
    Ok(())
}

#[cfg(feature = "embree")]
fn build(
    scene: &std::sync::Arc<crsh_scene::Scene>,
    mode: Mode,
    coherent: bool,
    quality: Quality,
) -> Result<Box<dyn crsh_core::Intersector<Cpu>>> {
    Ok(Box::new(tracer::Embree::new(
        scene, mode, coherent, quality,
    )?))
}

#[cfg(not(feature = "embree"))]
fn build(
    _scene: &std::sync::Arc<crsh_scene::Scene>,
    _mode: Mode,
    _coherent: bool,
    _quality: Quality,
) -> Result<Box<dyn crsh_core::Intersector<Cpu>>> {
    Err(not_built())
}

/// The error of asking for `embree` in a build without the `embree` feature.
pub fn not_built() -> CoreError {
    CoreError::NotBuilt {
        stage: "intersect",
        variant: "embree".into(),
        feature: "embree",
        needs: "Embree 3 (Debian/Ubuntu: `apt-get install libembree-dev`)",
    }
}

/// Whether this build can construct `embree` (the `embree` feature is on).
pub const AVAILABLE: bool = cfg!(feature = "embree");

#[cfg(feature = "embree")]
pub mod tracer;

#[cfg(test)]
mod tests;
