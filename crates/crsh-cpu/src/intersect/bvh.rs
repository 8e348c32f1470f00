//! `bvh`: an object-space compressed wide BVH (obvhs CWBVH, 8-wide) over the scene's triangles.
//!
//! The BVH is built once, when the stage is constructed ([`CwBvh::new`]), with obvhs's PLOC
//! builder and the preset chosen by `build_quality`. Leaf primitives are stored in leaf order
//! (triangles prepared for the configured ray-triangle test, indexed by the BVH's primitive
//! slot, plus each slot's scene triangle id), so a leaf test reads consecutive memory. Degenerate triangles (never hit, see
//! [`crate::triangle`]) are left out of the tree.
//!
//! # Identical to brute force
//!
//! Primitive tests use the ray-triangle test of parameter `test` (`mt`, `watertight`,
//! `projected`: [`crate::triangle`]), the same code brute force runs, on scene triangle ids,
//! merged with [`Hit::closer_than`]; the node test culls only boxes that cannot hold a hit that
//! could still win, so closest hits (triangle, `t`, `u`, `v`) are the brute-force ones (with the
//! same test) bit for bit, ties included:
//!
//! - obvhs's own node test clamps the entry distance to a fixed `1e-4` (ignoring the ray's
//!   `t_min`), maps zero direction components to `±1/f32::EPSILON` and rounds without margin;
//!   it can therefore drop hits close to the origin or on boxes touched at grazing angles. The
//!   node test here ([`child_hits`]) uses the ray's own interval, keeps zero components
//!   (clamped to `±1e-25`, a perturbation of `1e-25·t`) and widens every slab by a bound on
//!   the rounding of the quantized-plane arithmetic (`1e-6·(255·|E/d| + |(p - o)/d|)` per axis:
//!   the terms the computation adds, so the bound holds whatever the cancellation), and the
//!   distance interval by a relative `1e-5` for the rounding of the triangle test's `t`.
//! - The culling distance is `min(t_max, best.t)` and the comparison inclusive, so a
//!   triangle at exactly the best `t` with a lower id is still reached.
//! - The node test is geometric: a hit whose computed `t` puts it outside its triangle's box
//!   is culled. Real hits never are (the slack bounds the rounding of Möller-Trumbore's and the
//!   watertight test's `t`), but spurious self-hits can be: a ray leaving a surface with a tiny
//!   `t_min` (`raygen.offset=fixed`) can "hit" its own triangle at a `t` of pure rounding noise,
//!   and the projected test's `t = (d − n·o)/(n·dir)` cancels far from the origin by much more
//!   than the slack. There `bvh` reports fewer self-intersections than `brute` with the same
//!   test (`crsh stress`: `stadium/teapot` with `fixed`, 0 against 1; `far/plane-1e7` with
//!   `projected`, 577 against 592), and nothing else differs.
//! - The `slow` and `very_slow` presets (`BvhBuildParams::slow_build`, `very_slow_build`)
//!   are used without their spatial pre-splits:
//!   their clipped boxes are computed in floating point and are not guaranteed to contain
//!   their triangle fragments, which would break the guarantee above. Everything else of the
//!   preset (PLOC search distance, reinsertion, sort precision) is kept.
//!
//! With `exact = false` the same tree is traced with obvhs's own node and triangle tests
//! instead (module `stock`): what obvhs called directly returns, uncounted, so that every
//! ablation cell can set it beside the exact `bvh` and Embree.
//!
//! # Moving geometry (`update`)
//!
//! For a dynamic scene the pipeline is rebuilt every frame ([`crsh_core::Registry::rebuild`]).
//! With `update = "rebuild"` (the default) the BVH is built anew with `build_quality`. With
//! `update = "refit"` the binary tree obvhs builds before compressing it to 8-wide nodes
//! (`Bvh2`) is kept; the next frame recomputes its leaf boxes from the moved triangles,
//! refits the inner boxes bottom-up (`Bvh2::refit_all`) and compresses it again
//! (`bvh2_to_cwbvh`: obvhs has no in-place refit of the compressed layout). The topology stays
//! that of the frame it was built for, so traversal degrades as the geometry moves away from
//! it (Wald, Boulos and Shirley 2007); hits do not (the boxes bound the moved triangles). When
//! the set of triangles the test can hit changes (one becomes degenerate or stops being), the
//! kept tree does not hold the right primitives and the BVH is built anew instead.
//!
//! # Counting
//!
//! - `stats.add_bounds`: one per non-empty child box tested (each node visited tests all its
//!   children at once).
//! - `stats.add_ray_triangle`: one per leaf primitive tested.
//! - `stats.add_visits(inner, leaves)` (seed 001's "visited internal nodes / visited leaves"
//!   per ray): `inner` counts the nodes visited, i.e. the nodes whose children's boxes are
//!   tested (every run of the `traverse!` node block; the root is visited by every ray traced,
//!   so `inner >= 1` per ray on a non-empty tree). `leaves` counts the leaf children (CWBVH
//!   primitive clusters of 1 to 3 triangles: a non-empty `child_meta` whose `imask` bit is
//!   clear) whose primitives get tested: a cluster is counted when its first primitive is
//!   tested, so `leaves <= ray_triangle`, and a cluster left untested because an any-hit ray
//!   stopped first is not counted. A leaf is not a node of its own here: its box is one of
//!   its parent's child boxes, so a leaf visit adds no `bounds` test.
//!
//! Any-hit rays stop at the first hit found (traversal order), so their counts are the tests
//! done. Rays whose stored hit is already a hit are skipped in any-hit mode (nothing counted),
//! and so are rays with an empty interval (`t_min ≥ t_max`: seed 001's rays whose origin
//! offset passed their end "terminate in the root node"; here they do not even visit it).
//!
//! # Edge-width queries
//!
//! [`HitMode::EdgeWidth`] (seed 003 §5, eq. 5.1; seed 003's "future work": edge width on a
//! BVH): a BVH visits leaves in no order along the ray, so the segment's crossings are
//! gathered by a traversal without best-`t` culling (every box the segment `(t_min, t_max)`
//! overlaps), then sorted and paired by [`crsh_core::edge_width`] with the radius of the
//! ray's light. Each triangle is in one leaf (no spatial splits), so every crossing is found
//! once and the answer is brute force's bit for bit. `bvh2` does not answer it
//! ([`CoreError::Unsupported`]).
//!
//! Rays are traced in parallel with rayon, each independently, so results and counts do not
//! depend on the thread count. [`Query::Candidates`] is not supported (a BVH tests the whole
//! scene): it returns [`CoreError::Unsupported`].

use std::sync::Arc;
use std::time::Duration;

use crsh_core::edge_width::{Crossing, EdgePairing, EdgeWidthLights};
use crsh_core::glam::{UVec2, Vec3, Vec3A};
use crsh_core::{
    CoreError, Hit, HitMode, Intersector, ParamInfo, Query, Ray, Registry, Result, StageContext,
    StageKind, StageSpec, StageVariantInfo, Stats,
};
use crsh_scene::Scene;
use obvhs::bvh2::reinsertion::ReinsertionOptimizer;
use obvhs::bvh2::Bvh2;
use obvhs::cwbvh::bvh2_to_cwbvh::bvh2_to_cwbvh;
use obvhs::cwbvh::node::CwBvhNode;
use obvhs::ploc::PlocBuilder;
use obvhs::triangle::Triangle;
use obvhs::BvhBuildParams;
use rayon::prelude::*;

use crate::backend::Cpu;
use crate::intersect::brute::{check_batch, test_kind};
use crate::triangle::{MollerTrumbore, Projected, TestKind, TriangleSet, TriangleTest, Watertight};

/// Rays per rayon task.
pub(crate) const CHUNK: usize = 64;

/// Relative slab widening for the rounding of the node test (see the module doc).
pub(crate) const SLAB_SLACK: f32 = 1e-6;

/// Relative widening of the node test's distance interval (rounding of the triangle's `t`).
pub(crate) const T_SLACK: f32 = 1e-5;

/// Smallest direction component magnitude used in the node test.
pub(crate) const MIN_DIR: f32 = 1e-25;

/// BVH build presets (`build_quality`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BuildQuality {
    /// `BvhBuildParams::fast_build`.
    Fast,
    /// `BvhBuildParams::medium_build` (the default).
    Medium,
    /// `BvhBuildParams::slow_build` without spatial pre-splits (see the module doc).
    Slow,
    /// `BvhBuildParams::very_slow_build` (full reinsertion, 128-bit Morton sort, leaves of
    /// up to 8 before collapsing) without spatial pre-splits.
    VerySlow,
}

impl BuildQuality {
    /// The names accepted by `build_quality`.
    pub const NAMES: [&'static str; 4] = ["fast", "medium", "slow", "very_slow"];

    /// The preset called `name`.
    pub fn from_name(name: &str) -> Option<BuildQuality> {
        match name {
            "fast" => Some(BuildQuality::Fast),
            "medium" => Some(BuildQuality::Medium),
            "slow" => Some(BuildQuality::Slow),
            "very_slow" => Some(BuildQuality::VerySlow),
            _ => None,
        }
    }

    /// The obvhs build parameters.
    pub fn params(self) -> BvhBuildParams {
        match self {
            BuildQuality::Fast => BvhBuildParams::fast_build(),
            BuildQuality::Medium => BvhBuildParams::medium_build(),
            BuildQuality::Slow => BvhBuildParams {
                pre_split: false,
                ..BvhBuildParams::slow_build()
            },
            BuildQuality::VerySlow => BvhBuildParams {
                pre_split: false,
                ..BvhBuildParams::very_slow_build()
            },
        }
    }
}

/// The CWBVH intersector (variant `bvh`).
pub struct CwBvh {
    bvh: obvhs::cwbvh::CwBvh,
    /// Prepared triangle and scene triangle id per BVH primitive slot.
    leaves: Leaves,
    quality: BuildQuality,
    build_time: Duration,
    /// The binary tree and its primitives' scene ids, kept for the next frame's refit
    /// (`update = "refit"`); taken by the refit that uses it.
    refit: Option<Box<std::sync::Mutex<Option<RefitState>>>>,
    /// obvhs's triangles per primitive slot when the tree is traced with obvhs's own tests
    /// (`exact = false`, `bvh::stock`); `None` for the exact traversal.
    stock: Option<Vec<Triangle>>,
}

/// What a refit of the next frame needs: the binary tree before compression and the scene
/// triangle id of each of its primitives.
struct RefitState {
    bvh2: Bvh2,
    ids: Vec<u32>,
}

/// The leaf triangles prepared for one ray-triangle test (matched once per query).
#[derive(Clone, Debug)]
pub(crate) enum LeafTriangles {
    MollerTrumbore(Vec<<MollerTrumbore as TriangleTest>::Tri>),
    Watertight(Vec<<Watertight as TriangleTest>::Tri>),
    Projected(Vec<<Projected as TriangleTest>::Tri>),
}

/// A tree's primitives in slot (leaf) order: each slot's triangle prepared for the configured
/// test, and its scene triangle id.
#[derive(Clone, Debug)]
pub(crate) struct Leaves {
    pub tris: LeafTriangles,
    pub ids: Vec<u32>,
    /// The scene lights' radii (the `R` of edge-width queries) and shared vertices.
    pub lights: EdgeWidthLights,
}

impl Leaves {
    /// The scene triangles `ids` (in slot order) of `scene`, prepared for `test`.
    pub fn new(scene: &Scene, ids: Vec<u32>, test: TestKind) -> Leaves {
        fn prepare<T: TriangleTest>(scene: &Scene, ids: &[u32]) -> Vec<T::Tri> {
            TriangleSet::<T>::from_triangles(ids.iter().map(|&t| scene.triangle(t as usize)))
                .triangles()
                .to_vec()
        }
        let tris = match test {
            TestKind::MollerTrumbore => {
                LeafTriangles::MollerTrumbore(prepare::<MollerTrumbore>(scene, &ids))
            }
            TestKind::Watertight => LeafTriangles::Watertight(prepare::<Watertight>(scene, &ids)),
            TestKind::Projected => LeafTriangles::Projected(prepare::<Projected>(scene, &ids)),
        };
        Leaves {
            tris,
            ids,
            lights: crate::intersect::brute::edge_width_lights(scene),
        }
    }

    /// The ray-triangle test the triangles are prepared for.
    pub fn test(&self) -> TestKind {
        match self.tris {
            LeafTriangles::MollerTrumbore(_) => TestKind::MollerTrumbore,
            LeafTriangles::Watertight(_) => TestKind::Watertight,
            LeafTriangles::Projected(_) => TestKind::Projected,
        }
    }
}

impl std::fmt::Debug for CwBvh {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CwBvh")
            .field("nodes", &self.bvh.nodes.len())
            .field("primitives", &self.leaves.ids.len())
            .field("quality", &self.quality)
            .field("test", &self.test())
            .field("exact", &self.exact())
            .field("build_time", &self.build_time)
            .finish()
    }
}

/// The catalogue entry of the `bvh` intersector.
pub fn info() -> StageVariantInfo {
    StageVariantInfo::new(
        StageKind::Intersect,
        "bvh",
        "obvhs compressed-wide BVH (CWBVH), closest and any hit, node and triangle tests \
         counted; whole-scene queries only",
    )
    .param(quality_param())
    .param(update_param(
        "per frame of a moving scene: build anew with `build_quality`, or refit the boxes of \
         the first frame's tree (obvhs `Bvh2::refit_all`, then re-compression to 8-wide nodes)",
    ))
    .param(test_param())
    .param(ParamInfo::bool(
        "exact",
        true,
        "`true`: brute force's hits bit for bit, every test counted (the node test keeps the \
         ray's interval and a rounding margin); `false`: obvhs's own node and triangle tests \
         as obvhs ships them (the anchor of obvhs called directly), nothing counted, hits \
         compared by the accuracy report; edge-width queries are always exact",
    ))
    .scene_only()
}

/// Parameter `build_quality` of the obvhs intersectors.
pub(crate) fn quality_param() -> ParamInfo {
    ParamInfo::choice(
        "build_quality",
        "medium",
        &BuildQuality::NAMES,
        "obvhs build preset: faster builds or better trees",
    )
}

/// Parameter `update` (`rebuild` | `refit`) of the obvhs intersectors, documented by `doc`.
pub(crate) fn update_param(doc: &'static str) -> ParamInfo {
    ParamInfo::choice("update", "rebuild", &["rebuild", "refit"], doc)
}

/// Parameter `test` (the ray-triangle test) of the obvhs intersectors.
pub(crate) fn test_param() -> ParamInfo {
    ParamInfo::choice(
        "test",
        "mt",
        crate::triangle::TEST_NAMES,
        "ray-triangle test: `mt` Möller-Trumbore (f32), `watertight` Woop, Benthin and Wald \
         2013 (no ray slips through shared edges), `projected` RTTest's projected \
         barycentrics (seed 003 §4.2)",
    )
}

/// The parameters [`quality_param`], [`update_param`] (whether to refit) and [`test_param`]
/// of `spec`, for intersector `variant`.
pub(crate) fn build_params(
    spec: &StageSpec,
    variant: &str,
) -> Result<(BuildQuality, bool, TestKind)> {
    let name = spec.str("build_quality")?;
    let quality = BuildQuality::from_name(name).ok_or_else(|| CoreError::InvalidParam {
        key: format!("{variant}.build_quality"),
        reason: format!("`{name}` is not one of {}", BuildQuality::NAMES.join(", ")),
    })?;
    let refit = match spec.str("update")? {
        "rebuild" => false,
        "refit" => true,
        other => {
            return Err(CoreError::InvalidParam {
                key: format!("{variant}.update"),
                reason: format!("`{other}` is not one of rebuild, refit"),
            })
        }
    };
    Ok((quality, refit, test_kind(spec, variant)?))
}

/// Registers `bvh` ([`info`], [`CwBvh::new`]).
pub fn register(registry: &mut Registry<Cpu>) -> Result<()> {
    registry.add_intersector(info(), |ctx, spec| {
        Ok(Box::new(CwBvh::new(ctx.scene, spec)?))
    })?;
    Ok(())
}

/// The scene ids of the triangles test `test` can hit (degenerate ones stay out of the tree)
/// and those triangles in obvhs's form.
pub(crate) fn hittable_triangles(scene: &Scene, test: TestKind) -> (Vec<u32>, Vec<Triangle>) {
    fn hittable<T: TriangleTest>(tri: [Vec3; 3]) -> bool {
        !T::is_degenerate(&T::prepare(tri[0], tri[1], tri[2]))
    }
    let keep = match test {
        TestKind::MollerTrumbore => hittable::<MollerTrumbore>,
        TestKind::Watertight => hittable::<Watertight>,
        TestKind::Projected => hittable::<Projected>,
    };
    (0..scene.triangle_count())
        .into_par_iter()
        .filter_map(|t| {
            let tri = scene.triangle(t);
            keep(tri).then(|| (t as u32, obvhs_triangle(tri)))
        })
        .unzip()
}

/// A scene triangle as obvhs's `Triangle`.
pub(crate) fn obvhs_triangle([a, b, c]: [Vec3; 3]) -> Triangle {
    Triangle {
        v0: a.into(),
        v1: b.into(),
        v2: c.into(),
    }
}

/// obvhs's binary tree over `tris` (not empty) with the preset `params`: PLOC, then
/// reinsertion (what obvhs's CWBVH builder does before compressing, without pre-splits).
pub(crate) fn build_bvh2(tris: &[Triangle], params: &BvhBuildParams) -> Bvh2 {
    let mut bvh2 = PlocBuilder::with_capacity(tris.len()).build(
        params.ploc_search_distance,
        tris,
        (0..tris.len() as u32).collect::<Vec<_>>(),
        params.sort_precision,
        params.search_depth_threshold,
    );
    ReinsertionOptimizer::default().run(&mut bvh2, params.reinsertion_batch_ratio, None);
    bvh2
}

/// obvhs's compressed 8-wide layout of `bvh2` (built with `quality`'s parameters), leaves of
/// `quality`'s size clamped to the 1 to 3 primitives the layout holds, children ordered: the
/// tree `bvh` traverses, and `dual`'s wide ray nodes.
pub(crate) fn compress_bvh2(bvh2: &Bvh2, quality: BuildQuality) -> obvhs::cwbvh::CwBvh {
    bvh2_to_cwbvh(
        bvh2,
        quality.params().max_prims_per_leaf.clamp(1, 3),
        true,
        false,
    )
}

/// Refits `bvh2` to the moved triangles `tris` (indexed by its primitive indices): each
/// leaf's box recomputed from its triangles, then the inner boxes bottom-up.
pub(crate) fn refit_bvh2(bvh2: &mut Bvh2, tris: &[Triangle]) {
    let prims = &bvh2.primitive_indices;
    bvh2.nodes.par_iter_mut().for_each(|node| {
        if node.is_leaf() {
            let first = node.first_index as usize;
            let count = node.prim_count as usize;
            let aabb = prims[first..first + count]
                .iter()
                .map(|&p| tris[p as usize].aabb())
                .reduce(|a, b| a.union(&b))
                .unwrap_or_else(|| *node.aabb());
            node.set_aabb(aabb);
        }
    });
    bvh2.refit_all();
}

impl CwBvh {
    /// Builds the BVH of `scene` with `spec.build_quality` (`fast` | `medium` | `slow`), its
    /// leaves prepared for `spec.test` (`mt` | `watertight` | `projected`).
    /// With `spec.exact = false` it traces with obvhs's own tests (`bvh::stock`).
    pub fn new(scene: &Arc<Scene>, spec: &StageSpec) -> Result<CwBvh, CoreError> {
        let (quality, refit, test) = build_params(spec, "bvh")?;
        let mut bvh = CwBvh::build_with_test(scene, quality, test);
        if !refit {
            bvh.refit = None;
        }
        if !spec.bool("exact")? {
            bvh.stock = Some(bvh.stock_triangles(scene));
        }
        Ok(bvh)
    }

    /// obvhs's form of each primitive slot's triangle, for `bvh::stock`.
    fn stock_triangles(&self, scene: &Scene) -> Vec<Triangle> {
        self.leaves
            .ids
            .iter()
            .map(|&t| obvhs_triangle(scene.triangle(t as usize)))
            .collect()
    }

    /// Whether hits are brute force's (`exact = true`) rather than obvhs's own (`bvh::stock`).
    pub fn exact(&self) -> bool {
        self.stock.is_none()
    }

    /// The BVH of `scene` (the same triangles as the one this was built for, moved) from this
    /// one's kept binary tree: leaf boxes recomputed, inner boxes refitted, the tree compressed
    /// again. `None` when nothing was kept (`update = "rebuild"`, or already refitted from) or
    /// the triangles the test can hit are not the same set.
    pub fn refitted(&self, scene: &Scene) -> Option<CwBvh> {
        let state = self.refit.as_ref()?.lock().ok()?.take()?;
        let RefitState { mut bvh2, ids } = state;
        let test = self.test();
        let (current, tris) = hittable_triangles(scene, test);
        if current != ids {
            return None;
        }
        let t0 = std::time::Instant::now();
        refit_bvh2(&mut bvh2, &tris);
        let bvh = compress_bvh2(&bvh2, self.quality);
        let build_time = t0.elapsed();
        let mut out = CwBvh::assemble(scene, bvh, &current, test, self.quality, build_time);
        out.refit = Some(Box::new(std::sync::Mutex::new(Some(RefitState {
            bvh2,
            ids,
        }))));
        if !self.exact() {
            out.stock = Some(out.stock_triangles(scene));
        }
        Some(out)
    }

    /// Builds the BVH of `scene` with the given preset, for Möller-Trumbore.
    pub fn build(scene: &Scene, quality: BuildQuality) -> CwBvh {
        CwBvh::build_with_test(scene, quality, TestKind::MollerTrumbore)
    }

    /// Builds the BVH of `scene` with the given preset, its leaves prepared for test `test`.
    pub fn build_with_test(scene: &Scene, quality: BuildQuality, test: TestKind) -> CwBvh {
        let (ids, tris) = hittable_triangles(scene, test);
        let mut build_time = Duration::ZERO;
        let (bvh, bvh2) = if tris.is_empty() {
            (obvhs::cwbvh::CwBvh::default(), None)
        } else {
            // What obvhs's `build_cwbvh_from_tris` does without pre-splits (never used here,
            // see the module doc), keeping the binary tree for a refit.
            let params = quality.params();
            let t0 = std::time::Instant::now();
            let bvh2 = build_bvh2(&tris, &params);
            let bvh = compress_bvh2(&bvh2, quality);
            build_time = t0.elapsed();
            (bvh, Some(bvh2))
        };
        let mut out = CwBvh::assemble(scene, bvh, &ids, test, quality, build_time);
        out.refit =
            bvh2.map(|bvh2| Box::new(std::sync::Mutex::new(Some(RefitState { bvh2, ids }))));
        out
    }

    /// The intersector of the compressed tree `bvh` over the triangles `ids` of `scene`.
    fn assemble(
        scene: &Scene,
        bvh: obvhs::cwbvh::CwBvh,
        ids: &[u32],
        test: TestKind,
        quality: BuildQuality,
        build_time: Duration,
    ) -> CwBvh {
        let leaf_ids: Vec<u32> = bvh
            .primitive_indices
            .iter()
            .map(|&i| ids[i as usize])
            .collect();
        CwBvh {
            bvh,
            leaves: Leaves::new(scene, leaf_ids, test),
            quality,
            build_time,
            refit: None,
            stock: None,
        }
    }

    /// The build preset used.
    pub fn quality(&self) -> BuildQuality {
        self.quality
    }

    /// The ray-triangle test of the leaves.
    pub fn test(&self) -> TestKind {
        self.leaves.test()
    }

    /// The CWBVH nodes (obvhs's `Pod` layout, 80 bytes each; the GPU twin uploads them).
    pub fn nodes(&self) -> &[CwBvhNode] {
        &self.bvh.nodes
    }

    /// Scene triangle id per BVH primitive slot.
    pub fn leaf_ids(&self) -> &[u32] {
        &self.leaves.ids
    }

    /// The leaf triangles prepared for Möller-Trumbore, per primitive slot (`None` when the
    /// BVH was built for another test).
    pub fn leaf_triangles_mt(&self) -> Option<&[crate::triangle::PreparedTriangle]> {
        match &self.leaves.tris {
            LeafTriangles::MollerTrumbore(t) => Some(t),
            _ => None,
        }
    }

    /// Number of BVH nodes.
    pub fn node_count(&self) -> usize {
        self.bvh.nodes.len()
    }

    /// Core build time as obvhs measured it.
    pub fn build_time(&self) -> Duration {
        self.build_time
    }
}

impl LeafTracer for CwBvh {
    type Scratch = ();
    const EDGE_WIDTH: bool = true;

    fn gather<T: TriangleTest>(
        &self,
        leaf_tris: &[T::Tri],
        ray: &Ray,
        out: &mut Vec<Crossing>,
        _: &mut (),
    ) -> Counts {
        let mut n = Counts::default();
        if self.bvh.nodes.is_empty() {
            return n;
        }
        // Every crossing of the segment, so no best hit culls: a closest-hit start from a miss.
        let Some((r, nr, t_lo, t_hi)) = start_trace::<T>(ray, HitMode::Closest, &Hit::MISS) else {
            return n;
        };
        let bvh = &self.bvh;
        let mut state = bvh.new_traversal(Vec3A::from(ray.dir));
        let mut node: &CwBvhNode;
        obvhs::traverse!(
            bvh,
            node,
            state,
            {
                let (mask, hit) = child_test(node, &nr, state.oct_inv4, t_lo, t_hi);
                n.visit(node, hit);
                mask
            },
            {
                let slot = state.primitive_id as usize;
                n.prims += 1;
                let id = self.leaves.ids[slot];
                if let Some(h) = T::hit(&leaf_tris[slot], &r, ray.t_min, ray.t_max, id) {
                    out.push(Crossing { t: h.t, tri: id });
                }
            }
        );
        n
    }

    fn leaves(&self) -> &Leaves {
        &self.leaves
    }

    fn trace_uncounted(&self, rays: &[Ray], mode: HitMode, hits: &mut [Hit]) -> bool {
        let Some(tris) = &self.stock else {
            return false;
        };
        let ids = &self.leaves.ids;
        rays.par_chunks(CHUNK)
            .zip(hits.par_chunks_mut(CHUNK))
            .for_each(|(rs, hs)| {
                for (ray, h) in rs.iter().zip(hs) {
                    stock::trace(&self.bvh, tris, ids, ray, mode, h);
                }
            });
        true
    }

    #[inline]
    fn trace<T: TriangleTest>(
        &self,
        leaf_tris: &[T::Tri],
        ray: &Ray,
        mode: HitMode,
        best: &mut Hit,
        _: &mut (),
    ) -> Counts {
        let ids = &self.leaves.ids;
        trace_cwbvh::<T, false>(
            &self.bvh,
            |slot| (&leaf_tris[slot], ids[slot]),
            ray,
            mode,
            best,
        )
    }
}

/// What a single-ray traversal of test `T` starts from: the ray in `T`'s form, its node-test
/// form and the node test's interval `(t_lo, t_hi)` (`t_hi` at the best hit so far); `None`
/// when there is nothing to trace (any hit: `best` is already a hit; an empty interval, a ray
/// whose origin offset passed its end, seed 001, which can hit nothing).
#[inline]
pub(crate) fn start_trace<T: TriangleTest>(
    ray: &Ray,
    mode: HitMode,
    best: &Hit,
) -> Option<(T::Ray, NodeRay, f32, f32)> {
    if crate::intersect::nothing_to_trace(ray, mode, best) {
        return None;
    }
    Some((
        T::ray_of(ray),
        NodeRay::new(ray.origin, ray.dir),
        entry_bound(ray.t_min),
        cull_distance(ray.t_max.min(best.t)),
    ))
}

/// Traces `ray` through the compressed tree `bvh` with test `T`, merging into `best` as
/// [`LeafTracer::trace`] does (any hit: skipped when `best` is a hit, stops at the first hit;
/// an empty interval visits nothing); `leaf(slot)` is the triangle of primitive slot `slot`,
/// prepared for `T`, and its scene id. The node test is [`child_hits`], so the hits are brute
/// force's (module doc, "Identical to brute force"). `bvh`'s own [`CwBvh::trace`] and
/// `dual`'s wide ray nodes (which read the triangles by scene id) share it. With `TALLY` the
/// counts include [`Counts::bounds_passed`] and [`Counts::prims_hit`] (left 0 otherwise:
/// `bvh` does not report them, and its traversal need not count them).
#[inline]
pub(crate) fn trace_cwbvh<'t, T: TriangleTest + 't, const TALLY: bool>(
    bvh: &obvhs::cwbvh::CwBvh,
    leaf: impl Fn(usize) -> (&'t T::Tri, u32),
    ray: &Ray,
    mode: HitMode,
    best: &mut Hit,
) -> Counts {
    let mut n = Counts::default();
    if bvh.nodes.is_empty() {
        return n;
    }
    let Some((r, nr, t_lo, mut t_hi)) = start_trace::<T>(ray, mode, best) else {
        return n;
    };
    let mut state = bvh.new_traversal(Vec3A::from(ray.dir));
    // The node whose primitive group is being tested (the root until `traverse!` assigns it).
    let mut node: &CwBvhNode = &bvh.nodes[0];
    'trace: {
        obvhs::traverse!(
            bvh,
            node,
            state,
            {
                let (mask, hit) = child_test(node, &nr, state.oct_inv4, t_lo, t_hi);
                n.visit(node, hit);
                if TALLY {
                    n.bounds_passed += u64::from(mask.count_ones());
                }
                mask
            },
            {
                let slot = state.primitive_id as usize;
                n.prims += 1;
                let (tri, id) = leaf(slot);
                if let Some(h) = T::hit(tri, &r, ray.t_min, ray.t_max, id) {
                    if TALLY {
                        n.prims_hit += 1;
                    }
                    if mode == HitMode::Any {
                        *best = h;
                        n.stop(node, state.primitive_group.y);
                        break 'trace;
                    }
                    if h.closer_than(best) {
                        *best = h;
                        t_hi = cull_distance(ray.t_max.min(best.t));
                    }
                }
            }
        );
    }
    n
}

/// An object hierarchy over [`Leaves`] that traces one ray at a time: what
/// [`intersect_scene`] needs of `bvh` and `bvh2`.
pub(crate) trait LeafTracer: Sync {
    /// Per-task scratch space (a traversal stack), reused by the rays of a rayon task.
    type Scratch: Default;

    /// Whether [`LeafTracer::gather`] is implemented (edge-width queries are answered).
    const EDGE_WIDTH: bool = false;

    /// Appends to `out` every crossing of `ray`'s segment `(t_min, t_max)` with test `T`
    /// (each once, any order), for [`HitMode::EdgeWidth`]; returns its counts. Only called
    /// when [`LeafTracer::EDGE_WIDTH`] is set.
    fn gather<T: TriangleTest>(
        &self,
        leaf_tris: &[T::Tri],
        ray: &Ray,
        out: &mut Vec<Crossing>,
        scratch: &mut Self::Scratch,
    ) -> Counts {
        let _ = (leaf_tris, ray, out, scratch);
        Counts::default()
    }

    /// The tree's primitives.
    fn leaves(&self) -> &Leaves;

    /// Traces the whole-scene batch `rays` (any or closest hit) its own uncounted way when the
    /// tree is set to (`bvh.exact = false`, `bvh::stock`), returning `true`; `false` (the
    /// default) leaves the batch to [`LeafTracer::trace`].
    fn trace_uncounted(&self, rays: &[Ray], mode: HitMode, hits: &mut [Hit]) -> bool {
        let _ = (rays, mode, hits);
        false
    }

    /// Traces `ray` with test `T` on `leaf_tris` (this tree's leaves, prepared for `T`),
    /// merging into `best` (any hit: skipped when `best` is a hit, stops at the first hit);
    /// returns its counts.
    fn trace<T: TriangleTest>(
        &self,
        leaf_tris: &[T::Tri],
        ray: &Ray,
        mode: HitMode,
        best: &mut Hit,
        scratch: &mut Self::Scratch,
    ) -> Counts;
}

/// [`Intersector::intersect`] of the tree `x` (variant `variant`): whole-scene queries traced
/// ray by ray in parallel (each ray independently, so hits and counts do not depend on the
/// thread count), counts recorded in `stats`; candidate queries are unsupported.
pub(crate) fn intersect_scene<X: LeafTracer>(
    x: &X,
    variant: &str,
    rays: &[Ray],
    query: &Query<'_, Cpu>,
    mode: HitMode,
    hits: &mut [Hit],
    stats: &mut Stats,
) -> Result<()> {
    query.whole_scene_only(variant)?;
    check_batch(rays, hits)?;
    if mode.is_edge_width() {
        if !X::EDGE_WIDTH {
            return Err(mode.unsupported(variant));
        }
        x.leaves().lights.check(rays)?;
        let HitMode::EdgeWidth(pairing) = mode else {
            unreachable!("an edge-width mode")
        };
        fn edges<T: TriangleTest, X: LeafTracer>(
            x: &X,
            leaf_tris: &[T::Tri],
            rays: &[Ray],
            hits: &mut [Hit],
            pairing: EdgePairing,
        ) -> Counts {
            let lights = &x.leaves().lights;
            rays.par_chunks(CHUNK)
                .zip(hits.par_chunks_mut(CHUNK))
                .map(|(rs, hs)| {
                    let mut scratch = X::Scratch::default();
                    let mut crossings = Vec::new();
                    rs.iter()
                        .zip(hs.iter_mut())
                        .fold(Counts::default(), |n, (ray, h)| {
                            crossings.clear();
                            let c = x.gather::<T>(leaf_tris, ray, &mut crossings, &mut scratch);
                            *h = lights.hit(ray, pairing, &mut crossings);
                            n.add(c)
                        })
                })
                .reduce(Counts::default, Counts::add)
        }
        let counts = match &x.leaves().tris {
            LeafTriangles::MollerTrumbore(t) => {
                edges::<MollerTrumbore, X>(x, t, rays, hits, pairing)
            }
            LeafTriangles::Watertight(t) => edges::<Watertight, X>(x, t, rays, hits, pairing),
            LeafTriangles::Projected(t) => edges::<Projected, X>(x, t, rays, hits, pairing),
        };
        counts.record(stats);
        return Ok(());
    }
    if x.trace_uncounted(rays, mode, hits) {
        stats.mark_tests_uncounted();
        return Ok(());
    }
    fn all<T: TriangleTest, X: LeafTracer>(
        x: &X,
        leaf_tris: &[T::Tri],
        rays: &[Ray],
        mode: HitMode,
        hits: &mut [Hit],
    ) -> Counts {
        rays.par_chunks(CHUNK)
            .zip(hits.par_chunks_mut(CHUNK))
            .map(|(rs, hs)| {
                let mut scratch = X::Scratch::default();
                rs.iter()
                    .zip(hs.iter_mut())
                    .fold(Counts::default(), |n, (ray, h)| {
                        n.add(x.trace::<T>(leaf_tris, ray, mode, h, &mut scratch))
                    })
            })
            .reduce(Counts::default, Counts::add)
    }
    let counts = match &x.leaves().tris {
        LeafTriangles::MollerTrumbore(t) => all::<MollerTrumbore, X>(x, t, rays, mode, hits),
        LeafTriangles::Watertight(t) => all::<Watertight, X>(x, t, rays, mode, hits),
        LeafTriangles::Projected(t) => all::<Projected, X>(x, t, rays, mode, hits),
    };
    counts.record(stats);
    Ok(())
}

/// Bit `c` set for each non-empty child `c` of `node` (a non-zero `child_meta` byte), without
/// a loop: the high bit of each byte of `(meta & 0x7f..) + 0x7f.. | meta` says whether the
/// byte is non-zero, and the multiply gathers those eight bits into one byte.
#[inline(always)]
fn child_mask(node: &CwBvhNode) -> u32 {
    const LOW7: u64 = 0x7f7f_7f7f_7f7f_7f7f;
    let meta = u64::from_le_bytes(node.child_meta);
    let high = (((meta & LOW7) + LOW7) | meta) & !LOW7;
    ((high >> 7).wrapping_mul(0x0102_0408_1020_4080) >> 56) as u32
}

/// Bit `first + count - 1` (relative to the node's `primitive_base_idx`) for each leaf child
/// of `node` holding primitives `first .. first + count`: the primitive of that leaf that
/// `traverse!` tests first (it tests the hit mask's highest bit first). `children` is
/// [`child_mask`]`(node)`.
#[inline(always)]
fn leaf_top_bits(node: &CwBvhNode, children: u32) -> u32 {
    let mut leaves = children & !u32::from(node.imask);
    let mut tops = 0u32;
    while leaves != 0 {
        let m = node.child_meta[leaves.trailing_zeros() as usize];
        leaves &= leaves - 1;
        let first = u32::from(m & 0b1_1111);
        let count = (m >> 5).count_ones();
        tops |= 1 << (first + count - 1);
    }
    tops
}

/// The node test's near distance for a ray starting at `t_min` (widened for the rounding of
/// the triangle test's `t`).
#[inline(always)]
pub(crate) fn entry_bound(t_min: f32) -> f32 {
    t_min - t_min.abs() * T_SLACK
}

/// The node test's far distance for a best hit (or `t_max`) at `t`.
#[inline(always)]
pub(crate) fn cull_distance(t: f32) -> f32 {
    t + t.abs() * T_SLACK
}

/// Per-ray values of the node test.
#[derive(Clone, Copy, Debug)]
pub struct NodeRay {
    pub(crate) origin: Vec3A,
    pub(crate) inv_dir: Vec3A,
    pub(crate) negative: [bool; 3],
}

impl NodeRay {
    /// The node-test form of a ray: inverse direction with components clamped away from 0.
    pub fn new(origin: Vec3, dir: Vec3) -> NodeRay {
        let clamp = |d: f32| {
            if d.abs() < MIN_DIR {
                MIN_DIR.copysign(d)
            } else {
                d
            }
        };
        let d = Vec3A::new(clamp(dir.x), clamp(dir.y), clamp(dir.z));
        NodeRay {
            origin: origin.into(),
            inv_dir: Vec3A::ONE / d,
            negative: [d.x < 0.0, d.y < 0.0, d.z < 0.0],
        }
    }
}

/// The children of `node` whose (quantized, rounding-widened) boxes the ray overlaps within
/// `[t_lo, t_hi]`, as the CWBVH hit mask the `traverse!` macro expects.
///
/// On x86-64 four children at a time in SSE (what obvhs's own node test does), with the same
/// operations in the same order as the scalar form (`child_test_scalar`, one child at a time
/// in plain `f32`), so the mask is the same bit for bit; the scalar form runs off x86-64 and
/// where an operand could overflow (a plane term beyond `1e30`), where SSE's `min`/`max`
/// would treat a NaN differently.
#[inline(always)]
pub fn child_hits(node: &CwBvhNode, nr: &NodeRay, oct_inv4: u32, t_lo: f32, t_hi: f32) -> u32 {
    child_test(node, nr, oct_inv4, t_lo, t_hi).0
}

/// [`child_hits`] and the children that passed (bit `c` for child `c`, empty children
/// included), for the counters.
#[inline(always)]
pub(crate) fn child_test(
    node: &CwBvhNode,
    nr: &NodeRay,
    oct_inv4: u32,
    t_lo: f32,
    t_hi: f32,
) -> (u32, u32) {
    #[cfg(target_arch = "x86_64")]
    {
        let a = node.compute_extent() * nr.inv_dir;
        let orig = (Vec3A::from(node.p) - nr.origin) * nr.inv_dir;
        if a.abs().max(orig.abs()).cmplt(Vec3A::splat(1e30)).all() {
            // SAFETY: SSE and SSE2 are part of the x86-64 baseline.
            return unsafe { child_hits_sse(node, nr, a, orig, oct_inv4, t_lo, t_hi) };
        }
    }
    child_test_scalar(node, nr, oct_inv4, t_lo, t_hi)
}

/// [`child_test`] four children at a time; `a` and `orig` are its per-node plane terms.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn child_hits_sse(
    node: &CwBvhNode,
    nr: &NodeRay,
    a: Vec3A,
    orig: Vec3A,
    oct_inv4: u32,
    t_lo: f32,
    t_hi: f32,
) -> (u32, u32) {
    use std::arch::x86_64::*;
    let slack = (a.abs() * 255.0 + orig.abs()) * SLAB_SLACK;
    let lo = orig - slack;
    let hi = orig + slack;
    #[inline(always)]
    unsafe fn q(v: &[u8; 8], i: usize) -> __m128 {
        _mm_set_ps(
            *v.get_unchecked(i * 4 + 3) as f32,
            *v.get_unchecked(i * 4 + 2) as f32,
            *v.get_unchecked(i * 4 + 1) as f32,
            *v.get_unchecked(i * 4) as f32,
        )
    }
    let [neg_x, neg_y, neg_z] = nr.negative;
    let (ax, ay, az) = (_mm_set1_ps(a.x), _mm_set1_ps(a.y), _mm_set1_ps(a.z));
    let (lx, ly, lz) = (_mm_set1_ps(lo.x), _mm_set1_ps(lo.y), _mm_set1_ps(lo.z));
    let (hx, hy, hz) = (_mm_set1_ps(hi.x), _mm_set1_ps(hi.y), _mm_set1_ps(hi.z));
    let (tl, th) = (_mm_set1_ps(t_lo), _mm_set1_ps(t_hi));
    let (child_bits8, bit_index8) = node.get_child_and_index_bits(oct_inv4);
    let mut mask = 0u32;
    let mut passed = 0u32;
    for i in 0..2 {
        // Near and far planes per axis (swapped for a negative direction component), then
        // the scalar order: max(max(max(x, y), z), t_lo) and min(min(min(x, y), z), t_hi).
        let (min_x, max_x) = (q(&node.child_min_x, i), q(&node.child_max_x, i));
        let (near_x, far_x) = if neg_x {
            (max_x, min_x)
        } else {
            (min_x, max_x)
        };
        let (min_y, max_y) = (q(&node.child_min_y, i), q(&node.child_max_y, i));
        let (near_y, far_y) = if neg_y {
            (max_y, min_y)
        } else {
            (min_y, max_y)
        };
        let (min_z, max_z) = (q(&node.child_min_z, i), q(&node.child_max_z, i));
        let (near_z, far_z) = if neg_z {
            (max_z, min_z)
        } else {
            (min_z, max_z)
        };
        let t0 = _mm_max_ps(
            _mm_max_ps(
                _mm_max_ps(
                    _mm_add_ps(_mm_mul_ps(near_x, ax), lx),
                    _mm_add_ps(_mm_mul_ps(near_y, ay), ly),
                ),
                _mm_add_ps(_mm_mul_ps(near_z, az), lz),
            ),
            tl,
        );
        let t1 = _mm_min_ps(
            _mm_min_ps(
                _mm_min_ps(
                    _mm_add_ps(_mm_mul_ps(far_x, ax), hx),
                    _mm_add_ps(_mm_mul_ps(far_y, ay), hy),
                ),
                _mm_add_ps(_mm_mul_ps(far_z, az), hz),
            ),
            th,
        );
        let hits = _mm_movemask_ps(_mm_cmple_ps(t0, t1));
        passed |= (hits as u32) << (i * 4);
        for j in 0..4 {
            if hits & (1 << j) != 0 {
                let c = i * 4 + j;
                let child_bits = ((child_bits8 >> (c * 8)) & 0xff) as u32;
                let bit_index = ((bit_index8 >> (c * 8)) & 0xff) as u32;
                mask |= child_bits << bit_index;
            }
        }
    }
    (mask, passed)
}

/// The CWBVH hit mask of `node` for the children whose bit is set in `hits`.
#[inline(always)]
fn hit_mask(node: &CwBvhNode, oct_inv4: u32, mut hits: u32) -> u32 {
    let (child_bits8, bit_index8) = node.get_child_and_index_bits(oct_inv4);
    let mut mask = 0u32;
    while hits != 0 {
        let c = hits.trailing_zeros() as usize;
        hits &= hits - 1;
        let child_bits = ((child_bits8 >> (c * 8)) & 0xff) as u32;
        let bit_index = ((bit_index8 >> (c * 8)) & 0xff) as u32;
        mask |= child_bits << bit_index;
    }
    mask
}

/// [`child_test`] one child at a time, in plain `f32` arithmetic: the definition the SSE form
/// must match, and the form that runs off x86-64.
#[inline(always)]
fn child_test_scalar(
    node: &CwBvhNode,
    nr: &NodeRay,
    oct_inv4: u32,
    t_lo: f32,
    t_hi: f32,
) -> (u32, u32) {
    let e = node.compute_extent();
    let a = e * nr.inv_dir;
    let orig = (Vec3A::from(node.p) - nr.origin) * nr.inv_dir;
    let slack = (a.abs() * 255.0 + orig.abs()) * SLAB_SLACK;
    let lo = orig - slack;
    let hi = orig + slack;
    let pick =
        |neg: bool, min: &[u8; 8], max: &[u8; 8]| if neg { (*max, *min) } else { (*min, *max) };
    let (nx, fx) = pick(nr.negative[0], &node.child_min_x, &node.child_max_x);
    let (ny, fy) = pick(nr.negative[1], &node.child_min_y, &node.child_max_y);
    let (nz, fz) = pick(nr.negative[2], &node.child_min_z, &node.child_max_z);
    let mut hit = [false; 8];
    for c in 0..8 {
        let t0 = (nx[c] as f32 * a.x + lo.x)
            .max(ny[c] as f32 * a.y + lo.y)
            .max(nz[c] as f32 * a.z + lo.z)
            .max(t_lo);
        let t1 = (fx[c] as f32 * a.x + hi.x)
            .min(fy[c] as f32 * a.y + hi.y)
            .min(fz[c] as f32 * a.z + hi.z)
            .min(t_hi);
        hit[c] = t0 <= t1;
    }
    let hits = hit
        .iter()
        .enumerate()
        .fold(0u32, |m, (c, &h)| m | (u32::from(h) << c));
    (hit_mask(node, oct_inv4, hits), hits)
}

/// `impl Intersector<Cpu>` for the obvhs tree `$tree` (a [`LeafTracer`] with a method
/// `refitted(&self, &Scene) -> Option<$tree>`), variant `$name`: whole-scene queries through
/// [`intersect_scene`], per-frame refits through `refitted`, no candidate queries.
macro_rules! obvhs_intersector {
    ($tree:ty, $name:literal) => {
        impl Intersector<Cpu> for $tree {
            fn name(&self) -> &str {
                $name
            }

            fn refit(
                &self,
                ctx: &StageContext<'_, Cpu>,
            ) -> Option<Result<Box<dyn Intersector<Cpu>>>> {
                self.refitted(ctx.scene)
                    .map(|b| Ok(Box::new(b) as Box<dyn Intersector<Cpu>>))
            }

            fn supports_candidates(&self) -> bool {
                false
            }

            fn intersect(
                &self,
                _backend: &Cpu,
                rays: &Vec<Ray>,
                query: Query<'_, Cpu>,
                mode: HitMode,
                hits: &mut Vec<Hit>,
                stats: &mut Stats,
            ) -> Result<()> {
                $crate::intersect::bvh::intersect_scene(
                    self, $name, rays, &query, mode, hits, stats,
                )
            }
        }
    };
}
pub(crate) use obvhs_intersector;

obvhs_intersector!(CwBvh, "bvh");

mod counts;
mod stock;

pub(crate) use counts::Counts;

#[cfg(test)]
pub(crate) mod tests;
