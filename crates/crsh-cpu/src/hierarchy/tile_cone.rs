//! `tile_cone`: one enclosing cone per screen tile, Szécsi's hierarchical ray engine
//! (seed 004: "The Hierarchical Ray Engine", WSCG 2006, §3-§4 and §7), on the shared spec of
//! the CPU and wgpu twins (`tile_cone_spec.md`).
//!
//! # Nodes
//!
//! The rays arrive in the sorter's `order`. A node is a maximal run of consecutive positions
//! whose rays have the same *group* ([`TileGrid::group`], the one definition the `tile` hasher
//! uses for its keys: the tile of the ray's pixel for tiles of `tile_size` pixels, per light
//! for shadow rays). With the `tile` hasher and the same `tile_size`, every run is one whole
//! tile after compaction (only the rays that exist); over rays in generation order (no
//! sorting) runs are pieces of tiles, which is still correct, only less coherent. The
//! hierarchy has **one level** (the paper's tiles are not grouped further), the node ranges in
//! [`RayHierarchy::leaf_offsets`] (`offsets[k]` = first position of node `k`, the last entry
//! the ray count) and `subdivision = tile_size²` (nominal: no level above uses it).
//!
//! Each node is an *apex cone* stored as a [`SphereCone`]: sphere `(apex, 0)`, cone
//! `(axis, half_angle)`. Containment contract: every point `o + t·d`, `t ≥ 0`, of every ray of
//! the node lies in the cone of apex `apex`, unit axis `axis`, half-angle `half_angle`, which
//! is the hierarchy's node contract with sphere radius 0 (containing the whole half-line from
//! the origin contains every segment: the rays' `t_min ≥ 0`). [`RayHierarchy::reach`] holds,
//! per node, an upper bound on the distance from the apex to every point a ray reaches in its
//! interval: the largest distance from the apex to a ray's origin or to `o + d·t_max` (the
//! distance along a segment is convex, so its ends bound it), computed in `f64`, infinite for
//! an unbounded ray, rounded up by the sphere-cone builder's guard
//! ([`crate::hierarchy::sphere_cone::round_up_reach`]).
//!
//! # The incremental cone (seed 004 §4), in `f32`
//!
//! Start with the zero-angle cone of the first ray (`a = o₀`, `x = normalize(d₀)`, `φ = 0`).
//! For each further ray (origin `p = o_k`, direction `r = normalize(d_k)`):
//!
//! - **(a) Extending the cone** (§4, fig. 2) when `x·r < cos φ`: with
//!   `q = ((x·r)·x − r) / |(x·r)·x − r|` and the generator opposite the ray
//!   `e = x·cos φ + q·sin φ`, the new axis is `x_new = (e + r) / |e + r|` and
//!   `cos φ_new = x_new·r`: the narrowest cone holding the old solid angle and `r`.
//! - **(b) Translating the cone** (§4, fig. 3) when the origin lies outside
//!   (`x·c < cos φ·|c|`, `c = p − a`): with `q` as above for `c`, the far and near generators
//!   `e = x·cos φ + q·sin φ`, `n = x·cos φ − q·sin φ`, the offset of the origin from the near
//!   generator `g = c − (n·c)·n`, the translation `t = g² / (e·g)` and the new apex
//!   `a_new = a + e·t` (see erratum 1): the cone slides back along its far generator until the
//!   near generator passes through the origin, so it still holds the old cone.
//!
//! The exact operation order (the wgpu twin's kernel performs the same operations, so their
//! outputs agree to rounding) is in [`node_cone`]: `dot(a, b) = (a.x·b.x + a.y·b.y) + a.z·b.z`,
//! `length(v) = sqrt(dot(v, v))`, `normalize(v) = v / length(v)` (a division per component,
//! not a multiplication by a reciprocal), `cross` as in glam, `angle(x, v) =
//! atan2(length(cross(x, v)), dot(x, v))`. The rays of a node are independent of the other
//! nodes, so the nodes are built in parallel (rayon, one task per node) and the result does
//! not depend on the thread count.
//!
//! **Final pass (guard).** The incremental result only chooses the apex and the axis: the
//! stored half-angle is re-measured from the stored `a` and `x` as the largest
//! `max(angle(x, d_k), angle(x, o_k − a))` over the node's rays (the second term skipped when
//! `o_k = a`), then `φ·(1 + 10⁻⁵) + 4·10⁻⁶` for the rounding of the `f32` angles. So
//! containment never depends on the accuracy of the incremental formulas. A node whose cone
//! had to exceed a half-space (`full`) or whose guarded `φ ≥ π/2` stores half-angle π.
//!
//! # Errata and choices
//!
//! 1. **Apex sign.** The paper prints `a_new = a − e·t`. With `t = g²/(e·g) < 0` (`g` points
//!    away from the cone, `e` into it) the translation must be `a + e·t`: then
//!    `p − a_new = c − e·t = (n·c − t·(n·e))·n + (g − t·(e − (n·e)·n))`, and the second term
//!    vanishes exactly for `t = g²/(e·g)` (all vectors lie in the plane of `x` and `c`), so the
//!    origin lies on the near generator; with `a − e·t` it does not, and the origin stays
//!    outside (the test `the_papers_apex_sign_loses_the_origin` shows a 30° cone for which the
//!    literal update leaves the origin at 120° from the axis; [`translate_apex`] applies one
//!    step either way). Since `a − a_new = −e·t = |t|·e` lies in the cone, the translated cone
//!    holds the old one.
//! 2. **Cone-sphere test.** The paper culls a triangle's bounding sphere `(v, r)` unless
//!    `φ > arccos[(v − a)·x] − arcsin[r / |v − a|]` (§4). As printed, `v − a` is not
//!    normalized (it must be: `arccos((v − a)·x / |v − a|)`), a sphere containing the apex
//!    (`|v − a| ≤ r`, where `arcsin` is undefined) must count as a hit, and `φ ≥ 90°` must
//!    disable culling: such a cone is no longer convex, so holding every origin and every
//!    direction no longer implies holding the half-lines `o + t·d` (for a convex cone `K`,
//!    `(o − a) + t·d ∈ K + K ⊆ K`); the builder stores π for it, and that node culls only by
//!    its reach. The `crsh` traverser's [`NodeBound::may_hit`](crate::traverse::crsh::NodeBound::may_hit)
//!    with sphere radius 0 is exactly this corrected test (with small margins): it passes
//!    when the apex lies in the sphere, and otherwise iff
//!    `angle(x, v − a) ≤ φ + arcsin(r / |v − a|)`, evaluated without trigonometry, every
//!    sphere passing once that sum reaches π; see the proof in the traverser's module docs
//!    ("The node-sphere test"). A node of half-angle π passes every sphere within its reach.
//! 3. **Zero-angle widening.** A zero-angle cone (all rays so far parallel) cannot be
//!    translated to hold an origin off its axis line (`e = n = x`, so `e·g = 0`). Before a
//!    translation the half-angle is raised to at least `min_half_angle_deg` (default 1°, [`DEFAULT_MIN_HALF_ANGLE_DEG`]):
//!    `sin φ` and `cos φ` are replaced by those of the minimum when `sin φ` is below it.
//!    [`TileConeParams::sin_cos_min`] computes them once, in `f64`, rounded to `f32` (the
//!    wgpu host passes the same two numbers to its kernel).
//! 4. **`q` undefined.** The paper's `q` divides by `|(x·r)·x − r|`, which is 0 when the ray
//!    is parallel or opposite to the axis (or the origin lies on the axis line); below
//!    `10⁻⁶·|v|` ([`PERP_EPS`], where `f32` rounding alone makes `w`) a fixed perpendicular
//!    of `x` is used (`normalize(cross(x, (1,0,0)))` if `|x.x| < 0.9`, else with `(0,1,0)`).
//! 5. **Beyond a half-space.** The paper's cone extension is minimal only while the result
//!    is narrower than a hemisphere. For `φ + angle(x, r) ≥ π` (`x·r ≤ −cos φ`) the new
//!    half-angle `(φ + angle(x, r)) / 2` reaches 90° and `e + r` would bisect the other arc,
//!    so the node is marked *full* (half-angle π) at once; so it is when `|e + r| ≤ 10⁻⁶` or
//!    `cos φ_new ≤ 0` after an extension (rounding at the boundary). Should the incremental
//!    apex or axis ever stop being finite (it needs an overflow), the node is full too, its
//!    apex the first ray's origin.
//! 6. **Origins behind the apex.** The translation puts the origin on the near generator's
//!    *line*: `p − a_new = λ·n` with `λ = |c|·sin(θ + φ) / sin 2φ` (`θ = angle(x, c)`), which
//!    is negative when `θ ≥ π − φ`, i.e. when `p` lies in the mirror image of the cone behind
//!    its apex (an origin on the axis line behind the apex, for instance). The paper does not
//!    treat this case. Then (`−x·c ≥ cos φ·|c|`, after the widening of item 3) the apex moves
//!    to `p` itself: `a − p` lies in the cone, so the cone of apex `p` holds the old one and
//!    the origin, with the same axis and angle.
//!
//! # Degenerate input
//!
//! An `order` that is not a permutation of the batch, a ray with a non-finite origin or a
//! zero-length or non-finite direction, or a ray whose pixel lies outside the frame is
//! [`CoreError::InvalidInput`] naming the first such leaf. No rays give one empty level and
//! the offsets `[0]`.
//!
//! [`TileGrid::group`]: crate::hash::tile::TileGrid::group

use std::f32::consts::{FRAC_PI_2, PI};

use crsh_core::glam::{DVec3, Vec3};
use crsh_core::{
    Cone, CoreError, FrameSize, HierarchyBuilder, ParamInfo, Ray, RayHierarchy, Registry, Result,
    Sphere, SphereCone, StageKind, StageSpec, StageVariantInfo, Stats,
};
use rayon::prelude::*;

use crate::hash::tile::{tile_size_param, TileGrid, TILE_SIZE_RANGE};
use crate::hierarchy::sphere_cone::{round_up_reach, validate_leaves};
use crate::Cpu;

/// Default minimum half-angle, in degrees, a cone gets before it is translated (erratum 3).
///
/// Measured on `glass-sphere-5000` at 256², 16-pixel tiles, depth 2 (all tests of the frame
/// in % of brute force's): 0.05° → 6.8 %, 0.5° → 1.25 %, **1° → 0.95 %**, 2° → 0.99 %,
/// 3° → 1.06 %, 5° → 1.25 %, 10° → 1.96 %. A tiny minimum slides the apex far back along
/// a nearly parallel generator at the first translation (`t ≈ offset / sin 2φ`), and the
/// later extensions about that distant apex end wide (first-generation cones of 28° mean
/// at 0.05° against 1.05° at 1°).
pub const DEFAULT_MIN_HALF_ANGLE_DEG: f64 = 1.0;
/// Largest accepted `min_half_angle_deg` (the smallest is anything above 0).
pub const MAX_MIN_HALF_ANGLE_DEG: f64 = 10.0;
/// Relative enlargement of the re-measured half-angle (`f32`): `1 + 10⁻⁵`.
pub const GUARD_SCALE: f32 = 1.0 + 1e-5;
/// Absolute enlargement of the re-measured half-angle, radians (`f32`).
pub const GUARD_ADD: f32 = 4e-6;
/// `|e + r|` at or below which extending the cone would exceed a half-space.
pub const EXTEND_EPS: f32 = 1e-6;
/// Relative length below which the component of a vector orthogonal to the axis counts as
/// zero (erratum 4).
pub const PERP_EPS: f32 = 1e-6;
/// `|x.x|` below which [`any_perpendicular`] crosses `x` with the x axis (else the y axis).
pub const PERP_SWITCH: f32 = 0.9;

/// The catalogue entry of this variant.
pub fn info() -> StageVariantInfo {
    StageVariantInfo::new(
        StageKind::Hierarchy,
        "tile_cone",
        "one enclosing cone (apex, axis, angle) per screen tile of consecutive rays, built \
         incrementally (seed 004 §4, apex sign corrected), one level with variable-size \
         nodes (seed 004, the hierarchical ray engine)",
    )
    .param(tile_size_param())
    .param(
        ParamInfo::float(
            "min_half_angle_deg",
            DEFAULT_MIN_HALF_ANGLE_DEG,
            "the smallest half-angle, in degrees (> 0), a cone is widened to before it is \
             translated to hold an origin off its axis (a zero-angle cone cannot be)",
        )
        .range(0.0, MAX_MIN_HALF_ANGLE_DEG),
    )
}

/// Registers `tile_cone` ([`info`], [`TileConeBuilder::new`]).
pub fn register(registry: &mut Registry<Cpu>) -> Result<()> {
    registry.add_hierarchy(info(), |ctx, spec| {
        Ok(Box::new(TileConeBuilder::new(ctx.frame, spec)?))
    })?;
    Ok(())
}

/// The parameters of the tile cones.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TileConeParams {
    /// Tile side in pixels ([`TILE_SIZE_RANGE`]).
    pub tile_size: u32,
    /// Minimum half-angle before a translation, degrees, in `(0, 10]` (erratum 3).
    pub min_half_angle_deg: f64,
}

impl Default for TileConeParams {
    fn default() -> Self {
        TileConeParams {
            tile_size: crate::hash::tile::DEFAULT_TILE_SIZE,
            min_half_angle_deg: DEFAULT_MIN_HALF_ANGLE_DEG,
        }
    }
}

impl TileConeParams {
    /// Checked parameters.
    ///
    /// # Errors
    /// [`CoreError::InvalidParam`] for a tile size outside [`TILE_SIZE_RANGE`] or a minimum
    /// half-angle outside `(0, 10]` degrees.
    pub fn new(tile_size: u32, min_half_angle_deg: f64) -> Result<TileConeParams> {
        crate::hash::tile::check_tile_size("tile_cone.tile_size", tile_size)?;
        if !(min_half_angle_deg > 0.0 && min_half_angle_deg <= MAX_MIN_HALF_ANGLE_DEG) {
            return Err(CoreError::InvalidParam {
                key: "tile_cone.min_half_angle_deg".into(),
                reason: format!(
                    "{min_half_angle_deg} is outside (0, {MAX_MIN_HALF_ANGLE_DEG}] degrees"
                ),
            });
        }
        Ok(TileConeParams {
            tile_size,
            min_half_angle_deg,
        })
    }

    /// `(sin, cos)` of the minimum half-angle: computed once in `f64` from the degrees and
    /// rounded to `f32` (the `sin_min`, `cos_min` of [`node_cone`]).
    pub fn sin_cos_min(&self) -> (f32, f32) {
        let rad = self.min_half_angle_deg.to_radians();
        (rad.sin() as f32, rad.cos() as f32)
    }
}

/// The tile cones of one batch: what [`build_nodes`] computes and the builder stores.
#[derive(Clone, Debug, PartialEq)]
pub struct TileCones {
    /// `nodes.len() + 1` strictly increasing positions in `order`, from 0 to the ray count:
    /// node `k` holds `order[offsets[k] .. offsets[k + 1]]`.
    pub offsets: Vec<u32>,
    /// Per node: sphere `(apex, 0)`, cone `(axis, half_angle)`; half-angle π for a node whose
    /// rays need more than a half-space.
    pub nodes: Vec<SphereCone>,
    /// Per node: an upper bound on the distance from the apex to any point its rays reach
    /// in their interval (`f32::INFINITY` for an unbounded ray).
    pub reach: Vec<f32>,
    /// Per node: whether the incremental construction gave up (*full*: the cone had to exceed
    /// a half-space). A full node stores π; so does a node whose re-measured angle reached
    /// π/2.
    pub full: Vec<bool>,
}

impl TileCones {
    /// Nodes whose stored half-angle is π (they cull only by reach).
    pub fn full_nodes(&self) -> usize {
        self.nodes
            .iter()
            .filter(|n| n.cone.half_angle >= PI)
            .count()
    }
}

/// The tile cones of `rays` taken in `order`, for the frame `frame` (see the module docs).
///
/// # Errors
/// [`CoreError::InvalidInput`] for an `order` that is not a permutation of the rays, a ray
/// without a finite origin and a finite non-zero direction, or a ray whose pixel lies outside
/// the frame; [`CoreError::InvalidParam`] for a tile size out of range.
pub fn build_nodes(
    rays: &[Ray],
    order: &[u32],
    frame: FrameSize,
    params: &TileConeParams,
) -> Result<TileCones> {
    validate_leaves("tile_cone", rays, order)?;
    let grid = TileGrid::new(frame, params.tile_size)?;
    let offsets = group_offsets(rays, order, &grid)?;
    let (sin_min, cos_min) = params.sin_cos_min();
    let built: Vec<(SphereCone, bool, f32)> = offsets
        .par_windows(2)
        .map(|w| {
            let leaves = &order[w[0] as usize..w[1] as usize];
            let (node, full) = node_cone(rays, leaves, sin_min, cos_min);
            (node, full, node_reach(rays, leaves, node.sphere.center))
        })
        .collect();
    let mut cones = TileCones {
        offsets,
        nodes: Vec::with_capacity(built.len()),
        reach: Vec::with_capacity(built.len()),
        full: Vec::with_capacity(built.len()),
    };
    for (node, full, reach) in built {
        cones.nodes.push(node);
        cones.full.push(full);
        cones.reach.push(reach);
    }
    Ok(cones)
}

/// The node boundaries: `offsets[k]` is the first position of the `k`-th maximal run of
/// positions of `order` whose rays share a [`TileGrid::group`], the last entry `order.len()`.
///
/// # Errors
/// [`CoreError::InvalidInput`] for a ray whose pixel lies outside the frame (the first one).
/// `order` must index `rays` (it is not checked here otherwise).
pub fn group_offsets(rays: &[Ray], order: &[u32], grid: &TileGrid) -> Result<Vec<u32>> {
    let groups: Vec<Option<u64>> = order
        .par_iter()
        .map(|&i| grid.group(&rays[i as usize]))
        .collect();
    if let Some(leaf) = groups.iter().position(Option::is_none) {
        let r = &rays[order[leaf] as usize];
        return Err(CoreError::InvalidInput(format!(
            "tile_cone: ray {} (leaf {leaf}) has pixel {}, outside the {} frame",
            order[leaf],
            r.pixel,
            grid.frame()
        )));
    }
    let mut offsets = Vec::with_capacity(order.len() / 16 + 2);
    offsets.push(0u32);
    for i in 1..groups.len() {
        if groups[i] != groups[i - 1] {
            offsets.push(i as u32);
        }
    }
    if !order.is_empty() {
        offsets.push(order.len() as u32);
    }
    Ok(offsets)
}

/// `(a.x·b.x + a.y·b.y) + a.z·b.z` in `f32` (glam's order, written out for the twin).
#[inline]
fn dot(a: Vec3, b: Vec3) -> f32 {
    a.x * b.x + a.y * b.y + a.z * b.z
}

/// `sqrt(dot(v, v))`.
#[inline]
fn length(v: Vec3) -> f32 {
    dot(v, v).sqrt()
}

/// `v / length(v)`, component by component.
#[inline]
fn normalize(v: Vec3) -> Vec3 {
    let l = length(v);
    Vec3::new(v.x / l, v.y / l, v.z / l)
}

/// `atan2(length(cross(x, v)), dot(x, v))` in `f32`.
#[inline]
fn angle(x: Vec3, v: Vec3) -> f32 {
    length(x.cross(v)).atan2(dot(x, v))
}

/// A unit vector perpendicular to `x` (erratum 4): `normalize(cross(x, (1, 0, 0)))` if
/// `|x.x| <` [`PERP_SWITCH`] (0.9), else `normalize(cross(x, (0, 1, 0)))`.
#[inline]
pub fn any_perpendicular(x: Vec3) -> Vec3 {
    if x.x.abs() < PERP_SWITCH {
        normalize(x.cross(Vec3::X))
    } else {
        normalize(x.cross(Vec3::Y))
    }
}

/// The paper's `q` (§4): the unit vector from `v` towards the axis line of `x`, in the plane
/// of `x` and `v`: `w = x·xv − v` (with `xv = x·v`), `w / |w|`; when
/// `|w| ≤ 10⁻⁶·|v|` ([`PERP_EPS`]: `v` parallel or opposite to the axis to within `f32`
/// rounding, so `w` is rounding noise), [`any_perpendicular`].
#[inline]
pub fn perp_towards_axis(x: Vec3, v: Vec3, xv: f32) -> Vec3 {
    let w = x * xv - v;
    let l = length(w);
    if l > PERP_EPS * length(v) {
        Vec3::new(w.x / l, w.y / l, w.z / l)
    } else {
        any_perpendicular(x)
    }
}

/// Which sign step (b) moves the apex with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ApexSign {
    /// `a + e·t`: the corrected update (erratum 1), what the builder uses.
    Corrected,
    /// `a − e·t`: the update as the paper prints it (for the erratum's evidence).
    Paper,
}

/// One translation of step (b) (§4, fig. 3) for the cone `(a, x, φ)` (`cos φ`, `sin φ`) and
/// the origin `p` lying outside it: `c = p − a`, `q` towards the axis, far and near generators
/// `e`, `n`, `g = c − (n·c)·n`, `t = g² / (e·g)`, and the new apex `a + e·t` (or the paper's
/// `a − e·t`). `None` when `e·g` is not negative (a translation cannot hold the origin: never
/// the case in exact arithmetic for a cone of positive angle below π/2).
pub fn translate_apex(
    a: Vec3,
    x: Vec3,
    cos_phi: f32,
    sin_phi: f32,
    p: Vec3,
    sign: ApexSign,
) -> Option<Vec3> {
    let c = p - a;
    let q = perp_towards_axis(x, c, dot(x, c));
    let e = x * cos_phi + q * sin_phi;
    let n = x * cos_phi - q * sin_phi;
    let g = c - n * dot(n, c);
    let eg = dot(e, g);
    if eg >= 0.0 || eg.is_nan() {
        return None;
    }
    let t = dot(g, g) / eg;
    Some(match sign {
        ApexSign::Corrected => a + e * t,
        ApexSign::Paper => a - e * t,
    })
}

/// The tile cone of the rays `leaves` (indices into `rays`, non-empty, validated), with the
/// minimum half-angle's `sin_min`, `cos_min` ([`TileConeParams::sin_cos_min`]): the node
/// (sphere `(apex, 0)`, cone `(axis, half_angle)`) and whether the construction gave up
/// (*full*). The operations, in `f32` and in this order (the spec both twins follow):
///
/// ```text
/// x = normalize(d₀); a = o₀; cos φ = 1; sin φ = 0; full = false
/// for each further ray (o, d):
///     r = normalize(d); xr = dot(x, r)
///     if xr < cos φ:                                   // (a) extend
///         q = perp_towards_axis(x, r, xr); e = x·cos φ + q·sin φ
///         s = e + r; ls = length(s)
///         if ls ≤ 1e-6: full; stop
///         x = s / ls; cos φ = dot(x, r)
///         if cos φ ≤ 0: full; stop
///         sin φ = sqrt(max(0, 1 − cos φ·cos φ))
///     c = o − a
///     if dot(x, c) < cos φ·length(c):                   // (b) translate
///         if sin φ < sin_min: cos φ = cos_min; sin φ = sin_min
///         a = translate_apex(a, x, cos φ, sin φ, o, Corrected), or full; stop
/// φ = max over the rays of max(angle(x, d), angle(x, o − a) unless o = a)
/// φ = φ·(1 + 1e-5) + 4e-6; half_angle = π if full or φ ≥ π/2, else φ
/// ```
pub fn node_cone(rays: &[Ray], leaves: &[u32], sin_min: f32, cos_min: f32) -> (SphereCone, bool) {
    let ray = |i: u32| &rays[i as usize];
    let first = ray(leaves[0]);
    let mut x = normalize(first.dir);
    let mut a = first.origin;
    let mut cos_phi = 1.0f32;
    let mut sin_phi = 0.0f32;
    let mut full = false;
    for &i in &leaves[1..] {
        if full {
            break;
        }
        let k = ray(i);
        let r = normalize(k.dir);
        // (a) Extend the solid angle to hold r (§4, fig. 2).
        let xr = dot(x, r);
        if xr < cos_phi {
            if xr <= -cos_phi {
                // φ + angle(x, r) ≥ π: the new half-angle (φ + angle) / 2 reaches 90° and `e + r`
                // would bisect the wrong arc; the cone culls nothing any more (erratum 2).
                full = true;
                break;
            }
            let q = perp_towards_axis(x, r, xr);
            let e = x * cos_phi + q * sin_phi;
            let s = e + r;
            let ls = length(s);
            if ls <= EXTEND_EPS {
                full = true;
                break;
            }
            x = Vec3::new(s.x / ls, s.y / ls, s.z / ls);
            cos_phi = dot(x, r);
            if cos_phi <= 0.0 {
                full = true;
                break;
            }
            sin_phi = (1.0 - cos_phi * cos_phi).max(0.0).sqrt();
        }
        // (b) Translate to hold the origin (§4, fig. 3), apex sign corrected (erratum 1).
        let c = k.origin - a;
        let (xc, lc) = (dot(x, c), length(c));
        if xc < cos_phi * lc {
            if sin_phi < sin_min {
                cos_phi = cos_min;
                sin_phi = sin_min;
            }
            if -xc >= cos_phi * lc {
                // The origin lies in the backward cone (angle(x, c) ≥ π − φ): the cone with its
                // apex there holds the old one (a − p is within φ of x) and the origin, with
                // the same axis and angle; translating along a generator would put the origin
                // on the near generator's backward extension instead.
                a = k.origin;
                continue;
            }
            match translate_apex(a, x, cos_phi, sin_phi, k.origin, ApexSign::Corrected) {
                Some(moved) => a = moved,
                None => {
                    full = true;
                    break;
                }
            }
        }
    }
    if !(a.is_finite() && x.is_finite()) {
        // Safety net (module docs, item 5): a full node at the first origin.
        full = true;
        a = first.origin;
        x = if x.is_finite() { x } else { Vec3::Z };
    }
    let half_angle = if full {
        PI
    } else {
        let mut phi = 0.0f32;
        for &i in leaves {
            let k = ray(i);
            phi = phi.max(angle(x, k.dir));
            let c = k.origin - a;
            if c != Vec3::ZERO {
                phi = phi.max(angle(x, c));
            }
        }
        let phi = phi * GUARD_SCALE + GUARD_ADD;
        // A NaN angle (a degenerate direction) goes to π too.
        if phi >= FRAC_PI_2 || phi.is_nan() {
            PI
        } else {
            phi
        }
    };
    let node = SphereCone {
        sphere: Sphere::new(a, 0.0),
        cone: Cone {
            axis: x,
            half_angle,
        },
    };
    (node, full)
}

/// An upper bound on the distance from `apex` to every point the rays `leaves` reach: the
/// largest distance, in `f64`, to a ray's origin or to `o + d·t_max` (infinite when `t_max`
/// is infinite or NaN), rounded up by [`round_up_reach`].
pub fn node_reach(rays: &[Ray], leaves: &[u32], apex: Vec3) -> f32 {
    let a = apex.as_dvec3();
    let far = leaves.iter().fold(0.0f64, |m, &i| {
        let r = &rays[i as usize];
        let o = r.origin.as_dvec3();
        let end = if r.t_max.is_nan() || r.t_max == f32::INFINITY {
            f64::INFINITY
        } else {
            (o + r.dir.as_dvec3() * r.t_max as f64 - a).length()
        };
        m.max((o - a).length()).max(end)
    });
    round_up_reach(far)
}

/// Checks, in `f64`, what the tile cones promise (the spec's containment test, for the tests of
/// both twins): for node `k` (leaves `order[offsets[k] .. offsets[k + 1]]`) with the stored
/// (`f32`) apex `a`, axis `x` and half-angle `φ`, sphere radius 0, and for each of its rays,
/// `angle(x, d) ≤ φ` and `angle(x, o − a) ≤ φ` (unless `o = a`) or `φ = π`, and the reach bounds
/// `|o − a|` and `|o + d·t_max − a|` (infinite when `t_max` is not finite). Returns the number
/// of π nodes.
///
/// # Errors
/// A description of the first violation (or of mismatched lengths).
pub fn check_containment(
    rays: &[Ray],
    order: &[u32],
    offsets: &[u32],
    nodes: &[SphereCone],
    reach: &[f32],
) -> std::result::Result<usize, String> {
    crsh_core::check_leaf_offsets(offsets, nodes.len(), order.len()).map_err(|e| e.to_string())?;
    if reach.len() != nodes.len() {
        return Err(format!(
            "{} reach bounds for {} nodes",
            reach.len(),
            nodes.len()
        ));
    }
    let angle64 = |a: DVec3, b: DVec3| a.cross(b).length().atan2(a.dot(b));
    // `v ≤ bound`, false for NaN.
    let within = |v: f64, bound: f64| v <= bound;
    let mut full = 0;
    for (k, (node, w)) in nodes.iter().zip(offsets.windows(2)).enumerate() {
        let a = node.sphere.center.as_dvec3();
        let x = node.cone.axis.as_dvec3();
        let phi = node.cone.half_angle as f64;
        let bound = reach[k] as f64;
        if node.sphere.radius != 0.0 || !within(0.0, phi) {
            return Err(format!("node {k} is not an apex cone: {node:?}"));
        }
        full += (node.cone.half_angle >= PI) as usize;
        for &i in &order[w[0] as usize..w[1] as usize] {
            let r = rays
                .get(i as usize)
                .ok_or_else(|| format!("node {k} names ray {i} of {}", rays.len()))?;
            let o = r.origin.as_dvec3();
            let d = r.dir.as_dvec3();
            if node.cone.half_angle < PI {
                let ad = angle64(x, d);
                if !within(ad, phi) {
                    return Err(format!("node {k} ray {i}: direction at {ad} rad > {phi}"));
                }
                if o != a {
                    let ao = angle64(x, o - a);
                    if !within(ao, phi) {
                        return Err(format!("node {k} ray {i}: origin at {ao} rad > {phi}"));
                    }
                }
            }
            let end = if r.t_max.is_finite() {
                (o + d * r.t_max as f64 - a).length()
            } else {
                f64::INFINITY
            };
            let far = (o - a).length().max(end);
            if !within(far, bound) {
                return Err(format!("node {k} ray {i}: reaches {far} > reach {bound}"));
            }
        }
    }
    Ok(full)
}

/// The `tile_cone` hierarchy builder (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TileConeBuilder {
    frame: FrameSize,
    params: TileConeParams,
}

impl TileConeBuilder {
    /// The builder for `frame` with the parameters of a resolved `spec` (`tile_size`,
    /// `min_half_angle_deg`).
    ///
    /// # Errors
    /// [`CoreError::InvalidParam`] for a parameter out of range.
    pub fn new(frame: FrameSize, spec: &StageSpec) -> Result<TileConeBuilder> {
        let params = TileConeParams::new(
            spec.u32_in("tile_size", TILE_SIZE_RANGE)?,
            spec.f64("min_half_angle_deg")?,
        )?;
        Ok(TileConeBuilder::with_params(frame, params))
    }

    /// The builder for `frame` with `params`.
    pub fn with_params(frame: FrameSize, params: TileConeParams) -> TileConeBuilder {
        TileConeBuilder { frame, params }
    }

    /// The parameters.
    pub fn params(&self) -> &TileConeParams {
        &self.params
    }

    /// The frame whose pixels the rays name.
    pub fn frame(&self) -> FrameSize {
        self.frame
    }
}

impl HierarchyBuilder<Cpu> for TileConeBuilder {
    fn name(&self) -> &str {
        "tile_cone"
    }

    fn build(
        &self,
        _backend: &Cpu,
        rays: &Vec<Ray>,
        order: Vec<u32>,
        _stats: &mut Stats,
    ) -> Result<RayHierarchy<Cpu>> {
        let cones = build_nodes(rays, &order, self.frame, &self.params)?;
        Ok(RayHierarchy {
            order,
            levels: vec![cones.nodes],
            subdivision: self.params.tile_size * self.params.tile_size,
            leaf_offsets: Some(cones.offsets),
            reach: vec![cones.reach],
        })
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::triangle::tests::TestRng;
    use crate::with_threads;
    use crsh_core::glam::DVec3;
    use crsh_core::{ParamValue, RayKind};

    /// The angle between two vectors in `f64`.
    fn angle64(a: DVec3, b: DVec3) -> f64 {
        a.cross(b).length().atan2(a.dot(b))
    }

    /// [`check_containment`], panicking with `what` on a violation; the number of π nodes.
    pub(crate) fn assert_contains(
        cones: &TileCones,
        rays: &[Ray],
        order: &[u32],
        what: &str,
    ) -> usize {
        check_containment(rays, order, &cones.offsets, &cones.nodes, &cones.reach)
            .unwrap_or_else(|e| panic!("{what}: {e}"))
    }

    /// Checks the offsets: first 0, last n, strictly increasing, one group per run, adjacent
    /// runs of different groups.
    pub(crate) fn assert_offsets(
        cones: &TileCones,
        rays: &[Ray],
        order: &[u32],
        grid: &TileGrid,
        what: &str,
    ) {
        let o = &cones.offsets;
        assert_eq!(o.len(), cones.nodes.len() + 1, "{what}");
        assert_eq!(cones.reach.len(), cones.nodes.len(), "{what}");
        assert_eq!(cones.full.len(), cones.nodes.len(), "{what}");
        assert_eq!(o[0], 0, "{what}");
        assert_eq!(*o.last().unwrap() as usize, order.len(), "{what}");
        assert!(
            o.windows(2).all(|w| w[0] < w[1]),
            "{what}: not strictly increasing"
        );
        let group = |leaf: u32| grid.group(&rays[order[leaf as usize] as usize]).unwrap();
        for (k, w) in o.windows(2).enumerate() {
            let g = group(w[0]);
            assert!(
                (w[0]..w[1]).all(|l| group(l) == g),
                "{what}: node {k} mixes groups"
            );
            if k > 0 {
                assert_ne!(
                    group(w[0] - 1),
                    g,
                    "{what}: nodes {} and {k} share a group",
                    k - 1
                );
            }
        }
    }

    const W: u32 = 100;
    const H: u32 = 37;

    fn frame() -> FrameSize {
        FrameSize::new(W, H).unwrap()
    }

    fn ray(kind: RayKind, pixel: u32, light: u32, origin: Vec3, dir: Vec3, t_max: f32) -> Ray {
        Ray {
            pixel,
            light,
            source: pixel,
            ..Ray::new(kind, origin, dir, 0.0, t_max)
        }
    }

    /// One ray per pixel of the 100×37 frame (two per pixel for the shadow soup, one per
    /// light), made by `make(rng, pixel)`.
    fn soup(seed: u64, name: &str) -> Vec<Ray> {
        let mut rng = TestRng(seed);
        let n = W * H;
        let refl =
            |o: Vec3, d: Vec3, p: u32| ray(RayKind::Reflection, p, u32::MAX, o, d, f32::INFINITY);
        let axis = rng.unit();
        match name {
            // Parallel rays from different origins.
            "parallel" => (0..n).map(|p| refl(rng.vec3(-5.0, 5.0), axis, p)).collect(),
            // Opposite directions side by side (every tile needs more than a half-space).
            "opposite" => (0..n)
                .map(|p| {
                    let d = if p % 2 == 0 { axis } else { -axis };
                    refl(rng.vec3(-1.0, 1.0), d, p)
                })
                .collect(),
            // Origins on the axis line (q undefined for the translation), some behind.
            "on_axis" => (0..n)
                .map(|p| {
                    let d = (axis + rng.vec3(-0.01, 0.01)).normalize();
                    refl(
                        Vec3::splat(0.5) + axis * rng.range(-3.0, 3.0),
                        if p % 3 == 0 { axis } else { d },
                        p,
                    )
                })
                .collect(),
            // Huge coordinates, coherent directions, finite segments.
            "huge" => (0..n)
                .map(|p| {
                    let o = Vec3::new(1e6, -2e6, 3e6) + rng.vec3(-10.0, 10.0);
                    let d = (axis + rng.vec3(-0.05, 0.05)).normalize();
                    let mut r = refl(o, d, p);
                    r.t_max = rng.range(1.0, 1e4);
                    r
                })
                .collect(),
            // Grazing: directions close to a plane, spread around in it.
            "grazing" => {
                let (u, v) = axis.any_orthonormal_pair();
                (0..n)
                    .map(|p| {
                        let t = rng.range(-0.4, 0.4) + (p % 7) as f32 * 0.01;
                        let d =
                            (u * t.cos() + v * t.sin() + axis * rng.range(-0.02, 0.02)).normalize();
                        refl(rng.vec3(-2.0, 2.0), d, p)
                    })
                    .collect()
            }
            // Coherent bundles per pixel block: what tiles see on a mirror.
            "coherent" => (0..n)
                .map(|p| {
                    let (x, y) = ((p % W) as f32, (p / W) as f32);
                    let o = Vec3::new(x * 0.01, y * 0.01, (x * 0.3).sin() * 0.05);
                    let d = (axis + Vec3::new(x * 0.002, y * 0.002, 0.0) + rng.vec3(-1e-3, 1e-3))
                        .normalize();
                    refl(o, d, p)
                })
                .collect(),
            // Shadow rays of two lights (the light's position as origin, segments to points).
            "shadow" => {
                let lights = [Vec3::new(0.0, 5.0, 0.0), Vec3::new(3.0, 4.0, -2.0)];
                (0..2u32)
                    .flat_map(|l| (0..n).map(move |p| (l, p)))
                    .map(|(l, p)| {
                        let target = Vec3::new(
                            (p % W) as f32 * 0.05 - 2.5,
                            -1.0,
                            (p / W) as f32 * 0.05 - 1.0,
                        );
                        let seg = target - lights[l as usize];
                        ray(
                            RayKind::Shadow,
                            p,
                            l,
                            lights[l as usize],
                            seg.normalize(),
                            seg.length() * 0.999,
                        )
                    })
                    .collect()
            }
            // Anything goes.
            "random" => (0..n)
                .map(|p| refl(rng.vec3(-3.0, 3.0), rng.unit(), p))
                .collect(),
            _ => unreachable!(),
        }
    }

    const SOUPS: [&str; 8] = [
        "parallel", "opposite", "on_axis", "huge", "grazing", "coherent", "shadow", "random",
    ];

    /// The stable tile order (what `tile` + `radix` produce).
    fn tile_order(rays: &[Ray], grid: &TileGrid) -> Vec<u32> {
        let mut order: Vec<u32> = (0..rays.len() as u32).collect();
        order.sort_by_key(|&i| grid.group(&rays[i as usize]).unwrap());
        order
    }

    fn shuffled(n: usize, seed: u64) -> Vec<u32> {
        let mut rng = TestRng(seed);
        let mut order: Vec<u32> = (0..n as u32).collect();
        for i in (1..n).rev() {
            order.swap(i, rng.next_u64() as usize % (i + 1));
        }
        order
    }

    #[test]
    fn every_ray_of_every_node_lies_in_its_cone() {
        for (si, name) in SOUPS.iter().enumerate() {
            let rays = soup(100 + si as u64, name);
            let mut full_somewhere = 0;
            let mut narrow = 0;
            for ts in [1u32, 8, 16, 32] {
                let params = TileConeParams::new(ts, DEFAULT_MIN_HALF_ANGLE_DEG).unwrap();
                let grid = TileGrid::new(frame(), ts).unwrap();
                for (oi, order) in [
                    tile_order(&rays, &grid),
                    (0..rays.len() as u32).collect(),
                    shuffled(rays.len(), 7 + si as u64),
                ]
                .into_iter()
                .enumerate()
                {
                    let what = format!("{name} tile {ts} order {oi}");
                    let cones = build_nodes(&rays, &order, frame(), &params).unwrap();
                    assert_offsets(&cones, &rays, &order, &grid, &what);
                    full_somewhere += assert_contains(&cones, &rays, &order, &what);
                    narrow += cones
                        .nodes
                        .iter()
                        .filter(|n| n.cone.half_angle < 0.5)
                        .count();
                    if oi == 0 {
                        // Sorted by tile: one node per tile (per light for shadow rays).
                        let groups = if *name == "shadow" { 2 } else { 1 } * grid.tiles() as usize;
                        assert_eq!(cones.nodes.len(), groups, "{what}");
                    }
                    // Tiles of one pixel: every node holds one ray, ≈ 0 wide.
                    if ts == 1 && oi == 0 && *name != "shadow" {
                        assert!(
                            cones.nodes.iter().all(|n| n.cone.half_angle <= 1e-5),
                            "{what}"
                        );
                    }
                }
            }
            match *name {
                "opposite" | "random" => assert!(full_somewhere > 0, "{name}: never full"),
                "parallel" | "coherent" | "huge" | "on_axis" | "shadow" => {
                    assert!(narrow > 0, "{name}: never narrow")
                }
                _ => {}
            }
        }
    }

    #[test]
    fn single_rays_and_parallel_rays() {
        let d = Vec3::new(0.3, -0.2, 0.9).normalize();
        let rays = vec![ray(
            RayKind::Reflection,
            0,
            u32::MAX,
            Vec3::new(1.0, 2.0, 3.0),
            d,
            5.0,
        )];
        let params = TileConeParams::default();
        let cones = build_nodes(&rays, &[0], frame(), &params).unwrap();
        assert_eq!(cones.offsets, [0, 1]);
        let n = cones.nodes[0];
        assert_eq!(n.sphere.center, Vec3::new(1.0, 2.0, 3.0));
        assert!(n.cone.half_angle <= 1e-5 && n.cone.half_angle >= GUARD_ADD);
        assert!(!cones.full[0]);
        assert!((cones.reach[0] - 5.0).abs() < 1e-4 && cones.reach[0] >= 5.0);
        // Two parallel rays side by side: widened to the minimum angle, then translated back.
        let rays = vec![
            ray(
                RayKind::Reflection,
                0,
                u32::MAX,
                Vec3::ZERO,
                Vec3::Z,
                f32::INFINITY,
            ),
            ray(
                RayKind::Reflection,
                1,
                u32::MAX,
                Vec3::X,
                Vec3::Z,
                f32::INFINITY,
            ),
        ];
        let cones = build_nodes(&rays, &[0, 1], frame(), &params).unwrap();
        let n = cones.nodes[0];
        let min = DEFAULT_MIN_HALF_ANGLE_DEG.to_radians() as f32;
        assert!(
            n.cone.half_angle >= min && n.cone.half_angle < min * 1.01,
            "{n:?}"
        );
        // The apex sits behind both origins, about 0.5 / tan(min) back along the axis.
        assert!(n.sphere.center.z < -0.5 / min.tan() * 0.99, "{n:?}");
        assert_contains(&cones, &rays, &[0, 1], "parallel pair");
        // Empty batch: one empty level.
        let cones = build_nodes(&[], &[], frame(), &params).unwrap();
        assert_eq!(cones.offsets, [0]);
        assert!(cones.nodes.is_empty());
    }

    #[test]
    fn the_papers_apex_sign_loses_the_origin() {
        // A 30° cone at the origin along +z and the ray origin (2, 0, 0), at 90° off axis.
        let (a, x) = (Vec3::ZERO, Vec3::Z);
        let (sin_phi, cos_phi) = (0.5f32, 0.75f32.sqrt());
        let p = Vec3::new(2.0, 0.0, 0.0);
        let at = |apex: Vec3| angle64(x.as_dvec3(), (p - apex).as_dvec3()).to_degrees();
        let fixed = translate_apex(a, x, cos_phi, sin_phi, p, ApexSign::Corrected).unwrap();
        let paper = translate_apex(a, x, cos_phi, sin_phi, p, ApexSign::Paper).unwrap();
        // t = g²/(e·g) = −2: a + e·t = (1, 0, −√3), the origin lies on the near generator...
        assert!(
            (fixed - Vec3::new(1.0, 0.0, -3f32.sqrt())).length() < 1e-5,
            "{fixed}"
        );
        assert!((at(fixed) - 30.0).abs() < 1e-4, "{}", at(fixed));
        // ...and the old apex is inside the moved cone (it holds the old cone).
        assert!(angle64(x.as_dvec3(), (a - fixed).as_dvec3()).to_degrees() <= 30.0 + 1e-4);
        // a − e·t = (−1, 0, √3): the origin is at 120° from the axis, far outside.
        assert!(
            (paper - Vec3::new(-1.0, 0.0, 3f32.sqrt())).length() < 1e-5,
            "{paper}"
        );
        assert!((at(paper) - 120.0).abs() < 1e-3, "{}", at(paper));
    }

    #[test]
    fn beyond_a_half_space_and_behind_the_apex() {
        let params = TileConeParams::default();
        let (s, c) = params.sin_cos_min();
        let r = |o: Vec3, d: Vec3, p: u32| ray(RayKind::Reflection, p, u32::MAX, o, d, 1.0);
        // Module docs item 5: z, then x (a 45° cone about (x + z)/√2), then a direction 150°
        // from that axis: φ + θ = 195° ≥ 180°, so the node is flagged full at once (e + r
        // would bisect the wrong arc).
        let axis = (Vec3::X + Vec3::Z).normalize();
        let (u, _) = axis.any_orthonormal_pair();
        let t = 150f32.to_radians();
        let back = axis * t.cos() + u * t.sin();
        let rays = [
            r(Vec3::ZERO, Vec3::Z, 0),
            r(Vec3::ZERO, Vec3::X, 1),
            r(Vec3::ZERO, back, 2),
        ];
        let (node, full) = node_cone(&rays, &[0, 1, 2], s, c);
        assert_eq!((node.cone.half_angle, full), (PI, true));
        // 120° instead: φ + θ = 165°, a cone of about 82.5° that holds all three.
        let t = 120f32.to_radians();
        let side = axis * t.cos() + u * t.sin();
        let rays = [
            r(Vec3::ZERO, Vec3::Z, 0),
            r(Vec3::ZERO, Vec3::X, 1),
            r(Vec3::ZERO, side, 2),
        ];
        let (node, full) = node_cone(&rays, &[0, 1, 2], s, c);
        assert!(
            !full && node.cone.half_angle < 83f32.to_radians(),
            "{node:?}"
        );
        // Item 6: an origin behind the apex, on the axis line. One translation step would put
        // it on the backward extension of the near generator, 180° − φ = 170° from the axis;
        // the builder moves the apex onto it instead, which keeps a thin cone.
        let p = Vec3::new(0.0, 0.0, -1.0);
        let (sin10, cos10) = (10f32.to_radians().sin(), 10f32.to_radians().cos());
        let moved =
            translate_apex(Vec3::ZERO, Vec3::Z, cos10, sin10, p, ApexSign::Corrected).unwrap();
        let seen = angle64(DVec3::Z, (p - moved).as_dvec3()).to_degrees();
        assert!((seen - 170.0).abs() < 1e-3, "{seen}");
        let rays = [r(Vec3::ZERO, Vec3::Z, 0), r(p, Vec3::Z, 1)];
        let (node, full) = node_cone(&rays, &[0, 1], s, c);
        assert!(!full && node.cone.half_angle < 1e-5, "{node:?}");
        assert_eq!(node.sphere.center, p);
        // The same two rays the other way round: the second origin is ahead, on the axis.
        let (node, _) = node_cone(&rays, &[1, 0], s, c);
        assert!(node.cone.half_angle < 1e-5, "{node:?}");
    }

    #[test]
    fn same_cones_for_any_thread_count() {
        let rays: Vec<Ray> = ["coherent", "random"]
            .iter()
            .enumerate()
            .flat_map(|(i, n)| soup(300 + i as u64, n))
            .map(|mut r| {
                r.pixel %= W * H;
                r
            })
            .collect();
        let params = TileConeParams::new(8, 0.1).unwrap();
        let grid = TileGrid::new(frame(), 8).unwrap();
        let order = tile_order(&rays, &grid);
        let one = with_threads(1, || build_nodes(&rays, &order, frame(), &params))
            .unwrap()
            .unwrap();
        let two = with_threads(2, || build_nodes(&rays, &order, frame(), &params))
            .unwrap()
            .unwrap();
        let bits = |c: &TileCones| -> Vec<u32> {
            c.nodes
                .iter()
                .flat_map(|n| {
                    let (s, k) = (n.sphere, n.cone);
                    [
                        s.center.x,
                        s.center.y,
                        s.center.z,
                        s.radius,
                        k.axis.x,
                        k.axis.y,
                        k.axis.z,
                        k.half_angle,
                    ]
                })
                .chain(c.reach.iter().copied())
                .map(f32::to_bits)
                .collect()
        };
        assert_eq!(one.offsets, two.offsets);
        assert_eq!(one.full, two.full);
        assert_eq!(bits(&one), bits(&two));
    }

    #[test]
    fn bad_input_and_params_are_errors() {
        let params = TileConeParams::default();
        let good = ray(RayKind::Reflection, 0, u32::MAX, Vec3::ZERO, Vec3::Z, 1.0);
        let outside = ray(
            RayKind::Reflection,
            W * H,
            u32::MAX,
            Vec3::ZERO,
            Vec3::Z,
            1.0,
        );
        let zero_dir = ray(
            RayKind::Reflection,
            1,
            u32::MAX,
            Vec3::ZERO,
            Vec3::ZERO,
            1.0,
        );
        for (rays, order) in [
            (vec![good, outside], vec![0u32, 1]),
            (vec![good, zero_dir], vec![0, 1]),
            (vec![good, good], vec![0, 0]),
            (vec![good, good], vec![0]),
            (vec![good], vec![1]),
        ] {
            let r = build_nodes(&rays, &order, frame(), &params);
            assert!(matches!(r, Err(CoreError::InvalidInput(_))), "{r:?}");
        }
        for (ts, deg) in [
            (0u32, 0.05),
            (4097, 0.05),
            (16, 0.0),
            (16, -1.0),
            (16, 10.5),
            (16, f64::NAN),
        ] {
            assert!(
                matches!(
                    TileConeParams::new(ts, deg),
                    Err(CoreError::InvalidParam { .. })
                ),
                "{ts} {deg}"
            );
        }
        assert!(TileConeParams::new(16, 10.0).is_ok());
        // The resolved spec: the catalogue's defaults.
        let mut spec = StageSpec::new("tile_cone");
        for p in info().params {
            spec.params.insert(p.name.to_string(), p.default);
        }
        let b = TileConeBuilder::new(frame(), &spec).unwrap();
        assert_eq!(*b.params(), TileConeParams::default());
        spec.params
            .insert("min_half_angle_deg".into(), ParamValue::Float(0.0));
        assert!(TileConeBuilder::new(frame(), &spec).is_err());
        assert_eq!(GUARD_SCALE, 1.00001f32);
    }

    #[test]
    fn the_builder_stores_one_level_with_offsets() {
        let rays = soup(400, "coherent");
        let grid = TileGrid::new(frame(), 16).unwrap();
        let order = tile_order(&rays, &grid);
        let b = TileConeBuilder::with_params(frame(), TileConeParams::default());
        let h = b
            .build(&Cpu, &rays, order.clone(), &mut Stats::default())
            .unwrap();
        let cones = build_nodes(&rays, &order, frame(), &TileConeParams::default()).unwrap();
        assert_eq!(h.order, order);
        assert_eq!(h.levels, vec![cones.nodes.clone()]);
        assert_eq!(h.leaf_offsets.as_ref(), Some(&cones.offsets));
        assert_eq!(h.reach, vec![cones.reach.clone()]);
        assert_eq!(h.subdivision, 256);
        assert_eq!(h.levels[0].len(), 7 * 3);
        crsh_core::check_leaf_offsets(
            h.leaf_offsets.as_ref().unwrap(),
            h.levels[0].len(),
            rays.len(),
        )
        .unwrap();
    }
}
