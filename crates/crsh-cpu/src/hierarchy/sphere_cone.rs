//! The sphere-cone ray-space hierarchy (seed 000 §3.2.7, eq. 3.8-3.15; seed 004 §4).
//!
//! Every node bounds a set of rays by a [`SphereCone`]: the sphere contains the ray origins,
//! the cone (apex at the origin of direction space) contains the ray directions. Together they
//! bound the volume the rays sweep: every point `o + t·d` (`t ≥ 0`) of a covered ray lies in
//! the Minkowski sum *sphere ⊕ cone* (see [`swept_excess`]).
//!
//! # Construction
//!
//! The leaves are the rays in the `order` the sorter produced. The hierarchy is built bottom-up,
//! one flat array per level, each level in parallel with rayon (one task per node; a node only
//! reads its own children, so the result does not depend on the thread count):
//!
//! - **Level 0** (the thesis' lowest node level, level 1 in its numbering) groups `subdivision`
//!   consecutive leaves (the last node may have fewer).
//!   - *Cone*: the incremental construction of eq. 3.8-3.11 (seed 004 §4): start with the
//!     zero-angle cone of the first ray and add the rays one by one; a ray outside the cone
//!     rotates and widens it so that the new cone just touches the farthest generator `e` of
//!     the old cone (eq. 3.8-3.9) and the ray `r`: axis `normalize(e + r)` (eq. 3.10),
//!     half-angle `acos(x_new·r)` (eq. 3.11). This is computed in angle form (see
//!     [`extend_cone`]), which is the same cone while the result is narrower than a hemisphere
//!     and stays correct beyond it, where `e + r` would point the wrong way or vanish. The
//!     builder sums and halves those angles on `(cos, sin)` pairs (square roots, no
//!     trigonometry); the stored angle is re-measured either way (*Float rounding*).
//!     With parameter `leaf_cone = extremes` the axis is chosen without that sequence instead
//!     (see *Leaf cones from extreme rays* below).
//!   - *Sphere*: the exact minimal sphere of the origins ([`crsh_scene::bounding::min_sphere`],
//!     Welzl); rays that share an origin (shadow rays from a light) get radius 0. With
//!     parameter `leaf_sphere = box` the centre is the origins' bounding-box centre instead
//!     (`(min + max)·0.5` in `f32`), the radius measured from it the same way: no Welzl
//!     iterations. Its radius is at most half the box's diagonal, so at most √3 times the
//!     minimal one (which spans the box's longest side); over a node's origins on one patch
//!     of surface it is close to minimal (README, "Object side on obvhs's BVH").
//! - **Upper levels** group `subdivision` consecutive nodes of the level below.
//!   - *Cone*: the union of the children's cones, folded left to right with the *tight*
//!     pairwise union [`cone_union`] (the smallest cone containing two cones). For two cones it
//!     is never wider than the erratum formula of eq. 3.12-3.13 (`normalize(x1 + x2)`,
//!     `acos(x1·x2)/2 + max(φ1, φ2)`), and equal to it when `φ1 = φ2`; folding it over `n`
//!     children generalises it without the erratum's growth by `max(φ)` at every step.
//!   - *Sphere*: the children's spheres folded with the tight pairwise union [`sphere_union`]
//!     (the smallest sphere containing two spheres), instead of the conservative eq. 3.14-3.15.
//! - **Depth**: `depth` levels are kept (the thesis limits the levels because the high nodes
//!   grow too large, §3.2.7), except that construction *stops early* once a level has a
//!   single node: a level above it would only repeat that root. So `levels.len() =
//!   min(depth, L)` where `L` is the number of levels down to and including the first one with
//!   a single node, and level `l` (0-based) has `ceil(n / subdivision^(l+1))` nodes
//!   ([`level_sizes`]).
//!
//! # Leaf cones from extreme rays (`leaf_cone = extremes`)
//!
//! Eq. 3.8-3.11 add the rays one at a time, and each step that widens the cone needs the
//! previous step's axis and angle (square roots and divisions in a chain): on Sponza's shadow
//! rays that chain was most of the hierarchy stage. Since the stored half-angle is re-measured
//! from the stored axis anyway (*Float rounding*), any axis gives a correct cone; the
//! construction only decides how narrow it is. `extremes` takes the better of two axes, each
//! found by independent passes over the node's directions:
//!
//! - the **mean** direction `normalize(Σ d̂ᵢ)`;
//! - the **bisector of two extreme rays** `normalize(a + b)`, with `a` the direction farthest
//!   from the first ray's (smallest dot product) and `b` the one farthest from `a` (an
//!   approximate diameter of the directions, as in Ritter's bounding sphere);
//!
//! "better" being the axis whose farthest direction is nearer (the larger smallest dot
//! product; the mean on a tie). Around a cluster of directions these axes are tight; over
//! spread directions they can be wider than eq. 3.8-3.11's, so a node whose widest ray is
//! more than about 14° from the chosen axis ([`WIDE_LEAF_COS`]) runs eq. 3.8-3.11 as well and
//! keeps the narrower axis. When the directions nearly cancel (`|Σ d̂ᵢ| ≤ 10⁻³·n`) the node
//! uses eq. 3.8-3.11 alone, which also recognises a cone of every direction.
//! Measured with the `dual` preset (1024², depth 3, subdivision 16, depth 3; 2026-12-04):
//! Sponza 16.79M bound tests against 17.02M with eq. 3.8-3.11 (37.1 against 37.3 tests per
//! ray), the dining room 38.5 against 38.9, cornell-mirror 4.7 either way, the images
//! identical; the hierarchy stage 54-59 against 57-62 ms on Sponza, 38-40 against 44-46 on the
//! dining room, 40-42 against 49-50 on cornell-mirror (two alternating runs each); criterion
//! `hierarchy/sphere_cone_s16_d3_extremes` 2.53 ms against `sphere_cone_s16_d3` 3.73 ms
//! (Sponza 256², the same run). The mean direction alone was cheaper still but looser (Sponza
//! 19.02M bound tests). The default stays the thesis's construction.
//!
//! # Narrow lowest nodes in `f32` lanes
//!
//! A lowest node of `leaf_cone = extremes` whose rays are usable, of squared length in
//! `[2⁻¹⁰⁰, 2¹⁰⁰]`, not cancelling, and whose chosen axis is narrow (widest ray within
//! [`WIDE_LEAF_COS`]) is built from its rays gathered into `f32` columns: unit directions,
//! the two heuristic axes and the widest-ray search run on four rays per SSE2 instruction,
//! comparing rays by their squared chord `|d̂ − a|²` (the dot product's order, with `f32`
//! precision left for small angles). The stored half-angle is the exact `f64` maximum of
//! `atan2(|a × d|, a · d)` over the node's rays: only rays whose `f32` chord comes within twice
//! a bound on its error (`2·10⁻⁶`) of the largest are measured, and the true widest ray is
//! always among them (tested bit for bit against measuring every ray). Spheres and reaches use
//! the same `f64` formulas (a one-point node's reach as `√max(t_max²·|d|²)`, within `f64`
//! rounding of the same). Other nodes are built as before, one `f64` ray at a time. Criterion
//! `hierarchy/sphere_cone_s16_d3_extremes/sponza` (Sponza's 256² shadow batch): 1.26 against
//! 1.56 ms (−18.5 %, p < 0.01, the previous build as baseline); what is left is mostly the
//! gather of the rays through the sort order.
//!
//! # Float rounding
//!
//! All construction arithmetic runs in `f64`, except the axis of a narrow lowest node with
//! `leaf_cone = extremes`, chosen in `f32` lanes four rays at a time (its half-angle is still
//! the exact `f64` maximum; see *Narrow lowest nodes in `f32` lanes*). When a node is stored in `f32`, its bound is
//! *re-measured* against the rounded `f32` axis and centre (half-angle = the largest angle
//! from the stored axis to a child direction or child cone; radius = the largest distance
//! from the stored centre to a child origin or child sphere), so containment does not depend
//! on the accuracy of the construction formulas. Then the half-angle is enlarged by
//! [`CONE_REL_MARGIN`] (relative) plus [`CONE_ABS_MARGIN`] radians and the radius by
//! [`SPHERE_REL_MARGIN`] (relative), and both are rounded up to the next `f32`. Every
//! child therefore lies inside its parent with a little room to spare for consumers that test
//! in `f32`. Cones are clamped to half-angle π (all directions).
//!
//! # Degenerate input
//!
//! No rays give no levels (an empty hierarchy). An `order` that is not a permutation of the
//! batch (wrong length, an index out of range, a repeated ray), or a ray with a non-finite
//! origin or a zero-length or non-finite direction, is [`CoreError::InvalidInput`] naming the
//! first such leaf (deterministically).

use std::f64::consts::PI;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use crsh_core::{
    f32_up, Cone, CoreError, HierarchyBuilder, ParamInfo, Ray, RayHierarchy, Registry, Result,
    Sphere, SphereCone, StageKind, StageSpec, StageVariantInfo, Stats,
};
use crsh_scene::bounding::min_sphere;
use crsh_scene::Scene;
use glam::{DVec3, Vec3};
use rayon::prelude::*;

use crate::Cpu;

mod narrow_leaf;

/// Default children per node.
pub const DEFAULT_SUBDIVISION: u32 = 8;
/// Accepted children per node.
pub const SUBDIVISION_RANGE: std::ops::RangeInclusive<u32> = 2..=64;
/// Default number of node levels kept above the leaves.
pub const DEFAULT_DEPTH: u32 = 2;
/// Accepted numbers of node levels.
pub const DEPTH_RANGE: std::ops::RangeInclusive<u32> = 1..=8;

/// Relative enlargement of every stored cone half-angle (rounding guard, see module docs).
pub const CONE_REL_MARGIN: f64 = 1e-6;
/// Absolute enlargement of every stored cone half-angle, in radians (rounding guard).
pub const CONE_ABS_MARGIN: f64 = 1e-6;
/// Relative enlargement of every stored sphere radius (rounding guard).
pub const SPHERE_REL_MARGIN: f64 = 1e-6;

/// Below this length the component of one axis orthogonal to another counts as zero (the
/// axes are parallel or opposite) and a fixed perpendicular is used instead.
const PERP_EPS: f64 = 1e-12;

/// The catalogue entry of this variant.
pub fn info() -> StageVariantInfo {
    StageVariantInfo::new(
        StageKind::Hierarchy,
        "sphere_cone",
        "bottom-up sphere-cone ray-space hierarchy: incremental leaf cones (seed 000 \
         eq. 3.8-3.11, seed 004 §4), tight cone and sphere unions above (eq. 3.12-3.15 \
         with the erratum), seed 000 §3.2.7",
    )
    .param(ParamInfo::int(
        "subdivision",
        DEFAULT_SUBDIVISION as i64,
        *SUBDIVISION_RANGE.start() as i64,
        *SUBDIVISION_RANGE.end() as i64,
        "children per node (rays per lowest node)",
    ))
    .param(ParamInfo::int(
        "depth",
        DEFAULT_DEPTH as i64,
        *DEPTH_RANGE.start() as i64,
        *DEPTH_RANGE.end() as i64,
        "node levels kept above the leaves (fewer when a level already has a single node)",
    ))
    .param(ParamInfo::choice(
        "origins",
        "ray",
        &["ray", "start"],
        "what the spheres bound: the rays' origins (the thesis), or their segments' starts \
         `o + t_min·d` (seed 001's origin offsets then narrow every node)",
    ))
    .param(ParamInfo::choice(
        "leaf_cone",
        "incremental",
        &["incremental", "extremes"],
        "how a lowest node's cone axis is found: eq. 3.8-3.11 one ray at a time (the \
         thesis), or the better of the mean direction and the bisector of two extreme rays \
         (no sequential chain; the half-angle is measured either way)",
    ))
    .param(ParamInfo::choice(
        "leaf_sphere",
        "welzl",
        &LeafSphere::NAMES,
        "how a lowest node's sphere centre is found: the exact minimal sphere of the \
         origins (Welzl, the thesis), or the centre of their bounding box (no iterations; \
         the radius is measured either way)",
    ))
}

/// How a lowest node's sphere centre is found (parameter `leaf_sphere`, see the module doc).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LeafSphere {
    /// The exact minimal sphere of the origins (Welzl's algorithm, the thesis).
    #[default]
    Welzl,
    /// The centre of the origins' bounding box, computed in `f32` as `(min + max) · 0.5`.
    BoxCentre,
}

impl LeafSphere {
    /// The parameter values, in the order of the variants.
    pub const NAMES: [&'static str; 2] = ["welzl", "box"];

    /// Parses the parameter value (`welzl`, `box`).
    pub fn parse(s: &str) -> Option<LeafSphere> {
        match s {
            "welzl" => Some(LeafSphere::Welzl),
            "box" => Some(LeafSphere::BoxCentre),
            _ => None,
        }
    }

    /// Parses `spec`'s `leaf_sphere` for the variant `variant`.
    pub(crate) fn of(variant: &str, spec: &StageSpec) -> Result<LeafSphere> {
        LeafSphere::parse(spec.str("leaf_sphere")?).ok_or_else(|| CoreError::InvalidParam {
            key: format!("{variant}.leaf_sphere"),
            reason: format!("not one of {}", LeafSphere::NAMES.join(", ")),
        })
    }
}

/// How a lowest node's cone axis is found (parameter `leaf_cone`, see the module doc).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LeafCone {
    /// Eq. 3.8-3.11, one ray at a time (the thesis).
    #[default]
    Incremental,
    /// The better of the mean direction and the bisector of two extreme rays.
    Extremes,
}

impl LeafCone {
    /// Parses the parameter value (`incremental`, `extremes`).
    pub fn parse(s: &str) -> Option<LeafCone> {
        match s {
            "incremental" => Some(LeafCone::Incremental),
            "extremes" => Some(LeafCone::Extremes),
            _ => None,
        }
    }
}

/// Registers `sphere_cone` ([`info`], [`SphereConeBuilder::new`]).
pub fn register(registry: &mut Registry<Cpu>) -> Result<()> {
    registry.add_hierarchy(info(), |ctx, spec| {
        Ok(Box::new(SphereConeBuilder::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

/// The sphere-cone hierarchy builder (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SphereConeBuilder {
    subdivision: u32,
    depth: u32,
    starts: bool,
    leaf_cone: LeafCone,
    leaf_sphere: LeafSphere,
}

impl SphereConeBuilder {
    /// The builder configured by a resolved `spec` (`subdivision`, `depth`).
    pub fn new(scene: &Arc<Scene>, spec: &StageSpec) -> Result<SphereConeBuilder> {
        let _ = scene;
        let starts = match spec.str("origins")? {
            "ray" => false,
            "start" => true,
            other => {
                return Err(CoreError::InvalidParam {
                    key: "sphere_cone.origins".into(),
                    reason: format!("`{other}` is not one of ray, start"),
                })
            }
        };
        let leaf_cone =
            LeafCone::parse(spec.str("leaf_cone")?).ok_or_else(|| CoreError::InvalidParam {
                key: "sphere_cone.leaf_cone".into(),
                reason: "not one of incremental, extremes".into(),
            })?;
        Ok(SphereConeBuilder::with_params(
            spec.u32_in("subdivision", SUBDIVISION_RANGE)?,
            spec.u32_in("depth", DEPTH_RANGE)?,
        )?
        .bounding_starts(starts)
        .with_leaf_cone(leaf_cone)
        .with_leaf_sphere(LeafSphere::of("sphere_cone", spec)?))
    }

    /// The same builder finding lowest nodes' sphere centres by `leaf_sphere` (parameter
    /// `leaf_sphere`; [`SphereConeBuilder::with_params`] starts with Welzl's minimal sphere).
    pub fn with_leaf_sphere(mut self, leaf_sphere: LeafSphere) -> SphereConeBuilder {
        self.leaf_sphere = leaf_sphere;
        self
    }

    /// How lowest nodes' sphere centres are found.
    pub fn leaf_sphere(&self) -> LeafSphere {
        self.leaf_sphere
    }

    /// The same builder finding lowest nodes' cone axes by `leaf_cone` (parameter
    /// `leaf_cone`; [`SphereConeBuilder::with_params`] starts with eq. 3.8-3.11).
    pub fn with_leaf_cone(mut self, leaf_cone: LeafCone) -> SphereConeBuilder {
        self.leaf_cone = leaf_cone;
        self
    }

    /// How lowest nodes' cone axes are found.
    pub fn leaf_cone(&self) -> LeafCone {
        self.leaf_cone
    }

    /// The same builder bounding the rays' segment starts `o + t_min·d` instead of their
    /// origins (`origins = start`, see [`segment_starts`]).
    pub fn bounding_starts(mut self, starts: bool) -> SphereConeBuilder {
        self.starts = starts;
        self
    }

    /// Whether the spheres bound segment starts (`origins = start`).
    pub fn bounds_starts(&self) -> bool {
        self.starts
    }

    /// The builder with `subdivision` children per node and at most `depth` node levels.
    pub fn with_params(subdivision: u32, depth: u32) -> Result<SphereConeBuilder> {
        let check = |key: &str, v: u32, range: &std::ops::RangeInclusive<u32>| {
            if range.contains(&v) {
                Ok(())
            } else {
                Err(CoreError::InvalidParam {
                    key: format!("sphere_cone.{key}"),
                    reason: format!("{v} is outside {}..={}", range.start(), range.end()),
                })
            }
        };
        check("subdivision", subdivision, &SUBDIVISION_RANGE)?;
        check("depth", depth, &DEPTH_RANGE)?;
        Ok(SphereConeBuilder {
            subdivision,
            depth,
            starts: false,
            leaf_cone: LeafCone::Incremental,
            leaf_sphere: LeafSphere::Welzl,
        })
    }

    /// Children per node.
    pub fn subdivision(&self) -> u32 {
        self.subdivision
    }

    /// The most node levels built.
    pub fn depth(&self) -> u32 {
        self.depth
    }

    /// The node levels over `rays` taken in `order`, lowest first (what
    /// [`HierarchyBuilder::build`] stores in [`RayHierarchy::levels`]).
    pub fn build_levels(&self, rays: &[Ray], order: &[u32]) -> Result<Vec<Vec<SphereCone>>> {
        Ok(self.build_levels_and_reach(rays, order)?.0)
    }

    /// [`Self::build_levels`] and the levels' [`reach_levels`], the lowest level's reach
    /// computed from the rays gathered for its nodes (one pass over the sorted rays).
    #[allow(clippy::type_complexity)]
    pub fn build_levels_and_reach(
        &self,
        rays: &[Ray],
        order: &[u32],
    ) -> Result<(Vec<Vec<SphereCone>>, Vec<Vec<f32>>)> {
        // The order is checked here; the rays themselves where the lowest level reads them
        // (a separate pass over every ray read the whole batch once more).
        validate_order("sphere_cone", rays, order)?;
        let s = self.subdivision as usize;
        let mut levels: Vec<Vec<SphereCone>> = Vec::new();
        if order.is_empty() {
            return Ok((levels, Vec::new()));
        }
        let unusable = AtomicBool::new(false);
        let (lowest, lowest_reach): (Vec<SphereCone>, Vec<f32>) = order
            .par_chunks(s)
            .enumerate()
            .map_init(LeafScratch::default, |scratch, (n, leaves)| {
                // The next node's rays start loading while this one is built: the gather
                // through the sorted order would otherwise wait for memory at every ray.
                let next = order.get((n + 1) * s..).unwrap_or(&[]);
                for &i in &next[..s.min(next.len())] {
                    crate::prefetch(rays.get(i as usize));
                }
                leaf_node(rays, leaves, self.leaf_cone, self.leaf_sphere, scratch).unwrap_or_else(
                    || {
                        unusable.store(true, Ordering::Relaxed);
                        (bytemuck::Zeroable::zeroed(), 0.0)
                    },
                )
            })
            .unzip();
        if unusable.into_inner() {
            // Names the first unusable leaf in `order`, whichever thread met one.
            validate_rays("sphere_cone", rays, order)?;
        }
        levels.push(lowest);
        while levels.len() < self.depth as usize {
            let below = &levels[levels.len() - 1];
            if below.len() <= 1 {
                break;
            }
            let next: Vec<SphereCone> = below.par_chunks(s).map(inner_node).collect();
            levels.push(next);
        }
        let mut reach = vec![lowest_reach];
        for l in 1..levels.len() {
            let next = upper_reach(&levels[l], &levels[l - 1], &reach[l - 1], s);
            reach.push(next);
        }
        Ok((levels, reach))
    }
}

impl HierarchyBuilder<Cpu> for SphereConeBuilder {
    fn name(&self) -> &str {
        "sphere_cone"
    }

    fn build(
        &self,
        _backend: &Cpu,
        rays: &Vec<Ray>,
        order: Vec<u32>,
        _stats: &mut Stats,
    ) -> Result<RayHierarchy<Cpu>> {
        let starts;
        let rays = if self.starts {
            starts = segment_starts(rays);
            &starts
        } else {
            rays
        };
        let (levels, reach) = self.build_levels_and_reach(rays, &order)?;
        Ok(RayHierarchy {
            leaf_offsets: None,
            order,
            levels,
            subdivision: self.subdivision,
            reach,
        })
    }
}

/// The rays as segments from their starts (`origins = start`): origin `o + t·d` with
/// `t = clamp(t_min, 0, t_max)` (0 when `t_min` is not finite), interval `(0, t_max − t)`.
/// Every point a ray reaches in `(t_min, t_max)` is a point of its moved version, so a
/// hierarchy over the moved rays bounds the same hits; with seed 001's origin offsets (a
/// raised `t_min`) its spheres and reaches are narrower. The traverser reads only the
/// hierarchy, and the final tests run on the original rays.
pub fn segment_starts(rays: &[Ray]) -> Vec<Ray> {
    rays.par_iter()
        .map(|r| {
            let t = if r.t_min.is_finite() {
                r.t_min.clamp(0.0, r.t_max.max(0.0))
            } else {
                0.0
            };
            Ray {
                origin: r.origin + r.dir * t,
                t_min: 0.0,
                t_max: r.t_max - t,
                ..*r
            }
        })
        .collect()
}

/// [`RayHierarchy::reach`] for `levels` built over `rays` in `order`: for a lowest-level node,
/// the largest `|origin − centre| + t_max·|dir|` over its rays; for an upper node, the largest
/// `|child centre − centre| + child reach`. Computed in `f64` and rounded up to `f32`, so that
/// every point a ray reaches lies within the bound; `f32::INFINITY` where a ray is unbounded.
pub fn reach_levels(
    rays: &[Ray],
    order: &[u32],
    levels: &[Vec<SphereCone>],
    subdivision: u32,
) -> Vec<Vec<f32>> {
    let s = subdivision as usize;
    let mut out: Vec<Vec<f32>> = Vec::with_capacity(levels.len());
    for (l, level) in levels.iter().enumerate() {
        let reach: Vec<f32> = if l == 0 {
            level
                .par_iter()
                .zip(order.par_chunks(s))
                .map(|(node, leaves)| {
                    let c = node.sphere.center.as_dvec3();
                    let far = leaves.iter().fold(0.0f64, |m, &i| {
                        let r = &rays[i as usize];
                        let len = r.t_max as f64 * r.dir.as_dvec3().length();
                        m.max((r.origin.as_dvec3() - c).length() + len)
                    });
                    round_up_reach(far)
                })
                .collect()
        } else {
            upper_reach(level, &levels[l - 1], &out[l - 1], s)
        };
        out.push(reach);
    }
    out
}

/// The reach of the upper-level nodes `level` over the nodes `below` and their reaches:
/// the largest `|child centre − centre| + child reach`, rounded up.
fn upper_reach(
    level: &[SphereCone],
    below: &[SphereCone],
    below_reach: &[f32],
    s: usize,
) -> Vec<f32> {
    level
        .par_iter()
        .zip(below.par_chunks(s).zip(below_reach.par_chunks(s)))
        .map(|(node, (children, reaches))| {
            let c = node.sphere.center.as_dvec3();
            let far = children.iter().zip(reaches).fold(0.0f64, |m, (k, &r)| {
                m.max((k.sphere.center.as_dvec3() - c).length() + r as f64)
            });
            round_up_reach(far)
        })
        .collect()
}

/// A reach bound computed in `f64` as an `f32` that is not below it, with room to spare:
/// `x·(1 + 10⁻⁶) + 10⁻⁶·max(|x|, 1)·ε_f32`, rounded to `f32` and then up by one ulp;
/// `f32::INFINITY` for a non-finite `x`. The guard of [`reach_levels`] and of the tile cones'
/// reach ([`crate::hierarchy::tile_cone`]).
pub fn round_up_reach(x: f64) -> f32 {
    if !x.is_finite() {
        return f32::INFINITY;
    }
    let up = x * (1.0 + 1e-6) + 1e-6 * x.abs().max(1.0) * f32::EPSILON as f64;
    (up as f32).next_up()
}

/// Node counts per level for `n` leaves: level `l` (0-based) has `ceil(n / subdivision^(l+1))`
/// nodes; at most `depth` levels, stopping after the first level with a single node; empty for
/// `n = 0`. `subdivision` must be at least 2.
pub fn level_sizes(n: usize, subdivision: u32, depth: u32) -> Vec<usize> {
    let s = subdivision.max(2) as usize;
    let mut sizes = Vec::new();
    let mut count = n;
    while count > 1 || (count == 1 && sizes.is_empty()) {
        if sizes.len() >= depth as usize {
            break;
        }
        count = count.div_ceil(s);
        sizes.push(count);
    }
    sizes
}

/// The leaves (positions in [`RayHierarchy::order`]) under node `node` of level `level`
/// (0-based, lowest first) of a hierarchy over `leaves` rays with `subdivision` children per
/// node: `node·s^(level+1) .. (node+1)·s^(level+1)`, clipped to `leaves` (empty past the end).
pub fn leaf_range(
    level: usize,
    node: usize,
    subdivision: u32,
    leaves: usize,
) -> std::ops::Range<usize> {
    let span = (subdivision as usize)
        .checked_pow(level as u32 + 1)
        .unwrap_or(usize::MAX);
    let start = node.saturating_mul(span).min(leaves);
    let end = node.saturating_add(1).saturating_mul(span).min(leaves);
    start..end
}

/// The first leaf whose index is out of range or whose ray is unusable, as an error of
/// `variant` (`order` must be a permutation of the batch; every ray needs a finite origin and
/// a finite non-zero direction, [`usable`]). Shared by the hierarchy builders.
pub(crate) fn validate_leaves(variant: &str, rays: &[Ray], order: &[u32]) -> Result<()> {
    validate_order(variant, rays, order)?;
    // The rays in memory order first (a permutation holds every ray once); the first bad
    // leaf in `order` is looked for only when some ray is bad.
    if crate::position_first(rays, |r| !usable(r)).is_none() {
        return Ok(());
    }
    validate_rays(variant, rays, order)
}

/// Whether a ray can be a leaf: a finite origin and a finite non-zero direction.
#[inline]
fn usable(r: &Ray) -> bool {
    let d = r.dir.as_dvec3();
    r.origin.is_finite() && d.is_finite() && d.length_squared() != 0.0
}

/// The first leaf of `order` (in range) whose ray is not [`usable`], as an error of `variant`.
fn validate_rays(variant: &str, rays: &[Ray], order: &[u32]) -> Result<()> {
    if let Some(leaf) = crate::position_first(order, |&i| !usable(&rays[i as usize])) {
        let r = &rays[order[leaf] as usize];
        return Err(CoreError::InvalidInput(format!(
            "{variant}: ray {} (leaf {leaf}) has origin {} and direction {}: needs a finite \
             origin and a finite non-zero direction",
            order[leaf], r.origin, r.dir
        )));
    }
    Ok(())
}

/// The first leaf whose index is out of range or repeats an earlier one, or a length that is
/// not the batch's, as an error of `variant` (`order` must be a permutation of the batch).
fn validate_order(variant: &str, rays: &[Ray], order: &[u32]) -> Result<()> {
    if let Some(leaf) = crate::position_first(order, |&i| i as usize >= rays.len()) {
        return Err(CoreError::InvalidInput(format!(
            "{variant}: leaf {leaf} refers to ray {} of a batch of {} rays",
            order[leaf],
            rays.len()
        )));
    }
    if order.len() != rays.len() {
        return Err(CoreError::InvalidInput(format!(
            "{variant}: {} leaves for a batch of {} rays (the order must be a permutation)",
            order.len(),
            rays.len()
        )));
    }
    // Every entry is in range: the first one `first_repeat` names is a repeat.
    if let Some(leaf) = crate::first_repeat(order, rays.len()) {
        return Err(CoreError::InvalidInput(format!(
            "{variant}: ray {} appears twice in the order (again at leaf {leaf})",
            order[leaf]
        )));
    }
    Ok(())
}

/// A cone in `f64` during construction: unit axis, half-angle in `[0, π]`.
#[derive(Clone, Copy, Debug)]
struct DCone {
    axis: DVec3,
    angle: f64,
}

impl DCone {
    fn of(c: &Cone) -> DCone {
        DCone {
            axis: unit(c.axis.as_dvec3()),
            angle: (c.half_angle as f64).clamp(0.0, PI),
        }
    }

    fn to_cone(self) -> Cone {
        Cone {
            axis: self.axis.as_vec3(),
            half_angle: self.angle as f32,
        }
    }
}

/// `v` normalized; a zero or non-finite `v` gives `+z` (never reached with validated input).
fn unit(v: DVec3) -> DVec3 {
    let n = v.normalize_or_zero();
    if n == DVec3::ZERO {
        DVec3::Z
    } else {
        n
    }
}

/// The angle between two non-zero vectors, accurate for small and large angles.
fn angle(a: DVec3, b: DVec3) -> f64 {
    a.cross(b).length().atan2(a.dot(b))
}

/// The tight union of two cones (the smallest cone containing both), in `f64`.
fn union_d(a: DCone, b: DCone) -> DCone {
    if a.angle >= PI || b.angle >= PI {
        return DCone {
            axis: a.axis,
            angle: PI,
        };
    }
    let theta = angle(a.axis, b.axis);
    if theta + b.angle <= a.angle {
        return a;
    }
    if theta + a.angle <= b.angle {
        return b;
    }
    let phi = 0.5 * (a.angle + theta + b.angle);
    if phi >= PI {
        return DCone {
            axis: a.axis,
            angle: PI,
        };
    }
    // Rotate a's axis towards b's by the amount that puts a's far generator on the new
    // boundary: alpha = phi - a.angle, strictly between 0 and theta here.
    let alpha = phi - a.angle;
    let ortho = b.axis - a.axis * a.axis.dot(b.axis);
    let u = if ortho.length() > PERP_EPS {
        ortho.normalize()
    } else {
        a.axis.any_orthonormal_vector()
    };
    DCone {
        axis: unit(a.axis * alpha.cos() + u * alpha.sin()),
        angle: phi,
    }
}

/// The cone `cone` extended to contain the direction `dir` (seed 000 eq. 3.8-3.11, seed 004
/// §4), exact (no margin), computed in `f64`.
///
/// If `dir` lies outside, the new cone is the narrowest one containing the old cone and `dir`:
/// its boundary passes through `dir` and through the old cone's generator `e` farthest from
/// `dir` (eq. 3.8-3.9), so its half-angle is `(φ + θ) / 2` with `θ` the angle from the axis to
/// `dir`, and the axis turns from `x` towards `dir` by `(θ - φ) / 2`. Below a hemisphere this
/// is exactly eq. 3.10-3.11 (`normalize(e + r)`, `acos(x_new·r)`); in angle form it also holds
/// when `φ + θ ≥ π` (where `e + r` flips or vanishes), up to the full sphere (half-angle π).
/// A direction opposite to the axis turns it about a fixed perpendicular
/// ([`glam::DVec3::any_orthonormal_vector`]). `dir` need not be unit length.
pub fn extend_cone(cone: &Cone, dir: Vec3) -> Cone {
    let ray = DCone {
        axis: unit(dir.as_dvec3()),
        angle: 0.0,
    };
    union_d(DCone::of(cone), ray).to_cone()
}

/// The smallest cone containing cones `a` and `b` (exact, no margin, computed in `f64`).
///
/// With `θ` the angle between the axes: if one cone contains the other (`θ + φb ≤ φa` or the
/// reverse), that cone; otherwise half-angle `(φa + θ + φb) / 2` (clamped to π) and the axis
/// turned from `a`'s towards `b`'s by `(θ + φb − φa) / 2`, in the plane of both axes (any
/// plane through `a`'s axis when the axes are opposite). This is never wider than the erratum
/// form of seed 000 eq. 3.12-3.13 (`θ/2 + max(φa, φb)`) and equals it when `φa = φb`.
pub fn cone_union(a: &Cone, b: &Cone) -> Cone {
    union_d(DCone::of(a), DCone::of(b)).to_cone()
}

/// The smallest sphere containing spheres `a` and `b` (exact, no margin, computed in `f64`):
/// the larger if it contains the other, else the sphere through the two far points on the line
/// of centres, radius `(|c2 − c1| + r1 + r2) / 2`. Seed 000 eq. 3.14-3.15 give a sphere that
/// contains this one.
pub fn sphere_union(a: &Sphere, b: &Sphere) -> Sphere {
    let (c, r) = sphere_union_d(
        (a.center.as_dvec3(), a.radius as f64),
        (b.center.as_dvec3(), b.radius as f64),
    );
    Sphere::new(c.as_vec3(), r as f32)
}

fn sphere_union_d(a: (DVec3, f64), b: (DVec3, f64)) -> (DVec3, f64) {
    let d = a.0.distance(b.0);
    if d + b.1 <= a.1 {
        return a;
    }
    if d + a.1 <= b.1 {
        return b;
    }
    let r = 0.5 * (d + a.1 + b.1);
    // d > 0 here: with d = 0 one sphere contains the other.
    let c = a.0 + (b.0 - a.0) * ((r - a.1) / d);
    (c, r)
}

/// The stored cone: `axis` rounded to `f32`, half-angle re-measured as the largest of
/// `angle(stored axis, child axis) + child angle`, enlarged by the margins, clamped to π.
///
/// Only the children that can give that largest value are measured with `atan2`: an
/// estimate within [`ANGLE_ESTIMATE_ERROR`] of every angle ([`angle_estimate`]) rules out a
/// child whose estimate plus twice the error stays below the best estimate. The result is the
/// same maximum, bit for bit, as measuring every child (tested); an upper node of 16 children
/// measured all 16 (`atan2` was most of the upper levels' build).
fn store_cone(axis: DVec3, full: bool, children: impl Iterator<Item = (DVec3, f64)>) -> Cone {
    let stored = axis.as_vec3().normalize();
    let a = stored.as_dvec3();
    let measured = if full { PI } else { widest_child(a, children) };
    margined_cone(stored, measured)
}

/// The cone stored around `stored` for a measured half-angle `measured`: enlarged by the
/// margins, clamped to π and rounded up to `f32`.
fn margined_cone(stored: Vec3, measured: f64) -> Cone {
    let widened = measured * (1.0 + CONE_REL_MARGIN) + CONE_ABS_MARGIN;
    Cone {
        axis: stored,
        half_angle: f32_up(widened.min(PI)),
    }
}

/// The largest `angle(a, x) + φ` over the children `(x, φ)` (0 for none), with `atan2` only
/// where an [`angle_estimate`] does not rule the child out (see [`store_cone`]).
fn widest_child(a: DVec3, children: impl Iterator<Item = (DVec3, f64)>) -> f64 {
    // At most `SUBDIVISION_RANGE.end()` children: no allocation.
    const MAX: usize = *SUBDIVISION_RANGE.end() as usize;
    let mut estimates = [(0.0f64, DVec3::ZERO, 0.0f64); MAX];
    let mut n = 0;
    let mut best = f64::NEG_INFINITY;
    for (x, p) in children {
        let e = angle_estimate(a, x) + p;
        best = best.max(e);
        if n < MAX {
            estimates[n] = (e, x, p);
            n += 1;
        } else {
            // Never reached through the builder (it checks the subdivision): measure all.
            return estimates[..n]
                .iter()
                .map(|&(_, x, p)| (x, p))
                .chain(std::iter::once((x, p)))
                .fold(0.0f64, |m, (x, p)| m.max(angle(a, x) + p));
        }
    }
    let cut = best - 2.0 * ANGLE_ESTIMATE_ERROR;
    estimates[..n]
        .iter()
        .filter(|(e, _, _)| *e >= cut)
        .fold(0.0f64, |m, &(_, x, p)| m.max(angle(a, x) + p))
}

/// A bound on `|angle_estimate(a, b) − angle(a, b)|` in radians: the estimate's polynomial
/// is within 0.0015 rad of `atan` on `[0, 1]` (Rajan, Wang, Inkol and Joyal 2006),
/// and the rest is `f64` rounding, far below the room left here.
pub const ANGLE_ESTIMATE_ERROR: f64 = 0.004;

/// The angle between two non-zero vectors within [`ANGLE_ESTIMATE_ERROR`], without
/// trigonometry: `atan2(|a × b|, a · b)` with `atan t ≈ π/4·t + t·(1 − t)·(0.2447 + 0.0663·t)`
/// on the octant where `t ≤ 1`.
fn angle_estimate(a: DVec3, b: DVec3) -> f64 {
    let (s, c) = (a.cross(b).length(), a.dot(b));
    let ac = c.abs();
    let (lo, hi) = if s <= ac { (s, ac) } else { (ac, s) };
    if hi == 0.0 {
        return 0.0;
    }
    let t = lo / hi;
    let at = std::f64::consts::FRAC_PI_4 * t + t * (1.0 - t) * (0.2447 + 0.0663 * t);
    // atan2(s, c) from atan(t) by the octant (s ≥ 0).
    match (s <= ac, c >= 0.0) {
        (true, true) => at,
        (true, false) => PI - at,
        (false, true) => std::f64::consts::FRAC_PI_2 - at,
        (false, false) => std::f64::consts::FRAC_PI_2 + at,
    }
}

/// [`store_cone`] for a lowest node, whose children are directions (angle 0): the widest
/// direction is the one of smallest cosine with the stored axis, so only its angle is measured
/// (with `atan2`), not every ray's. Near ±1 two cosines, each off by up to three roundings of
/// the dot product, tell angles apart only to about 4e-8 rad (`√(2·6·2⁻⁵³)`), so a near tie
/// that rounding decides the wrong way loses at most that, far below the [`CONE_ABS_MARGIN`]
/// (1e-6) the stored angle is enlarged by.
fn store_leaf_cone(axis: DVec3, full: bool, dirs: impl Iterator<Item = DVec3>) -> Cone {
    let stored = axis.as_vec3().normalize();
    let a = stored.as_dvec3();
    let measured = if full {
        PI
    } else {
        let widest = dirs.fold(None, |best: Option<(f64, DVec3)>, x| {
            let c = a.dot(x);
            match best {
                Some((bc, _)) if c >= bc => best,
                _ => Some((c, x)),
            }
        });
        widest.map_or(0.0, |(_, x)| angle(a, x))
    };
    margined_cone(stored, measured)
}

/// The stored sphere: centre rounded to `f32`, radius re-measured as the largest of
/// `|stored centre − child centre| + child radius`, enlarged by the margin.
fn store_sphere(center: DVec3, children: impl Iterator<Item = (DVec3, f64)>) -> Sphere {
    let stored = center.as_vec3();
    let c = stored.as_dvec3();
    let measured = children.fold(0.0f64, |m, (p, r)| m.max(c.distance(p) + r));
    margined_sphere(stored, measured)
}

/// The sphere stored around `stored` for a measured radius `measured`: enlarged by the margin
/// and rounded up to `f32`.
fn margined_sphere(stored: Vec3, measured: f64) -> Sphere {
    Sphere::new(stored, f32_up(measured * (1.0 + SPHERE_REL_MARGIN)))
}

/// The cone of eq. 3.8-3.11 while a lowest node is built: its axis and the cosine and sine of
/// its half-angle `φ ∈ [0, π]`, so that adding a ray costs square roots, not trigonometry.
#[derive(Clone, Copy, Debug)]
struct GrowingCone {
    axis: DVec3,
    cos: f64,
    sin: f64,
}

/// `(cos(x/2), sin(x/2))` for `x ∈ [0, 2π]` from `(cos x, sin x)`: the normalized
/// `(1 + cos x, sin x)` while `sin x ≥ 0` (no cancellation for small `x`), else the normalized
/// `(sin x, 1 − cos x)` (both are `2·cos(x/2)` resp. `2·sin(x/2)` times a non-negative factor).
fn half_angle(cos: f64, sin: f64) -> (f64, f64) {
    let (c, s) = if sin >= 0.0 {
        (1.0 + cos, sin)
    } else {
        (sin, 1.0 - cos)
    };
    let n = (c * c + s * s).sqrt();
    if n > 0.0 {
        (c / n, s / n)
    } else {
        // x = π exactly: half of it is π/2.
        (0.0, 1.0)
    }
}

impl GrowingCone {
    /// The cone extended to contain the unit direction `d` (a no-op when it does): the same
    /// cone as [`union_d`] with a zero-angle cone (eq. 3.8-3.11 in angle form, see
    /// [`extend_cone`]), with the half-angle sums and halvings done on `(cos, sin)` pairs:
    /// new half-angle `(φ + θ)/2`, axis turned towards `d` by `(θ − φ)/2`.
    #[inline]
    fn extend(&mut self, d: DVec3) {
        let c = self.axis.dot(d);
        if c >= self.cos {
            return;
        }
        // θ = angle(axis, d) ∈ (φ, π].
        let ortho = d - self.axis * c;
        let s = ortho.length();
        // (φ + θ) and (θ − φ) as (cos, sin) pairs.
        let (sum_c, sum_s) = (self.cos * c - self.sin * s, self.sin * c + self.cos * s);
        let (dif_c, dif_s) = (c * self.cos + s * self.sin, s * self.cos - c * self.sin);
        let (cos_a, sin_a) = half_angle(dif_c, dif_s.max(0.0));
        let u = if s > PERP_EPS {
            ortho / s
        } else {
            self.axis.any_orthonormal_vector()
        };
        let (cos, sin) = half_angle(sum_c, sum_s);
        *self = GrowingCone {
            axis: unit(self.axis * cos_a + u * sin_a),
            cos,
            sin,
        };
    }
}

/// The gathered rays of one lowest node, kept per worker so that a node neither allocates nor
/// clears arrays for the largest subdivision (zeroing three 64-entry arrays per node was 5 % of
/// the stage).
#[derive(Default)]
struct LeafScratch {
    origins: Vec<Vec3>,
    dirs: Vec<DVec3>,
    lengths: Vec<f64>,
    columns: narrow_leaf::Columns,
}

/// A lowest-level node over the rays `leaves` (an in-range, non-empty part of a validated
/// order), and its reach (as [`reach_levels`] computes it, from the same gathered rays);
/// `None` when one of the rays is not [`usable`]. With `leaf_cone = extremes` a narrow node
/// is built in `f32` lanes ([`narrow_leaf`]), any other by [`exact_leaf`].
fn leaf_node(
    rays: &[Ray],
    leaves: &[u32],
    how: LeafCone,
    centre: LeafSphere,
    scratch: &mut LeafScratch,
) -> Option<(SphereCone, f32)> {
    if how == LeafCone::Extremes {
        if let Some(node) = narrow_leaf::narrow_leaf(rays, leaves, centre, &mut scratch.columns) {
            return Some(node);
        }
    }
    exact_leaf(rays, leaves, how, centre, scratch)
}

/// [`leaf_node`] built one `f64` ray at a time: every node of `leaf_cone = incremental`, and
/// the nodes of `extremes` that [`narrow_leaf`] leaves to it (wide, cancelling or unusable).
fn exact_leaf(
    rays: &[Ray],
    leaves: &[u32],
    how: LeafCone,
    centre: LeafSphere,
    scratch: &mut LeafScratch,
) -> Option<(SphereCone, f32)> {
    let LeafScratch {
        origins,
        dirs,
        lengths,
        ..
    } = scratch;
    origins.clear();
    dirs.clear();
    lengths.clear();
    let n = leaves.len();
    for i in leaves {
        let ray = &rays[*i as usize];
        if !usable(ray) {
            return None;
        }
        let d = ray.dir.as_dvec3();
        origins.push(ray.origin);
        // `unit(d)` and the length from one square root (`unit` is `d · (1 / |d|)`).
        let length = d.length();
        let rcp = 1.0 / length;
        dirs.push(if rcp.is_finite() && rcp > 0.0 {
            d * rcp
        } else {
            unit(d)
        });
        lengths.push(ray.t_max as f64 * length);
    }
    let (origins, dirs) = (&origins[..], &dirs[..]);
    // Eq. 3.8-3.11 one ray at a time; a ray already inside (x·r ≥ cos φ) leaves the cone as
    // it is. Rounding in this test cannot lose a ray: the stored angle is re-measured.
    let incremental = || {
        let mut cone = GrowingCone {
            axis: dirs[0],
            cos: 1.0,
            sin: 0.0,
        };
        for &d in &dirs[1..] {
            cone.extend(d);
        }
        cone
    };
    let extremes = match how {
        LeafCone::Extremes => extremes_axis(dirs),
        LeafCone::Incremental => None,
    };
    let cone = match extremes {
        Some((axis, cos)) => {
            let heuristic = GrowingCone {
                axis,
                cos: 1.0,
                sin: 0.0,
            };
            if cos >= WIDE_LEAF_COS {
                heuristic
            } else {
                // A wide node: eq. 3.8-3.11 too, and the narrower of the two.
                let thesis = incremental();
                if thesis.cos > -1.0 && min_dot(dirs, thesis.axis) > cos {
                    thesis
                } else {
                    heuristic
                }
            }
        }
        None => incremental(),
    };
    // Rays from one point (shadow rays leaving a light) need no Welzl, and every distance
    // from the stored centre (that point, exactly) is 0: the same sphere and reach as the
    // loops below, without their square roots.
    let one_point = origins.iter().all(|o| *o == origins[0]);
    // A half-angle of π has sine 0 and cosine −1.
    let full = cone.cos <= -1.0;
    let (sphere, far) = if one_point {
        let o = origins[0].as_dvec3();
        let far = lengths[..n].iter().fold(0.0f64, |m, len| m.max(*len));
        (store_sphere(o, std::iter::once((o, 0.0))), far)
    } else {
        let c = match centre {
            LeafSphere::Welzl => min_sphere(origins).center,
            LeafSphere::BoxCentre => crsh_core::Aabb::from_points(origins.iter().copied()).center(),
        };
        // `store_sphere` over the origins (radius 0) and the reach, from one distance per
        // origin to the stored centre.
        let stored = c.as_dvec3();
        let (measured, far) =
            origins
                .iter()
                .zip(&lengths[..n])
                .fold((0.0f64, 0.0f64), |(m, f), (o, len)| {
                    let d = stored.distance(o.as_dvec3());
                    (m.max(d), f.max(d + len))
                });
        let sphere = margined_sphere(c, measured);
        (sphere, far)
    };
    let node = SphereCone {
        sphere,
        cone: store_leaf_cone(cone.axis, full, dirs.iter().copied()),
    };
    Some((node, round_up_reach(far)))
}

/// Below this cosine of its widest ray (about 14°), a node of `leaf_cone = extremes` also
/// gets eq. 3.8-3.11's axis and keeps the narrower: the heuristic axes are tight around a
/// cluster of directions but can be wider than eq. 3.8-3.11's over spread ones.
pub const WIDE_LEAF_COS: f64 = 0.97;

/// The smallest dot product of `axis` with the directions `dirs` (the cosine of the widest).
fn min_dot(dirs: &[DVec3], axis: DVec3) -> f64 {
    dirs.iter().fold(f64::INFINITY, |m, &d| m.min(axis.dot(d)))
}

/// The axis of `leaf_cone = extremes` for the unit directions `dirs` (non-empty; see the
/// module doc) and the cosine of its widest direction, `None` when they nearly cancel
/// (eq. 3.8-3.11 then).
fn extremes_axis(dirs: &[DVec3]) -> Option<(DVec3, f64)> {
    let sum = dirs.iter().fold(DVec3::ZERO, |a, &d| a + d);
    if sum.length() <= 1e-3 * dirs.len() as f64 {
        return None;
    }
    // The direction farthest from `from` (the first on a tie).
    let farthest = |from: DVec3| {
        dirs.iter()
            .fold((f64::INFINITY, from), |(m, best), &d| {
                let c = from.dot(d);
                if c < m {
                    (c, d)
                } else {
                    (m, best)
                }
            })
            .1
    };
    let mean = sum.normalize();
    let mean_cos = min_dot(dirs, mean);
    let a = farthest(dirs[0]);
    let pair = a + farthest(a);
    if pair.length() > 1e-6 {
        let pair = pair.normalize();
        let pair_cos = min_dot(dirs, pair);
        if pair_cos > mean_cos {
            return Some((pair, pair_cos));
        }
    }
    Some((mean, mean_cos))
}

/// A node over the nodes `children` of the level below (non-empty).
fn inner_node(children: &[SphereCone]) -> SphereCone {
    let cones = children.iter().map(|n| DCone::of(&n.cone));
    let cone = cones.clone().reduce(union_d).expect("non-empty chunk");
    let spheres = children
        .iter()
        .map(|n| (n.sphere.center.as_dvec3(), n.sphere.radius as f64));
    let (center, _) = spheres
        .clone()
        .reduce(sphere_union_d)
        .expect("non-empty chunk");
    SphereCone {
        sphere: store_sphere(center, spheres),
        cone: store_cone(
            cone.axis,
            cone.angle >= PI,
            cones.map(|c| (c.axis, c.angle)),
        ),
    }
}

/// Whether the ray (`origin`, `dir`) is bounded by `node`: `origin` in the sphere and `dir`
/// in the cone, tested exactly in `f64` without tolerance (the builder's margins are part of
/// the stored node). `dir` need not be unit length; a zero direction is covered only by a
/// full cone.
pub fn covers(node: &SphereCone, origin: Vec3, dir: Vec3) -> bool {
    let s = &node.sphere;
    let in_sphere = s.center.as_dvec3().distance(origin.as_dvec3()) <= s.radius as f64;
    let c = &node.cone;
    let d = dir.as_dvec3();
    let in_cone = c.half_angle as f64 >= PI
        || (d != DVec3::ZERO && angle(c.axis.as_dvec3(), d) <= c.half_angle as f64);
    in_sphere && in_cone
}

/// How far `p` lies outside the volume swept by the rays `node` bounds (negative or zero:
/// inside), computed in `f64`.
///
/// The rays' points `o + t·d` (`o` in the sphere `S(c, r)`, `d` in the cone `K` with apex at
/// the coordinate origin, `t ≥ 0`) all lie in the Minkowski sum `c + K + B(r)`, the set of
/// points within `r` of the translated cone `c + K`. So `p` is inside exactly when
/// `dist(v, K) ≤ r` with `v = p − c`. With `β` the angle between `v` and the axis and `φ` the
/// half-angle, the distance from `v` to the (solid, possibly wider than a hemisphere) cone is
/// `0` if `β ≤ φ`, `|v|·sin(β − φ)` (distance to the nearest generator line) if
/// `β − φ < π/2`, and `|v|` (the apex is nearest) otherwise. The result is `dist(v, K) − r`.
pub fn swept_excess(node: &SphereCone, p: DVec3) -> f64 {
    let v = p - node.sphere.center.as_dvec3();
    let r = node.sphere.radius as f64;
    let len = v.length();
    let phi = node.cone.half_angle as f64;
    if len == 0.0 || phi >= PI {
        return -r;
    }
    let beta = angle(node.cone.axis.as_dvec3(), v);
    let dist = if beta <= phi {
        0.0
    } else if beta - phi < 0.5 * PI {
        len * (beta - phi).sin()
    } else {
        len
    };
    dist - r
}

#[cfg(test)]
mod tests {
    use super::*;
    use crsh_core::ParamValue;
    use crsh_core::{Hit, RayKind};

    /// SplitMix64 for reproducible test data.
    struct Rng(u64);

    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        }
        fn unit(&mut self) -> f32 {
            (self.next() >> 40) as f32 / (1u64 << 24) as f32
        }
        fn range(&mut self, lo: f32, hi: f32) -> f32 {
            lo + (hi - lo) * self.unit()
        }
        fn dir(&mut self) -> Vec3 {
            loop {
                let v = Vec3::new(
                    self.range(-1.0, 1.0),
                    self.range(-1.0, 1.0),
                    self.range(-1.0, 1.0),
                );
                let l = v.length();
                if l > 0.1 && l <= 1.0 {
                    return v / l;
                }
            }
        }
        fn point(&mut self, extent: f32) -> Vec3 {
            Vec3::new(
                self.range(-extent, extent),
                self.range(-extent, extent),
                self.range(-extent, extent),
            )
        }
    }

    fn ray(origin: Vec3, dir: Vec3) -> Ray {
        Ray::new(RayKind::Reflection, origin, dir, 0.0, f32::INFINITY)
    }

    /// Coherent bundles: groups of 16 rays around a random direction (spread ≤ ~0.05 rad) from
    /// nearby origins.
    fn coherent(rng: &mut Rng, n: usize) -> Vec<Ray> {
        let mut rays = Vec::with_capacity(n);
        let mut base = (Vec3::ZERO, Vec3::Z);
        for i in 0..n {
            if i % 16 == 0 {
                base = (rng.point(50.0), rng.dir());
            }
            let d = (base.1 + rng.dir() * 0.05).normalize();
            rays.push(ray(base.0 + rng.point(0.5), d));
        }
        rays
    }

    fn random(rng: &mut Rng, n: usize) -> Vec<Ray> {
        (0..n).map(|_| ray(rng.point(50.0), rng.dir())).collect()
    }

    /// Pairs of opposite directions side by side, so that every node holds opposite rays.
    fn opposite(rng: &mut Rng, n: usize) -> Vec<Ray> {
        (0..n)
            .map(|i| {
                let d = if i % 2 == 0 { Vec3::X } else { -Vec3::X };
                let d = if i % 6 < 2 {
                    d
                } else {
                    rng.dir() * (i % 2) as f32 + d
                };
                ray(rng.point(3.0), d.normalize_or(Vec3::Y))
            })
            .collect()
    }

    /// Rays from one point (a light), random directions over a hemisphere-ish fan.
    fn one_point(rng: &mut Rng, n: usize) -> Vec<Ray> {
        let light = Vec3::new(1.5, 7.25, -3.0);
        (0..n)
            .map(|_| {
                let d = rng.dir();
                ray(light, Vec3::new(d.x, -d.y.abs() - 0.2, d.z))
            })
            .collect()
    }

    fn identity(n: usize) -> Vec<u32> {
        (0..n as u32).collect()
    }

    fn shuffled(rng: &mut Rng, n: usize) -> Vec<u32> {
        let mut o = identity(n);
        for i in (1..n).rev() {
            o.swap(i, (rng.next() % (i as u64 + 1)) as usize);
        }
        o
    }

    /// Every node at every level covers every ray below it (origin and direction), every node
    /// contains its children's spheres and cones, and sampled ray points lie in the swept volume.
    fn check_containment(rays: &[Ray], order: &[u32], s: u32, depth: u32) -> Vec<usize> {
        check_containment_with(
            rays,
            order,
            SphereConeBuilder::with_params(s, depth).unwrap(),
        )
        .0
    }

    /// [`check_containment`] with the builder `b` (its shape, lowest cones and spheres); also
    /// returns the levels.
    fn check_containment_with(
        rays: &[Ray],
        order: &[u32],
        b: SphereConeBuilder,
    ) -> (Vec<usize>, Vec<Vec<SphereCone>>) {
        let (s, depth) = (b.subdivision(), b.depth());
        let levels = b.build_levels(rays, order).unwrap();
        let sizes: Vec<usize> = levels.iter().map(Vec::len).collect();
        assert_eq!(sizes, level_sizes(order.len(), s, depth));
        for (l, level) in levels.iter().enumerate() {
            for (k, node) in level.iter().enumerate() {
                assert!(node.cone.half_angle >= 0.0 && node.cone.half_angle <= PI as f32);
                assert!((node.cone.axis.length() - 1.0).abs() < 1e-6);
                for leaf in leaf_range(l, k, s, order.len()) {
                    let r = &rays[order[leaf] as usize];
                    assert!(
                        covers(node, r.origin, r.dir),
                        "level {l} node {k} misses leaf {leaf}: {node:?} {r:?}"
                    );
                    for j in 0..=10 {
                        let t = j as f64 * 10.0;
                        let p = r.origin.as_dvec3() + r.dir.as_dvec3().normalize() * t;
                        let excess = swept_excess(node, p);
                        assert!(
                            excess <= 1e-9 * (1.0 + p.length()),
                            "level {l} node {k}, leaf {leaf}, t {t}: {excess}"
                        );
                    }
                }
                if l > 0 {
                    let s = s as usize;
                    for child in &levels[l - 1][k * s..((k + 1) * s).min(levels[l - 1].len())] {
                        let gap = node
                            .sphere
                            .center
                            .as_dvec3()
                            .distance(child.sphere.center.as_dvec3())
                            + child.sphere.radius as f64;
                        assert!(gap <= node.sphere.radius as f64);
                        let spread = angle(node.cone.axis.as_dvec3(), child.cone.axis.as_dvec3())
                            + child.cone.half_angle as f64;
                        assert!(spread.min(PI) <= node.cone.half_angle as f64);
                    }
                }
            }
        }
        (sizes, levels)
    }

    /// Every point a finite ray reaches lies within its nodes' reach, at every level; an
    /// unbounded ray makes its nodes' reach infinite.
    #[test]
    fn reach_bounds_every_point_of_finite_rays() {
        let mut rng = Rng(77);
        for (s, depth) in [(2u32, 4u32), (8, 3), (16, 2)] {
            let mut rays = one_point(&mut rng, 300);
            rays.extend(coherent(&mut rng, 300));
            for (i, r) in rays.iter_mut().enumerate() {
                r.t_max = rng.range(0.01, 40.0);
                r.dir *= 1.0 + (i % 3) as f32; // non-unit directions scale the reach too
            }
            let order = identity(rays.len());
            let b = SphereConeBuilder::with_params(s, depth).unwrap();
            let levels = b.build_levels(&rays, &order).unwrap();
            let reach = reach_levels(&rays, &order, &levels, s);
            assert_eq!(reach.len(), levels.len());
            for (l, level) in levels.iter().enumerate() {
                assert_eq!(reach[l].len(), level.len());
                for (n, node) in level.iter().enumerate() {
                    for leaf in leaf_range(l, n, s, rays.len()) {
                        let r = &rays[order[leaf] as usize];
                        for k in 0..=8 {
                            let p = r.at(r.t_max * k as f32 / 8.0);
                            let d = p.as_dvec3().distance(node.sphere.center.as_dvec3());
                            assert!(
                                d <= reach[l][n] as f64,
                                "level {l} node {n}: point at distance {d} beyond reach {}",
                                reach[l][n]
                            );
                        }
                    }
                }
            }
            // Shadow-like segments from one light reach about as far as the longest segment.
            let top = reach.last().unwrap();
            assert!(top.iter().all(|r| r.is_finite()));
        }
        let mut rays = random(&mut rng, 40);
        rays[5].t_max = 3.0;
        let order = identity(rays.len());
        let levels = SphereConeBuilder::with_params(4, 2)
            .unwrap()
            .build_levels(&rays, &order)
            .unwrap();
        let reach = reach_levels(&rays, &order, &levels, 4);
        assert!(reach[0][0].is_infinite() && reach[1][0].is_infinite());
    }

    /// The reach the builder computes while gathering a lowest node's rays is the one
    /// [`reach_levels`] defines, on every level, bounded and unbounded rays alike.
    #[test]
    fn fused_reach_is_reach_levels() {
        let mut rng = Rng(78);
        let mut rays = one_point(&mut rng, 200);
        rays.extend(coherent(&mut rng, 300));
        rays.extend(random(&mut rng, 100));
        for (i, r) in rays.iter_mut().enumerate() {
            if i % 7 != 0 {
                r.t_max = rng.range(0.01, 40.0);
            }
            r.dir *= 1.0 + (i % 3) as f32;
        }
        let mut order = identity(rays.len());
        order.reverse();
        for (s, depth) in [(2u32, 5u32), (8, 3), (64, 2)] {
            let b = SphereConeBuilder::with_params(s, depth).unwrap();
            let (levels, reach) = b.build_levels_and_reach(&rays, &order).unwrap();
            assert_eq!(levels, b.build_levels(&rays, &order).unwrap());
            assert_eq!(reach, reach_levels(&rays, &order, &levels, s));
        }
    }

    /// Extending a lowest node's cone on `(cos, sin)` pairs gives the cone of the angle-form
    /// union (eq. 3.8-3.11, [`union_d`]): the same axis and half-angle up to rounding, from
    /// narrow coherent bundles to cones wider than a hemisphere and opposite directions.
    #[test]
    fn leaf_cone_extension_is_the_angle_form_union() {
        let mut rng = Rng(79);
        for spread in [1e-6f32, 1e-3, 0.1, 1.0, 3.0, 10.0] {
            for _ in 0..200 {
                let base = rng.dir();
                let mut fast = GrowingCone {
                    axis: unit(base.as_dvec3()),
                    cos: 1.0,
                    sin: 0.0,
                };
                let mut exact = DCone {
                    axis: unit(base.as_dvec3()),
                    angle: 0.0,
                };
                for _ in 0..8 {
                    let d = unit((base + rng.dir() * spread).as_dvec3());
                    fast.extend(d);
                    if exact.axis.dot(d) < exact.angle.cos() {
                        exact = union_d(
                            exact,
                            DCone {
                                axis: d,
                                angle: 0.0,
                            },
                        );
                    }
                    let angle_fast = fast.sin.atan2(fast.cos);
                    assert!(
                        (angle_fast - exact.angle).abs() <= 1e-9 * (1.0 + exact.angle),
                        "half-angle {angle_fast} against {}",
                        exact.angle
                    );
                    if exact.angle < 3.0 {
                        assert!(angle(fast.axis, exact.axis) <= 1e-7 + 1e-6 * exact.angle);
                    }
                    // The inside test `axis·d ≥ cos φ` resolves angles to about 1e-8 rad
                    // near zero (the stored angle is re-measured).
                    let out = angle(fast.axis, d) - angle_fast;
                    assert!(
                        out <= 2e-8,
                        "direction {out} rad outside, spread {spread}, half-angle {angle_fast}"
                    );
                }
            }
        }
        // A direction opposite to the axis: a half-turn about some perpendicular.
        let mut cone = GrowingCone {
            axis: DVec3::Z,
            cos: 1.0,
            sin: 0.0,
        };
        cone.extend(-DVec3::Z);
        assert!(cone.cos.abs() < 1e-12 && (cone.sin - 1.0).abs() < 1e-12);
        assert!(cone.axis.z.abs() < 1e-12);
    }

    /// The ray sets the containment tests build over.
    fn ray_sets(rng: &mut Rng) -> Vec<(&'static str, Vec<Ray>)> {
        vec![
            ("coherent", coherent(rng, 1000)),
            ("random", random(rng, 777)),
            ("opposite", opposite(rng, 500)),
            ("one point", one_point(rng, 640)),
        ]
    }

    #[test]
    fn children_inside_parents_on_varied_ray_sets() {
        let mut rng = Rng(0x1234_5678);
        let sets = ray_sets(&mut rng);
        for (name, rays) in &sets {
            for (k, (s, depth)) in [(2, 8), (3, 4), (8, 2), (8, 8), (64, 3)]
                .into_iter()
                .enumerate()
            {
                // Leaves in batch order (neighbours share a node: the opposite pairs meet)
                // and shuffled.
                let order = if k % 2 == 0 {
                    identity(rays.len())
                } else {
                    shuffled(&mut rng, rays.len())
                };
                let sizes = check_containment(rays, &order, s, depth);
                println!(
                    "{name}: {} rays, subdivision {s}, depth {depth}: nodes per level {sizes:?}",
                    rays.len()
                );
            }
        }
    }

    /// `leaf_cone = extremes`: every ray inside its nodes on every ray set and shape, the
    /// same nodes as eq. 3.8-3.11 where the directions cancel (the fallback), lowest cones
    /// narrower on average than eq. 3.8-3.11's on coherent bundles and never wider by more than
    /// the comparison's rounding on spread ones (where it keeps the narrower axis).
    #[test]
    fn extreme_ray_cones_contain_every_ray() {
        let mut rng = Rng(0x5eed);
        let sets = ray_sets(&mut rng);
        for (name, rays) in &sets {
            for (k, (s, depth)) in [(2, 8), (3, 4), (8, 2), (16, 3), (64, 3), (8, 3)]
                .into_iter()
                .enumerate()
            {
                // Batch order keeps the coherent bundles together; shuffled spreads them.
                let coherent_order = k >= 2;
                let order = if coherent_order {
                    identity(rays.len())
                } else {
                    shuffled(&mut rng, rays.len())
                };
                let shape = SphereConeBuilder::with_params(s, depth).unwrap();
                let (_, ext) =
                    check_containment_with(rays, &order, shape.with_leaf_cone(LeafCone::Extremes));
                let (_, inc) = check_containment_with(rays, &order, shape);
                let mean = |v: &[SphereCone]| {
                    v.iter().map(|n| n.cone.half_angle as f64).sum::<f64>() / v.len() as f64
                };
                println!(
                    "{name} {s}/{depth}: mean lowest half-angle extremes {:.5}, incremental {:.5}",
                    mean(&ext[0]),
                    mean(&inc[0])
                );
                // Nodes of at most 16 rays lie within one bundle of 16 (64 span four).
                if *name == "coherent" && coherent_order && s <= 16 {
                    assert!(mean(&ext[0]) < mean(&inc[0]), "{name} {s}/{depth}");
                }
                // A wide node kept the narrower of the heuristic and eq. 3.8-3.11.
                let wide = WIDE_LEAF_COS.acos() * 1.01;
                for (e, i) in ext[0].iter().zip(&inc[0]) {
                    assert!(
                        e.cone.half_angle as f64 <= wide
                            || e.cone.half_angle <= i.cone.half_angle * 1.0001 + 1e-6,
                        "{name} {s}/{depth}: {e:?} wider than {i:?}"
                    );
                }
            }
        }
        // Directions that cancel exactly: the fallback is eq. 3.8-3.11 itself. (Over spread
        // directions, a shuffled order's nodes, the heuristic axes can be wider than eq.
        // 3.8-3.11's: printed above, not asserted.)
        let rays = [
            ray(Vec3::ZERO, Vec3::X),
            ray(Vec3::Y, -Vec3::X),
            ray(Vec3::Z, Vec3::Y),
            ray(Vec3::ONE, -Vec3::Y),
        ];
        let build = |how| {
            SphereConeBuilder::with_params(4, 1)
                .unwrap()
                .with_leaf_cone(how)
                .build_levels(&rays, &identity(4))
                .unwrap()
        };
        assert_eq!(build(LeafCone::Extremes), build(LeafCone::Incremental));
    }

    #[test]
    fn box_centred_spheres_contain_every_origin() {
        let mut rng = Rng(0xb0c5);
        let sets = ray_sets(&mut rng);
        for (name, rays) in &sets {
            let order = shuffled(&mut rng, rays.len());
            for (s, depth) in [(2, 6), (16, 3), (64, 2)] {
                // Containment of rays and children at every level, as with Welzl's spheres.
                let shape = SphereConeBuilder::with_params(s, depth).unwrap();
                let (_, welzl) = check_containment_with(rays, &order, shape);
                let (_, boxed) = check_containment_with(
                    rays,
                    &order,
                    shape.with_leaf_sphere(LeafSphere::BoxCentre),
                );
                for (k, (w, b)) in welzl[0].iter().zip(&boxed[0]).enumerate() {
                    let leaves = leaf_range(0, k, s, order.len());
                    let origins: Vec<Vec3> = leaves
                        .map(|leaf| rays[order[leaf] as usize].origin)
                        .collect();
                    // The centre is the box's, the radius reaches every origin, and the
                    // minimal sphere is never larger (up to its own rounding and margin).
                    assert_eq!(
                        b.sphere.center,
                        crsh_core::Aabb::from_points(origins.iter().copied()).center()
                    );
                    for o in &origins {
                        assert!(
                            b.sphere.center.as_dvec3().distance(o.as_dvec3())
                                <= b.sphere.radius as f64
                        );
                    }
                    assert!(
                        w.sphere.radius <= b.sphere.radius * (1.0 + 1e-5) + 1e-6,
                        "{name}"
                    );
                    // Only the spheres differ.
                    assert_eq!(w.cone, b.cone);
                }
            }
        }
    }

    #[test]
    fn coherent_bundles_give_narrow_nodes() {
        // Bundles of 16 rays (direction jitter ≤ 0.05, origins within a 1-unit cube) align
        // with the nodes of 8 leaves in batch order: each lowest node stays narrow and small.
        let mut rng = Rng(11);
        let rays = coherent(&mut rng, 4096);
        let b = SphereConeBuilder::with_params(8, 3).unwrap();
        let levels = b.build_levels(&rays, &identity(rays.len())).unwrap();
        for node in &levels[0] {
            assert!(node.cone.half_angle < 0.11, "{node:?}");
            assert!(node.sphere.radius < 0.87, "{node:?}");
        }
        let random = random(&mut rng, 4096);
        let wide = b.build_levels(&random, &identity(4096)).unwrap();
        for (l, (a, b)) in levels.iter().zip(&wide).enumerate() {
            let mean = |v: &[SphereCone]| {
                let n = v.len() as f64;
                (
                    v.iter().map(|x| x.cone.half_angle as f64).sum::<f64>() / n,
                    v.iter().map(|x| x.sphere.radius as f64).sum::<f64>() / n,
                )
            };
            println!(
                "level {l}: coherent mean (half-angle, radius) {:?}, random {:?}",
                mean(a),
                mean(b)
            );
        }
    }

    #[test]
    fn opposite_rays_in_one_node_give_a_hemisphere_or_more() {
        let rays = [
            ray(Vec3::ZERO, Vec3::X),
            ray(Vec3::Y, -Vec3::X),
            ray(Vec3::Z, Vec3::X),
            ray(Vec3::ONE, -Vec3::X),
        ];
        for s in [2, 4] {
            let b = SphereConeBuilder::with_params(s, 2).unwrap();
            let levels = b.build_levels(&rays, &identity(4)).unwrap();
            for node in levels.iter().flatten() {
                let half = node.cone.half_angle as f64;
                assert!((PI / 2.0..PI / 2.0 + 1e-5).contains(&half), "{node:?}");
                assert!(node.cone.axis.dot(Vec3::X).abs() < 1e-6, "{node:?}");
            }
        }
        // Three directions spanning more than a hemisphere.
        let wide = [
            ray(Vec3::ZERO, Vec3::X),
            ray(Vec3::ZERO, -Vec3::X),
            ray(Vec3::ZERO, Vec3::new(0.0, -1.0, -1.0)),
            ray(Vec3::ZERO, Vec3::new(0.0, 1.0, -1.0)),
            ray(Vec3::ZERO, Vec3::Z),
        ];
        let b = SphereConeBuilder::with_params(8, 1).unwrap();
        let node = b.build_levels(&wide, &identity(5)).unwrap()[0][0];
        assert!(node.cone.half_angle as f64 > PI / 2.0);
        for r in &wide {
            assert!(covers(&node, r.origin, r.dir), "{node:?} {r:?}");
        }
    }

    #[test]
    fn one_point_rays_have_zero_radius_and_coherent_cones_stay_tight() {
        let mut rng = Rng(7);
        let rays = one_point(&mut rng, 64);
        let b = SphereConeBuilder::with_params(8, 3).unwrap();
        let levels = b.build_levels(&rays, &identity(64)).unwrap();
        for node in levels.iter().flatten() {
            assert_eq!(node.sphere.radius, 0.0);
            assert_eq!(node.sphere.center, rays[0].origin);
        }
        // Parallel rays: the cone is the margin only.
        let par: Vec<Ray> = (0..16)
            .map(|i| ray(Vec3::new(i as f32, 0.0, 0.0), Vec3::new(0.3, 0.4, -1.2)))
            .collect();
        let levels = b.build_levels(&par, &identity(16)).unwrap();
        for node in levels.iter().flatten() {
            assert!(node.cone.half_angle < 1e-5, "{node:?}");
            assert!(node
                .cone
                .axis
                .abs_diff_eq(Vec3::new(0.3, 0.4, -1.2).normalize(), 1e-6));
        }
        // Leaf sphere of 8 collinear origins 0..7: centre 3.5, radius 3.5 (+ margin).
        let s = levels[0][0].sphere;
        assert!(
            (s.center.x - 3.5).abs() < 1e-6 && (s.radius - 3.5).abs() < 1e-5,
            "{s:?}"
        );
        // Upper sphere over origins 0..15: tight union gives centre 7.5, radius 7.5.
        let s = levels[1][0].sphere;
        assert!(
            (s.center.x - 7.5).abs() < 1e-5 && (s.radius - 7.5).abs() < 1e-4,
            "{s:?}"
        );
    }

    #[test]
    fn incremental_cone_is_tight_for_two_rays_and_a_fan() {
        let mut rng = Rng(99);
        for _ in 0..200 {
            let (a, b) = (rng.dir(), rng.dir());
            let start = Cone {
                axis: a,
                half_angle: 0.0,
            };
            let c = extend_cone(&start, b);
            let between = angle(a.as_dvec3(), b.as_dvec3());
            assert!(
                (c.half_angle as f64 - between / 2.0).abs() < 1e-6,
                "{c:?} {between}"
            );
            // The axis bisects the two rays.
            let ca = angle(c.axis.as_dvec3(), a.as_dvec3());
            let cb = angle(c.axis.as_dvec3(), b.as_dvec3());
            assert!((ca - between / 2.0).abs() < 1e-6 && (cb - between / 2.0).abs() < 1e-6);
        }
        // Symmetric fan: 12 directions at 0.3 rad around -y, in any order.
        let axis = -Vec3::Y;
        let fan: Vec<Vec3> = (0..12)
            .map(|k| {
                let a = k as f32 * std::f32::consts::TAU / 12.0;
                (axis * 0.3f32.cos() + Vec3::new(a.cos(), 0.0, a.sin()) * 0.3f32.sin()).normalize()
            })
            .collect();
        let mut perm = [0, 6, 3, 9, 1, 7, 4, 10, 2, 8, 5, 11];
        for round in 0..2 {
            let mut c = Cone {
                axis: fan[perm[0]],
                half_angle: 0.0,
            };
            for &k in &perm[1..] {
                c = extend_cone(&c, fan[k]);
            }
            assert!((c.half_angle - 0.3).abs() < 1e-5, "round {round}: {c:?}");
            assert!(c.axis.abs_diff_eq(axis, 1e-5), "round {round}: {c:?}");
            perm.reverse();
        }
        // Opposite rays: a hemisphere about a perpendicular axis.
        let c = extend_cone(
            &Cone {
                axis: Vec3::X,
                half_angle: 0.0,
            },
            -Vec3::X,
        );
        assert!((c.half_angle as f64 - PI / 2.0).abs() < 1e-6);
        assert!(c.axis.dot(Vec3::X).abs() < 1e-6);
        // Past a hemisphere: a 2.5 rad cone plus its opposite direction is (2.5 + π) / 2 wide
        // (not the full sphere); a direction at 2 rad is inside; one at 2.8 rad gives
        // (2.5 + 2.8) / 2; a full cone stays full.
        let wide = Cone {
            axis: Vec3::Z,
            half_angle: 2.5,
        };
        let c = extend_cone(&wide, -Vec3::Z);
        assert!(
            (c.half_angle as f64 - (2.5 + PI) / 2.0).abs() < 1e-6,
            "{c:?}"
        );
        assert!(angle(c.axis.as_dvec3(), -DVec3::Z) <= c.half_angle as f64 + 1e-6);
        let full = Cone {
            axis: Vec3::Y,
            half_angle: PI as f32,
        };
        assert_eq!(extend_cone(&full, -Vec3::Y).half_angle, PI as f32);
        let d = Vec3::new(2.0f32.sin(), 0.0, 2.0f32.cos());
        let inside = extend_cone(&wide, d);
        assert_eq!(inside, wide);
        let d = Vec3::new(2.8f32.sin(), 0.0, 2.8f32.cos());
        let c = extend_cone(&wide, d);
        assert!((c.half_angle - 2.65).abs() < 1e-5, "{c:?}");
        assert!(angle(c.axis.as_dvec3(), d.as_dvec3()) <= c.half_angle as f64 + 1e-6);
    }

    /// The erratum form of eq. 3.12-3.13.
    fn errata_union(a: &Cone, b: &Cone) -> f64 {
        (angle(a.axis.as_dvec3(), b.axis.as_dvec3()) / 2.0
            + (a.half_angle.max(b.half_angle)) as f64)
            .min(PI)
    }

    #[test]
    fn cone_union_contains_both_and_beats_the_erratum() {
        let mut rng = Rng(2024);
        for i in 0..300 {
            let a = Cone {
                axis: rng.dir(),
                half_angle: rng
                    .range(0.0, if i % 3 == 0 { 3.2 } else { 0.8 })
                    .min(PI as f32),
            };
            let b = Cone {
                axis: if i % 10 == 0 { -a.axis } else { rng.dir() },
                half_angle: rng.range(0.0, 0.8),
            };
            let u = cone_union(&a, &b);
            assert!(
                u.half_angle as f64 <= errata_union(&a, &b) + 1e-6,
                "{a:?} {b:?} {u:?}"
            );
            if a.half_angle == b.half_angle {
                assert!((u.half_angle as f64 - errata_union(&a, &b)).abs() < 1e-5);
            }
            // Brute force: directions sampled on and inside both cones lie in the union.
            for c in [&a, &b] {
                let basis = c.axis.any_orthonormal_pair();
                for k in 0..24 {
                    let rot = k as f32 * std::f32::consts::TAU / 24.0;
                    for frac in [0.0, 0.5, 1.0] {
                        let phi = c.half_angle * frac;
                        let side = basis.0 * rot.cos() + basis.1 * rot.sin();
                        let d = c.axis * phi.cos() + side * phi.sin();
                        let off = angle(u.axis.as_dvec3(), d.as_dvec3()) - u.half_angle as f64;
                        assert!(off <= 1e-5, "{a:?} {b:?} {u:?}: {d} off by {off}");
                    }
                }
            }
        }
        // The union of two equal-angle cones is the erratum's exactly.
        let a = Cone {
            axis: Vec3::X,
            half_angle: 0.2,
        };
        let b = Cone {
            axis: Vec3::Y,
            half_angle: 0.2,
        };
        let u = cone_union(&a, &b);
        assert!((u.half_angle as f64 - (PI / 4.0 + 0.2)).abs() < 1e-6);
        assert!(u
            .axis
            .abs_diff_eq(Vec3::new(1.0, 1.0, 0.0).normalize(), 1e-6));
        // Nested cones: the wider one.
        let c = Cone {
            axis: Vec3::X,
            half_angle: 1.0,
        };
        assert_eq!(cone_union(&c, &a), c);
        assert_eq!(cone_union(&a, &c), c);
    }

    #[test]
    fn sphere_union_is_tight_and_contains_both() {
        let a = Sphere::new(Vec3::ZERO, 1.0);
        let b = Sphere::new(Vec3::new(4.0, 0.0, 0.0), 2.0);
        let u = sphere_union(&a, &b);
        assert_eq!(u, Sphere::new(Vec3::new(2.5, 0.0, 0.0), 3.5));
        assert_eq!(sphere_union(&b, &Sphere::new(Vec3::X * 4.5, 0.5)), b);
        let mut rng = Rng(5);
        for _ in 0..200 {
            let a = Sphere::new(rng.point(10.0), rng.range(0.0, 5.0));
            let b = Sphere::new(rng.point(10.0), rng.range(0.0, 5.0));
            let u = sphere_union(&a, &b);
            for s in [a, b] {
                let far = u.center.distance(s.center) + s.radius;
                assert!(far <= u.radius * (1.0 + 1e-6) + 1e-5);
            }
            // Never larger than eq. 3.14-3.15.
            let thesis = a.center.distance(b.center) / 2.0 + a.radius.max(b.radius);
            assert!(u.radius <= thesis * (1.0 + 1e-6));
        }
    }

    #[test]
    fn node_counts_per_level() {
        assert_eq!(level_sizes(0, 8, 2), Vec::<usize>::new());
        assert_eq!(level_sizes(1, 8, 2), vec![1]);
        assert_eq!(level_sizes(8, 8, 2), vec![1]);
        assert_eq!(level_sizes(9, 8, 2), vec![2, 1]);
        assert_eq!(level_sizes(1000, 8, 2), vec![125, 16]);
        assert_eq!(level_sizes(1000, 8, 8), vec![125, 16, 2, 1]);
        assert_eq!(level_sizes(1001, 2, 3), vec![501, 251, 126]);
        assert_eq!(leaf_range(0, 2, 8, 100), 16..24);
        assert_eq!(leaf_range(1, 1, 8, 100), 64..100);
        assert_eq!(leaf_range(1, 2, 8, 100), 100..100);
        assert_eq!(leaf_range(7, usize::MAX, 64, 5), 5..5);
        let b = SphereConeBuilder::with_params(4, 8).unwrap();
        let mut rng = Rng(1);
        for n in [1usize, 3, 4, 5, 16, 17, 100, 1025] {
            let rays = random(&mut rng, n);
            let levels = b.build_levels(&rays, &identity(n)).unwrap();
            for (l, level) in levels.iter().enumerate() {
                assert_eq!(level.len(), n.div_ceil(4usize.pow(l as u32 + 1)));
            }
            assert_eq!(levels.last().unwrap().len(), 1);
        }
    }

    #[test]
    fn deterministic_across_thread_counts() {
        let mut rng = Rng(77);
        let mut rays = coherent(&mut rng, 3000);
        rays.extend(random(&mut rng, 3000));
        let order = shuffled(&mut rng, rays.len());
        let b = SphereConeBuilder::with_params(8, 4).unwrap();
        let one = crate::with_threads(1, || b.build_levels(&rays, &order).unwrap()).unwrap();
        let three = crate::with_threads(3, || b.build_levels(&rays, &order).unwrap()).unwrap();
        assert_eq!(one.len(), 4);
        assert!(one == three, "levels differ between 1 and 3 threads");
    }

    #[test]
    fn angle_estimates_stay_within_their_bound() {
        let mut rng = Rng(31);
        let mut worst = 0.0f64;
        let mut check = |a: DVec3, b: DVec3| {
            let err = (angle_estimate(a, b) - angle(a, b)).abs();
            worst = worst.max(err);
            assert!(err <= ANGLE_ESTIMATE_ERROR, "{a} {b}: off by {err}");
        };
        // Every angle in [0, π] in the plane, around each octant's edge, and random pairs
        // of unit and non-unit vectors.
        for k in 0..=200_000 {
            let t = PI * k as f64 / 200_000.0;
            check(DVec3::X, DVec3::new(t.cos(), t.sin(), 0.0));
            check(
                DVec3::new(0.0, 0.0, 3.0),
                DVec3::new(t.sin(), 0.0, t.cos()) * 0.25,
            );
        }
        for _ in 0..20_000 {
            let (a, b) = (rng.dir().as_dvec3(), rng.dir().as_dvec3() * 7.0);
            check(a, b);
            check(a, a);
            check(a, -a);
        }
        // The polynomial's own error is about 0.0015 rad: the bound has room for rounding.
        assert!(
            worst > 1e-3 && worst < 0.5 * ANGLE_ESTIMATE_ERROR,
            "worst {worst}"
        );
    }

    #[test]
    fn widest_child_is_the_largest_measured_angle() {
        let mut rng = Rng(32);
        for n in [1usize, 2, 5, 16, 64] {
            for spread in [1e-7f32, 1e-3, 0.05, 0.5, 3.0] {
                let a = rng.dir().as_dvec3();
                let children: Vec<(DVec3, f64)> = (0..n)
                    .map(|_| {
                        let x = (a + rng.dir().as_dvec3() * spread as f64).normalize();
                        (x, rng.unit() as f64 * spread as f64)
                    })
                    .collect();
                let all = children
                    .iter()
                    .fold(0.0f64, |m, &(x, p)| m.max(angle(a, x) + p));
                let got = widest_child(a, children.iter().copied());
                assert_eq!(got.to_bits(), all.to_bits(), "n {n}, spread {spread}");
            }
        }
        // Near ties: angle + φ within 1e-4 of each other at angles the estimate gets wrong
        // by different amounts, so its order is not the measured one.
        for trial in 0..200 {
            let a = DVec3::Z;
            let children: Vec<(DVec3, f64)> = (0..16)
                .map(|i| {
                    let theta = 2.0 * rng.unit() as f64;
                    let x = DVec3::new(theta.sin(), 0.0, theta.cos());
                    (x, 2.5 - theta + 1e-5 * i as f64)
                })
                .collect();
            let all = children
                .iter()
                .fold(0.0f64, |m, &(x, p)| m.max(angle(a, x) + p));
            let got = widest_child(a, children.iter().copied());
            assert_eq!(got.to_bits(), all.to_bits(), "trial {trial}");
        }
        assert_eq!(widest_child(DVec3::Z, std::iter::empty()), 0.0);
    }

    #[test]
    fn bad_input_is_an_error() {
        let b = SphereConeBuilder::with_params(8, 2).unwrap();
        let mut rays = vec![ray(Vec3::ZERO, Vec3::Z); 20];
        assert!(b.build_levels(&[], &[]).unwrap().is_empty());
        for order in [vec![0, 1, 20], identity(19), {
            let mut o = identity(20);
            o[7] = 3;
            o
        }] {
            let err = b.build_levels(&rays, &order).unwrap_err();
            assert!(matches!(err, CoreError::InvalidInput(_)), "{err}");
        }
        let mut o = identity(20);
        o.swap(0, 19);
        o[4] = 0;
        let err = b.build_levels(&rays, &o).unwrap_err();
        assert!(err.to_string().contains("ray 0 appears twice"), "{err}");
        rays[5].dir = Vec3::ZERO;
        rays[9].dir = Vec3::new(f32::NAN, 0.0, 1.0);
        let err = b.build_levels(&rays, &identity(20)).unwrap_err();
        assert!(err.to_string().contains("ray 5 "), "{err}");
        let mut o = identity(20);
        o.swap(0, 9);
        let err = b.build_levels(&rays, &o).unwrap_err();
        assert!(err.to_string().contains("ray 9 "), "{err}");
        rays[5].dir = Vec3::Z;
        rays[9].dir = Vec3::Z;
        rays[3].origin.y = f32::INFINITY;
        assert!(b.build_levels(&rays, &identity(20)).is_err());
        // The lowest level finds unusable rays as it reads them, in parallel: the error
        // still names the first leaf in the order, whichever thread met which.
        let mut rng = Rng(5);
        let mut many = coherent(&mut rng, 5000);
        let order = shuffled(&mut rng, many.len());
        for leaf in [4321, 77, 2500] {
            many[order[leaf] as usize].dir = Vec3::new(0.0, f32::INFINITY, 1.0);
        }
        for threads in [1, 3] {
            let err = crate::with_threads(threads, || b.build_levels(&many, &order))
                .unwrap()
                .unwrap_err();
            assert!(err.to_string().contains("(leaf 77)"), "{err}");
        }
        assert!(SphereConeBuilder::with_params(1, 2).is_err());
        assert!(SphereConeBuilder::with_params(65, 2).is_err());
        assert!(SphereConeBuilder::with_params(8, 0).is_err());
        assert!(SphereConeBuilder::with_params(8, 9).is_err());
    }

    #[test]
    fn stage_builds_through_the_trait_and_reads_its_spec() {
        let scene = Arc::new(crsh_scene::builtin::build("cornell-mirrors").unwrap());
        let mut spec = StageSpec::new("sphere_cone");
        for p in info().params {
            spec.params.insert(p.name.to_string(), p.default);
        }
        let b = SphereConeBuilder::new(&scene, &spec).unwrap();
        assert_eq!((b.subdivision(), b.depth()), (8, 2));
        spec.params.insert("subdivision".into(), ParamValue::Int(4));
        spec.params.insert("depth".into(), ParamValue::Int(3));
        let b = SphereConeBuilder::new(&scene, &spec).unwrap();
        assert_eq!((b.subdivision(), b.depth()), (4, 3));
        assert_eq!(b.leaf_cone(), LeafCone::Incremental);
        spec.params
            .insert("leaf_cone".into(), ParamValue::Str("extremes".into()));
        assert_eq!(
            SphereConeBuilder::new(&scene, &spec).unwrap().leaf_cone(),
            LeafCone::Extremes
        );
        spec.params
            .insert("leaf_cone".into(), ParamValue::Str("widest".into()));
        assert!(SphereConeBuilder::new(&scene, &spec).is_err());
        spec.params
            .insert("leaf_cone".into(), ParamValue::Str("incremental".into()));
        assert_eq!(b.leaf_sphere(), LeafSphere::Welzl);
        spec.params
            .insert("leaf_sphere".into(), ParamValue::Str("box".into()));
        assert_eq!(
            SphereConeBuilder::new(&scene, &spec).unwrap().leaf_sphere(),
            LeafSphere::BoxCentre
        );
        spec.params
            .insert("leaf_sphere".into(), ParamValue::Str("ritter".into()));
        assert!(SphereConeBuilder::new(&scene, &spec).is_err());
        spec.params
            .insert("leaf_sphere".into(), ParamValue::Str("welzl".into()));
        spec.params
            .insert("leaf_cone".into(), ParamValue::Str("incremental".into()));
        spec.params.insert("depth".into(), ParamValue::Int(9));
        assert!(SphereConeBuilder::new(&scene, &spec).is_err());

        let mut rng = Rng(3);
        let rays = coherent(&mut rng, 100);
        let order = shuffled(&mut rng, 100);
        let mut stats = Stats::default();
        let h = HierarchyBuilder::<Cpu>::build(&b, &Cpu, &rays, order.clone(), &mut stats).unwrap();
        assert_eq!(HierarchyBuilder::<Cpu>::name(&b), info().name);
        assert_eq!(h.order, order);
        assert_eq!(h.subdivision, 4);
        assert_eq!(
            h.levels.iter().map(Vec::len).collect::<Vec<_>>(),
            vec![25, 7, 2]
        );
    }

    #[test]
    fn brute_candidates_over_the_hierarchy_match_the_scene_query() {
        use crate::intersect::brute::BruteForce;
        use crsh_core::{Candidate, CandidateBatch, HitMode, Intersector, Query};
        let scene = crsh_scene::builtin::build("cornell-mirrors").unwrap();
        let mut rng = Rng(8);
        let c = scene.bounds.center();
        let half = scene.bounds.size() * 0.4;
        let rays: Vec<Ray> = (0..300)
            .map(|_| {
                let p = c + half
                    * Vec3::new(
                        rng.range(-1.0, 1.0),
                        rng.range(-1.0, 1.0),
                        rng.range(-1.0, 1.0),
                    );
                ray(p, rng.dir())
            })
            .collect();
        let order = shuffled(&mut rng, rays.len());
        let b = SphereConeBuilder::with_params(8, 2).unwrap();
        let h =
            HierarchyBuilder::<Cpu>::build(&b, &Cpu, &rays, order, &mut Stats::default()).unwrap();
        let pairs: Vec<Candidate> = (0..h.levels[0].len() as u32)
            .flat_map(|node| {
                (0..scene.triangle_count() as u32).map(move |tri| Candidate { node, tri })
            })
            .collect();
        let brute = BruteForce::from_scene(&scene);
        let mut stats = Stats::default();
        let mut via_nodes = vec![Hit::MISS; rays.len()];
        let batch = CandidateBatch::new(pairs);
        let query = Query::Candidates {
            hierarchy: &h,
            batch: &batch,
        };
        brute
            .intersect(
                &Cpu,
                &rays,
                query,
                HitMode::Closest,
                &mut via_nodes,
                &mut stats,
            )
            .unwrap();
        let mut direct = vec![Hit::MISS; rays.len()];
        brute
            .intersect(
                &Cpu,
                &rays,
                Query::Scene,
                HitMode::Closest,
                &mut direct,
                &mut stats,
            )
            .unwrap();
        assert_eq!(via_nodes, direct);
        assert!(direct.iter().any(|h| h.tri != crsh_core::NO_HIT));
    }

    #[test]
    fn covers_and_swept_excess_reject_outside_rays() {
        let node = SphereCone {
            sphere: Sphere::new(Vec3::ZERO, 1.0),
            cone: Cone {
                axis: Vec3::Z,
                half_angle: 0.5,
            },
        };
        assert!(covers(
            &node,
            Vec3::new(0.5, 0.5, 0.5),
            Vec3::new(0.0, 0.4, 1.0)
        ));
        assert!(!covers(&node, Vec3::new(1.0, 1.0, 0.0), Vec3::Z));
        assert!(!covers(&node, Vec3::ZERO, Vec3::X));
        assert!(!covers(&node, Vec3::ZERO, Vec3::ZERO));
        // Along the axis and inside the widening: inside; beside the cone, beyond r: outside.
        assert!(swept_excess(&node, DVec3::new(0.0, 0.0, 100.0)) <= 0.0);
        assert!(swept_excess(&node, DVec3::new(0.0, 100.0 * 0.5f64.tan(), 100.0)) <= 0.0);
        let beside = DVec3::new(0.0, 10.0, 0.0);
        let e = swept_excess(&node, beside);
        assert!(
            (e - (10.0 * (PI / 2.0 - 0.5).sin() - 1.0)).abs() < 1e-9,
            "{e}"
        );
        // Behind the apex region: distance to the centre.
        assert!((swept_excess(&node, DVec3::new(0.0, 0.0, -5.0)) - 4.0).abs() < 1e-12);
    }
}
