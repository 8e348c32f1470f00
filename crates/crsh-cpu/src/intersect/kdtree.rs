//! `kdtree`: RTTest's kd-tree (seed 003 §2.2.1, §3.2.1) over the scene's triangles, rays
//! traced front to back one by one (listing 2.2 with its errata fixed,
//! [`crate::kdtree::trace_single`]) or together (parameter `traversal`: seed 003's 2×2 packets,
//! omni-directional packets, frusta, MFT and cones over rays that share an origin,
//! [`crate::kdtree::coherent`], their `N` and `I` in [`crsh_core::Stats::packets`]), and
//! edge-width soft-shadow queries ([`HitMode::EdgeWidth`], [`crate::kdtree::edge_width`]).
//!
//! # Build
//!
//! The tree is built once, when the stage is constructed ([`KdIntersector::new`], through
//! [`build_tree`]), over the triangles the configured ray-triangle test can hit (degenerate
//! ones are never hit and stay out), with
//!
//! - `build = "sah"` (the default): the SAH build with perfect splits of
//!   [`crate::kdtree::sah`] (eq. 2.1 with `c_trav` and `c_isect`, the paper's
//!   `C_isect = 5·C_trav` by default; candidates at the faces of each triangle's box clipped to
//!   the cell);
//! - `build = "middle"`: cells halved on their longest axis ([`crate::kdtree::middle`], the
//!   paper's fig. 2.9 baseline; `c_trav` and `c_isect` are not used).
//!
//! Both stop at `max_depth` (0: `8 + 1.3·⌊log₂ N⌋`, [`crate::kdtree::sah::auto_max_depth`])
//! and do not split cells holding at most `leaf_size` triangles (default 1: the SAH alone
//! decides above that; 0 lets it split single-triangle cells to cut off empty space). The
//! layout is [`KdTree`]'s: 12-byte nodes with their children allocated together, leaves with
//! their cells, every triangle listed in each leaf whose cell it touches. The parameters
//! [`build_params`] and [`build_tree`] are shared with the wgpu twin, which uploads the same
//! tree.
//!
//! # Identical to brute force
//!
//! Leaf tests use the ray-triangle test of parameter `test` (`mt`, `watertight`, `projected`:
//! [`crate::triangle`]), the same code brute force runs, on scene triangle ids, merged with
//! [`Hit::closer_than`]; a closest-hit ray stops only in a leaf whose cell (shrunk by a rounding
//! margin) holds its best hit point ([`crate::kdtree`], "Exactness"). So closest hits
//! (triangle, `t`, `u`, `v`) are the brute-force ones bit for bit, ties included, and any-hit
//! rays agree on hit or miss.
//!
//! # Counting
//!
//! [`KdCounts::record`]: `stats.add_bounds` one per inner node visited (its split-plane test),
//! `stats.add_ray_triangle` one per leaf triangle tested, `stats.add_visits(inner, leaves)`
//! the inner nodes and the leaves visited (empty leaves included, so `leaves` may exceed the
//! triangle tests). A ray that misses the root box visits nothing. Any-hit rays stop at the
//! first hit; rays whose stored hit is already a hit are skipped in any-hit mode (nothing
//! counted), and so are rays with an empty interval (`t_min ≥ t_max`).
//!
//! Rays are traced in parallel with rayon ([`trace_rays`]), each independently, and the tree
//! does not depend on the thread count, so hits and counts do not either.
//! [`Query::Candidates`] is not supported (the tree covers the whole scene): it returns
//! [`CoreError::Unsupported`].

use std::sync::Arc;
use std::time::{Duration, Instant};

use crsh_core::glam::Vec3;
use crsh_core::{
    CoreError, Hit, HitMode, Intersector, ParamInfo, Query, Ray, RayKind, Registry, Result,
    StageKind, StageSpec, StageVariantInfo, Stats,
};
use crsh_scene::Scene;
use rayon::prelude::*;

use crate::backend::Cpu;
use crate::intersect::brute::{check_batch, test_kind};
use crate::intersect::bvh::{test_param, CHUNK};
use crate::kdtree::coherent::{trace_batch, CoherentOptions, Traversal};
use crate::kdtree::edge_width::trace_batch_edge_width;
use crate::kdtree::sah::{self, SahParams, MAX_DEPTH_LIMIT};
use crate::kdtree::{middle, trace_single, KdCounts, KdTree};
use crate::triangle::{
    AnyTriangleSet, MollerTrumbore, Projected, TestKind, TriangleTest, Watertight,
};

/// How the tree is built (parameter `build`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Build {
    /// SAH with perfect splits ([`crate::kdtree::sah`]).
    Sah,
    /// Middle splits ([`crate::kdtree::middle`]).
    Middle,
}

impl Build {
    /// The names accepted by `build`.
    pub const NAMES: [&'static str; 2] = ["sah", "middle"];

    /// The build called `name`.
    pub fn from_name(name: &str) -> Option<Build> {
        match name {
            "sah" => Some(Build::Sah),
            "middle" => Some(Build::Middle),
            _ => None,
        }
    }

    /// The parameter value naming this build.
    pub fn name(self) -> &'static str {
        match self {
            Build::Sah => "sah",
            Build::Middle => "middle",
        }
    }
}

/// Largest accepted `leaf_size`.
pub const MAX_LEAF_SIZE: i64 = 1 << 20;

/// Largest accepted `c_trav` and `c_isect`.
pub const MAX_COST: f64 = 1e9;

/// The build parameters (`build`, `max_depth`, `leaf_size`, `c_trav`, `c_isect`), shared by
/// the CPU intersector and its wgpu twin (module doc, "Build").
pub fn build_params() -> Vec<ParamInfo> {
    vec![
        ParamInfo::choice(
            "build",
            "sah",
            &Build::NAMES,
            "`sah`: seed 003's SAH (eq. 2.1) with perfect splits (each triangle's box clipped \
             to the cell); `middle`: cells halved on their longest axis (fig. 2.9)",
        ),
        ParamInfo::int(
            "max_depth",
            0,
            0,
            i64::from(MAX_DEPTH_LIMIT),
            "deepest leaf (0: 8 + 1.3·⌊log2 N⌋ for N triangles, as PBRT)",
        ),
        ParamInfo::int(
            "leaf_size",
            1,
            0,
            MAX_LEAF_SIZE,
            "cells with at most this many triangles are not split (0: the SAH cost alone \
             decides)",
        ),
        ParamInfo::float(
            "c_trav",
            1.0,
            "C_traversal of eq. 2.1: the cost of one traversal step (sah only)",
        )
        .range(0.0, MAX_COST),
        ParamInfo::float(
            "c_isect",
            5.0,
            "C_intersect of eq. 2.1: the cost of one triangle test, > 0 (sah only; the paper's \
             5·C_traversal)",
        )
        .range(0.0, MAX_COST),
    ]
}

/// The catalogue entry of the `kdtree` intersector: [`build_params`] and `test`.
pub fn info() -> StageVariantInfo {
    let info = StageVariantInfo::new(
        StageKind::Intersect,
        "kdtree",
        "RTTest's kd-tree (seed 003: SAH with perfect splits, eq. 2.1, or middle splits; \
         12-byte nodes, leaves with their cells), rays front to back alone (listing 2.2 with \
         its errata fixed) or in packets, frusta, MFT groups or cones (§2.3, §4.1), closest \
         hit, any hit and edge width (§5), inner nodes, leaves and triangle tests counted; \
         whole-scene queries only",
    );
    build_params()
        .into_iter()
        .chain(traversal_params())
        .fold(info, StageVariantInfo::param)
        .param(test_param())
        .scene_only()
}

/// The traversal parameters (`traversal`, `tile_size`, `leaf_culling`): seed 003's coherent
/// traversals of rays sharing an origin ([`crate::kdtree::coherent`]).
pub fn traversal_params() -> Vec<ParamInfo> {
    vec![
        ParamInfo::choice(
            "traversal",
            "single",
            &TRAVERSAL_NAMES,
            "`single`: each ray alone (listing 2.2); `packet`: 2×2 packets, sign-coherent \
             (listing 2.4); `omni`: omni-directional 2×2 packets (listing 4.1); `frustum`: one \
             interval frustum per tile (listing 4.2); `mft`: four quadrant frusta per tile \
             (§4.1.5); `cone`: one cone per tile (eq. 4.8). Camera and point-light shadow rays \
             sharing an origin are grouped; other rays go alone",
        ),
        ParamInfo::int(
            "tile_size",
            8,
            i64::from(CoherentOptions::MIN_TILE),
            i64::from(CoherentOptions::MAX_TILE),
            "tile side in pixels of frustum, mft and cone (even; the paper's 4 to 32)",
        ),
        ParamInfo::choice(
            "coherent_kinds",
            "all",
            &["all", "primary", "shadow"],
            "which rays take `traversal`: `all`, or only camera (`primary`) or shadow rays, the \
             others going alone (seed 003 traces frusta of camera rays and packets of \
             secondary rays)",
        ),
        ParamInfo::bool(
            "leaf_culling",
            true,
            "packet/leaf culling (§4.1.4): a tile traversal skips a packet whose rays all miss \
             a leaf's cell",
        ),
    ]
}

/// The names `traversal` accepts, in [`Traversal::ALL`] order.
pub const TRAVERSAL_NAMES: [&str; 6] = ["single", "packet", "omni", "frustum", "mft", "cone"];

/// Registers `kdtree` ([`info`], [`KdIntersector::new`]).
pub fn register(registry: &mut Registry<Cpu>) -> Result<()> {
    registry.add_intersector(info(), |ctx, spec| {
        Ok(Box::new(
            KdIntersector::new(ctx.scene, spec)?.with_traversal(spec, ctx.frame.width)?,
        ))
    })?;
    Ok(())
}

/// The build parameters of `spec` ([`build_params`]), checked.
///
/// # Errors
/// A missing or mistyped parameter, an unknown `build`, `max_depth` or `leaf_size` out of
/// range, `c_trav` not finite and ≥ 0, `c_isect` not finite and > 0.
pub fn parse_build(spec: &StageSpec) -> Result<(Build, SahParams)> {
    let bad = |key: &str, reason: String| CoreError::InvalidParam {
        key: format!("kdtree.{key}"),
        reason,
    };
    let name = spec.str("build")?;
    let build = Build::from_name(name).ok_or_else(|| {
        bad(
            "build",
            format!("`{name}` is not one of {}", Build::NAMES.join(", ")),
        )
    })?;
    let max_depth = spec.i64("max_depth")?;
    if !(0..=i64::from(MAX_DEPTH_LIMIT)).contains(&max_depth) {
        return Err(bad(
            "max_depth",
            format!("{max_depth} is outside 0..={MAX_DEPTH_LIMIT}"),
        ));
    }
    let leaf_size = spec.i64("leaf_size")?;
    if !(0..=MAX_LEAF_SIZE).contains(&leaf_size) {
        return Err(bad(
            "leaf_size",
            format!("{leaf_size} is outside 0..={MAX_LEAF_SIZE}"),
        ));
    }
    let c_trav = spec.f64("c_trav")?;
    if !(0.0..=MAX_COST).contains(&c_trav) {
        return Err(bad(
            "c_trav",
            format!("{c_trav} is not a cost in 0..={MAX_COST}"),
        ));
    }
    let c_isect = spec.f64("c_isect")?;
    if !(c_isect > 0.0 && c_isect <= MAX_COST) {
        return Err(bad(
            "c_isect",
            format!("{c_isect} is not a positive cost up to {MAX_COST}"),
        ));
    }
    Ok((
        build,
        SahParams {
            c_trav,
            c_isect,
            max_depth: max_depth as u32,
            leaf_size: leaf_size as usize,
        },
    ))
}

/// The triangles of `scene` that test `test` can hit, as `(scene id, vertices)`.
pub fn hittable_triangles(scene: &Scene, test: TestKind) -> Vec<(u32, [Vec3; 3])> {
    crate::intersect::grid::hittable(scene, test)
        .iter()
        .enumerate()
        .filter(|(_, &keep)| keep)
        .map(|(t, _)| (t as u32, scene.triangle(t)))
        .collect()
}

/// The tree over `tris` (hittable triangles) by `build` with `params`.
pub fn build_with(tris: &[(u32, [Vec3; 3])], build: Build, params: &SahParams) -> KdTree {
    match build {
        Build::Sah => sah::build(tris, params),
        Build::Middle => {
            let depth = match params.max_depth {
                0 => sah::auto_max_depth(tris.len()),
                d => d,
            };
            middle::build(tris, depth, params.leaf_size)
        }
    }
}

/// The tree of `scene` that `spec` asks for ([`build_params`]), over the triangles test
/// `test` can hit. `spec`'s `test` is not read (the wgpu twin narrows it).
///
/// # Errors
/// The parameter errors of [`parse_build`].
pub fn build_tree(scene: &Scene, spec: &StageSpec, test: TestKind) -> Result<KdTree> {
    let (build, params) = parse_build(spec)?;
    Ok(build_with(&hittable_triangles(scene, test), build, &params))
}

/// The `kdtree` intersector: the tree and every scene triangle prepared for the test.
pub struct KdIntersector {
    coherent: CoherentOptions,
    /// The ray kind `coherent` applies to (`None`: every kind).
    coherent_kind: Option<RayKind>,
    /// The scene lights' radii (the `R` of edge-width queries) and shared vertices.
    lights: crsh_core::edge_width::EdgeWidthLights,
    tree: KdTree,
    tris: AnyTriangleSet,
    build: Build,
    params: SahParams,
    build_time: Duration,
}

impl std::fmt::Debug for KdIntersector {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("KdIntersector")
            .field("nodes", &self.tree.nodes.len())
            .field("leaves", &self.tree.leaves.len())
            .field("references", &self.tree.leaf_tris.len())
            .field("depth", &self.tree.depth)
            .field("build", &self.build)
            .field("params", &self.params)
            .field("test", &self.test())
            .field("build_time", &self.build_time)
            .finish()
    }
}

impl KdIntersector {
    /// Builds the tree of `scene` that `spec` asks for ([`build_params`] and `test`).
    ///
    /// # Errors
    /// A bad parameter ([`parse_build`], an unknown `test`).
    pub fn new(scene: &Arc<Scene>, spec: &StageSpec) -> Result<KdIntersector> {
        let (build, params) = parse_build(spec)?;
        let test = test_kind(spec, "kdtree")?;
        Ok(KdIntersector::build(scene, build, &params, test))
    }

    /// Builds the tree of `scene` with `build` and `params`, for test `test` (the build time
    /// is measured).
    pub fn build(scene: &Scene, build: Build, params: &SahParams, test: TestKind) -> Self {
        let t0 = Instant::now();
        let tree = build_with(&hittable_triangles(scene, test), build, params);
        let build_time = t0.elapsed();
        KdIntersector {
            coherent: CoherentOptions::new(Traversal::Single, 1),
            coherent_kind: None,
            lights: crate::intersect::brute::edge_width_lights(scene),
            tree,
            tris: AnyTriangleSet::new(scene, test),
            build,
            params: *params,
            build_time,
        }
    }

    /// This intersector tracing with the traversal parameters of `spec`
    /// ([`traversal_params`]; a spec without them keeps `single`) on an image `width` pixels
    /// wide (the pixels of [`Ray::pixel`], which place rays in tiles).
    ///
    /// # Errors
    /// An unknown `traversal`, an odd or out-of-range `tile_size`, a zero width.
    pub fn with_traversal(mut self, spec: &StageSpec, width: u32) -> Result<KdIntersector> {
        let bad = |key: &str, reason: String| CoreError::InvalidParam {
            key: format!("kdtree.{key}"),
            reason,
        };
        let name = spec.str("traversal").unwrap_or("single");
        let traversal = Traversal::from_name(name).ok_or_else(|| {
            bad(
                "traversal",
                format!("`{name}` is not one of {}", TRAVERSAL_NAMES.join(", ")),
            )
        })?;
        let opts = CoherentOptions {
            traversal,
            tile_size: spec
                .i64("tile_size")
                .ok()
                .map_or(Ok(8), u32::try_from)
                .map_err(|_| bad("tile_size", "is negative or too large".into()))?,
            leaf_culling: spec.bool("leaf_culling").unwrap_or(true),
            width,
        };
        opts.validate().map_err(|e| bad("tile_size", e))?;
        self.coherent_kind = match spec.str("coherent_kinds").unwrap_or("all") {
            "all" => None,
            "primary" => Some(RayKind::Primary),
            "shadow" => Some(RayKind::Shadow),
            other => {
                return Err(bad(
                    "coherent_kinds",
                    format!("`{other}` is not one of all, primary, shadow"),
                ))
            }
        };
        self.coherent = opts;
        Ok(self)
    }

    /// The traversal options.
    pub fn coherent(&self) -> &CoherentOptions {
        &self.coherent
    }

    /// The tree.
    pub fn tree(&self) -> &KdTree {
        &self.tree
    }

    /// Every scene triangle prepared for the test, indexed by scene id (the ids
    /// [`KdTree::leaf_tris`] holds).
    pub fn triangles(&self) -> &AnyTriangleSet {
        &self.tris
    }

    /// The ray-triangle test.
    pub fn test(&self) -> TestKind {
        self.tris.kind()
    }

    /// The build used.
    pub fn build_kind(&self) -> Build {
        self.build
    }

    /// The build parameters (the SAH costs are unused by the middle-split build).
    pub fn params(&self) -> &SahParams {
        &self.params
    }

    /// Time the tree's build took (the triangles' preparation not included).
    pub fn build_time(&self) -> Duration {
        self.build_time
    }
}

/// Traces `rays` one by one through `tree` with test `T` on `tris` (every scene triangle
/// prepared for `T`, by scene id), merging into `hits` ([`trace_single`]); in parallel over
/// chunks of rays, each ray independently, so hits and counts do not depend on the thread
/// count. Returns the summed counts.
pub fn trace_rays<T: TriangleTest>(
    tree: &KdTree,
    tris: &[T::Tri],
    rays: &[Ray],
    mode: HitMode,
    hits: &mut [Hit],
) -> KdCounts {
    rays.par_chunks(CHUNK)
        .zip(hits.par_chunks_mut(CHUNK))
        .map(|(rs, hs)| {
            let mut stack = Vec::new();
            rs.iter()
                .zip(hs.iter_mut())
                .fold(KdCounts::default(), |n, (ray, h)| {
                    n.plus(trace_single::<T>(tree, tris, ray, mode, h, &mut stack))
                })
        })
        .reduce(KdCounts::default, KdCounts::plus)
}

impl Intersector<Cpu> for KdIntersector {
    fn name(&self) -> &str {
        "kdtree"
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
        query.whole_scene_only("kdtree")?;
        // Every mode is named: a new one must say how the tree answers it.
        match mode {
            HitMode::Closest | HitMode::Any => {}
            HitMode::EdgeWidth(pairing) => {
                // Seed 003 §5: front to back through the tree, one ray at a time.
                let r = &self.lights;
                let counts = match &self.tris {
                    AnyTriangleSet::MollerTrumbore(s) => trace_batch_edge_width::<MollerTrumbore>(
                        &self.tree,
                        s.triangles(),
                        rays,
                        r,
                        pairing,
                        hits,
                    ),
                    AnyTriangleSet::Watertight(s) => trace_batch_edge_width::<Watertight>(
                        &self.tree,
                        s.triangles(),
                        rays,
                        r,
                        pairing,
                        hits,
                    ),
                    AnyTriangleSet::Projected(s) => trace_batch_edge_width::<Projected>(
                        &self.tree,
                        s.triangles(),
                        rays,
                        r,
                        pairing,
                        hits,
                    ),
                }?;
                counts.record(stats);
                return Ok(());
            }
        }
        check_batch(rays, hits)?;
        let kind = rays.first().and_then(|r| RayKind::from_u32(r.kind));
        let single = CoherentOptions {
            traversal: Traversal::Single,
            ..self.coherent
        };
        let o = match self.coherent_kind {
            Some(k) if kind != Some(k) => &single,
            _ => &self.coherent,
        };
        let (counts, packets) = match &self.tris {
            AnyTriangleSet::MollerTrumbore(s) => {
                trace_batch::<MollerTrumbore>(&self.tree, s.triangles(), rays, mode, hits, o)
            }
            AnyTriangleSet::Watertight(s) => {
                trace_batch::<Watertight>(&self.tree, s.triangles(), rays, mode, hits, o)
            }
            AnyTriangleSet::Projected(s) => {
                trace_batch::<Projected>(&self.tree, s.triangles(), rays, mode, hits, o)
            }
        };
        if let Some(kind) = kind {
            packets.record(kind, stats);
        }
        counts.record(stats);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::intersect::brute::tests::{random_rays, soup, test_ray};
    use crate::intersect::bvh::tests::{
        assert_same_hits, box_room, builtin_rays, check_exact, check_never_hits, degenerate_scene,
        one, rejects_candidates_and_bad_rays, run, same_for_one_and_two_threads,
    };
    use crate::kdtree::sah::tests::check_membership;
    use crate::surface::tests::raw_scene;
    use crsh_core::{ParamValue, TestCounts};

    /// A resolved `kdtree` spec with `sets` (`key=value`) applied.
    fn spec(sets: &[&str]) -> StageSpec {
        let registry = Registry::<Cpu>::builtin();
        let mut cfg = crsh_core::PipelineConfig::whitted("k", "kdtree");
        for s in sets {
            cfg.set(&format!("intersect.{s}")).unwrap();
        }
        registry.resolve(&mut cfg).unwrap();
        cfg.intersect
    }

    fn kd(scene: &Scene, build: Build, test: TestKind) -> KdIntersector {
        KdIntersector::build(scene, build, &SahParams::default(), test)
    }

    /// The camera rays of a `w × h` image of `scene`'s camera.
    fn camera_rays(scene: &Scene, w: u32, h: u32) -> Vec<Ray> {
        (0..w * h)
            .map(|p| {
                let (o, d) = crate::primary::raycast::camera_ray(&scene.camera, p % w, p / w, w, h);
                test_ray(o, d, 0.0, f32::INFINITY, p as usize)
            })
            .collect()
    }

    /// `x` (for test `test`) answers `rays` as brute force does: closest hits bit for bit,
    /// any hits hit or miss alike ([`check_exact`] without its demand for node tests: a tree
    /// may be one leaf).
    fn check_hits(scene: &Scene, rays: &Vec<Ray>, test: TestKind, x: &KdIntersector, what: &str) {
        if x.tree().nodes.len() > 1 {
            return check_exact(scene, rays, test, x, what);
        }
        let brute = crate::intersect::brute::BruteForce::with_test(scene, test);
        for mode in [HitMode::Closest, HitMode::Any] {
            let (want, _) = run(&brute, rays, mode);
            let (got, _) = run(x, rays, mode);
            assert_same_hits(rays, &got, &want, mode, what);
        }
    }

    /// Both builds, every test: brute force's hits on `rays`; the trees are valid and list
    /// every triangle in every leaf it touches.
    fn check_both_builds(scene: &Scene, rays: &Vec<Ray>, what: &str) {
        check_builds(scene, rays, what, &[Build::Sah, Build::Middle]);
    }

    /// [`check_both_builds`] for `builds` only.
    fn check_builds(scene: &Scene, rays: &Vec<Ray>, what: &str, builds: &[Build]) {
        for test in TestKind::ALL {
            for &build in builds {
                let x = kd(scene, build, test);
                x.tree().validate().unwrap();
                assert_eq!(x.test(), test);
                check_hits(scene, rays, test, &x, &format!("{what} {build:?}"));
            }
        }
        let x = kd(scene, Build::Sah, TestKind::MollerTrumbore);
        check_membership(
            x.tree(),
            &hittable_triangles(scene, TestKind::MollerTrumbore),
        );
    }

    #[test]
    fn identical_to_brute_force_on_random_soups() {
        for (seed, n) in [(21u64, 500usize), (22, 60), (24, 7)] {
            let scene = soup(seed, n);
            let rays = random_rays(&scene, seed + 100, 1500);
            check_both_builds(&scene, &rays, &format!("soup {seed}"));
        }
    }

    /// A soup far from the origin (offset 1e6) and one scaled by 1e6: rays from near the
    /// origin, from the surfaces and grazing them.
    #[test]
    fn identical_to_brute_force_on_far_and_huge_geometry() {
        let base = soup(25, 300);
        let tris: Vec<[Vec3; 3]> = (0..base.triangle_count())
            .map(|t| base.triangle(t))
            .collect();
        for (what, f) in [
            (
                "offset 1e6",
                (|p: Vec3| p + Vec3::new(1e6, -1e6, 1e6)) as fn(Vec3) -> Vec3,
            ),
            ("scale 1e6", |p: Vec3| p * 1e6),
        ] {
            let positions: Vec<Vec3> = tris.iter().flatten().map(|&p| f(p)).collect();
            let indices = (0..tris.len() as u32)
                .map(|t| [3 * t, 3 * t + 1, 3 * t + 2])
                .collect();
            let scene = raw_scene(positions, vec![Vec3::Z; 3 * tris.len()], indices);
            let rays = random_rays(&scene, 26, 1200);
            // Not the middle split far from the origin: its margin (1e-5 of the coordinates,
            // 10 at 1e6) puts every triangle of this small soup in every cell down to the
            // depth limit (2^18 cells of 300 triangles).
            check_builds(&scene, &rays, what, &[Build::Sah]);
            if what == "offset 1e6" {
                // The SAH's margin (4e-5 of the coordinates, 40) covers the whole soup too:
                // one leaf, nothing to gain from a split.
                let x = kd(&scene, Build::Sah, TestKind::MollerTrumbore);
                assert_eq!(x.tree().leaves.len(), 1);
            }
        }
    }

    /// Axis-aligned walls (zero-thickness extents, triangles in split planes): rays grazing
    /// along them, starting on them, and parallel to the axes.
    #[test]
    fn identical_to_brute_force_on_grazing_axis_aligned_rays() {
        let (scene, rays) = box_room();
        check_both_builds(&scene, &rays, "box room");
    }

    /// Built-in scenes (and a sized one): camera rays, and rays from random points and
    /// leaving surfaces, as reflection and shadow rays do.
    #[test]
    fn identical_to_brute_force_on_builtin_scenes() {
        let names = crsh_scene::builtin::STATIC_NAMES
            .iter()
            .copied()
            .chain(["glass-sphere-1000"]);
        for name in names {
            let scene = crsh_scene::builtin::build(name).unwrap_or_else(|e| panic!("{name}: {e}"));
            let mut rays = builtin_rays(&scene, 61, 1000);
            rays.extend(camera_rays(&scene, 24, 24));
            for test in TestKind::ALL {
                let x = kd(&scene, Build::Sah, test);
                check_exact(&scene, &rays, test, &x, name);
            }
        }
    }

    /// The shared Cornell boxes (`CRSH_SCENES`, else `<workspace>/../shared/scenes`), when
    /// present: valid trees listing every touching triangle, brute force's hits.
    #[test]
    fn identical_to_brute_force_on_the_shared_cornell_boxes() {
        let dir = std::env::var_os("CRSH_SCENES")
            .map(std::path::PathBuf::from)
            .unwrap_or_else(|| {
                std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/scenes")
            });
        for rel in [
            "cornell/cornell-original.toml",
            "cornell/cornell-mirror.toml",
            "cornell/cornell-sphere.toml",
        ] {
            let path = dir.join(rel);
            if !path.is_file() {
                eprintln!("SKIP: {} not found (set CRSH_SCENES)", path.display());
                continue;
            }
            let scene = crsh_scene::load_path(&path).unwrap();
            let mut rays = builtin_rays(&scene, 62, 1000);
            rays.extend(camera_rays(&scene, 24, 24));
            check_both_builds(&scene, &rays, rel);
        }
    }

    #[test]
    fn the_sah_tree_needs_fewer_tests_than_middle_splits() {
        let scene = crsh_scene::builtin::build("office-boxes").unwrap();
        let mut rays = camera_rays(&scene, 32, 32);
        rays.extend(builtin_rays(&scene, 63, 1000));
        let sah = kd(&scene, Build::Sah, TestKind::MollerTrumbore);
        let mid = kd(&scene, Build::Middle, TestKind::MollerTrumbore);
        let (hs, s) = run(&sah, &rays, HitMode::Closest);
        let (hm, m) = run(&mid, &rays, HitMode::Closest);
        assert_eq!(hs, hm);
        assert!(
            s.tests.ray_triangle * 2 < m.tests.ray_triangle,
            "SAH {:?} middle {:?}",
            s.tests,
            m.tests
        );
        // Both far below brute force's N × M.
        assert!(s.tests.ray_triangle * 50 < (rays.len() * scene.triangle_count()) as u64);
    }

    #[test]
    fn parameters_reach_the_build() {
        let scene = Arc::new(crsh_scene::builtin::build("office-boxes").unwrap());
        let x = KdIntersector::new(&scene, &spec(&[])).unwrap();
        assert_eq!(
            (x.build_kind(), *x.params(), x.test()),
            (Build::Sah, SahParams::default(), TestKind::MollerTrumbore)
        );
        let shallow =
            KdIntersector::new(&scene, &spec(&["max_depth=3", "test=projected"])).unwrap();
        assert_eq!(shallow.tree().depth, 3);
        assert_eq!(shallow.test(), TestKind::Projected);
        let big = KdIntersector::new(&scene, &spec(&["leaf_size=64"])).unwrap();
        assert!(big.tree().leaves.len() < x.tree().leaves.len());
        assert!(big.tree().leaves.iter().any(|l| l.count > 1));
        let costly = KdIntersector::new(&scene, &spec(&["c_trav=100"])).unwrap();
        assert!(costly.tree().nodes.len() < x.tree().nodes.len());
        let mid = KdIntersector::new(&scene, &spec(&["build=middle", "max_depth=6"])).unwrap();
        assert_eq!(mid.build_kind(), Build::Middle);
        assert_eq!(
            mid.tree(),
            &middle::build(&hittable_triangles(&scene, TestKind::MollerTrumbore), 6, 1)
        );
        // build_tree (the wgpu twin's) builds the same tree.
        assert_eq!(
            &build_tree(&scene, &spec(&[]), TestKind::MollerTrumbore).unwrap(),
            x.tree()
        );
        // The shallow tree still answers exactly.
        let rays = builtin_rays(&scene, 64, 500);
        check_exact(&scene, &rays, TestKind::Projected, &shallow, "depth 3");
    }

    #[test]
    fn candidates_are_unsupported_and_bad_params_rejected() {
        let scene = Arc::new(soup(41, 20));
        let good = spec(&[]);
        assert!(KdIntersector::new(&scene, &StageSpec::new("kdtree")).is_err());
        for (key, value) in [
            ("build", ParamValue::Str("median".into())),
            ("build", ParamValue::Int(1)),
            ("max_depth", ParamValue::Int(-1)),
            ("max_depth", ParamValue::Int(65)),
            ("max_depth", ParamValue::Float(3.0)),
            ("leaf_size", ParamValue::Int(-2)),
            ("leaf_size", ParamValue::Int(MAX_LEAF_SIZE + 1)),
            ("c_trav", ParamValue::Float(-1.0)),
            ("c_trav", ParamValue::Float(f64::NAN)),
            ("c_trav", ParamValue::Float(f64::INFINITY)),
            ("c_isect", ParamValue::Float(0.0)),
            ("c_isect", ParamValue::Float(f64::NAN)),
            ("c_isect", ParamValue::Str("five".into())),
            ("test", ParamValue::Str("square".into())),
        ] {
            let mut s = good.clone();
            s.params.insert(key.into(), value.clone());
            assert!(
                matches!(
                    KdIntersector::new(&scene, &s),
                    Err(CoreError::InvalidParam { .. })
                ),
                "{key} = {value:?}"
            );
            let mut s = good.clone();
            s.params.remove(key);
            assert!(KdIntersector::new(&scene, &s).is_err(), "no {key}");
        }
        // The catalogue refuses them before anything is built, too.
        let registry = Registry::<Cpu>::builtin();
        for bad in ["max_depth=65", "leaf_size=-1", "c_trav=-1", "build=median"] {
            let mut cfg = crsh_core::PipelineConfig::whitted("k", "kdtree");
            cfg.set(&format!("intersect.{bad}")).unwrap();
            assert!(registry.resolve(&mut cfg).is_err(), "{bad}");
        }
        let x = KdIntersector::new(&scene, &good).unwrap();
        rejects_candidates_and_bad_rays(&x, &scene);
    }

    #[test]
    fn all_degenerate_scene_never_hits() {
        let scene = degenerate_scene();
        let x = kd(&scene, Build::Sah, TestKind::MollerTrumbore);
        assert_eq!(x.tree(), &KdTree::default());
        check_never_hits(&x, &scene);
    }

    #[test]
    fn same_result_for_any_thread_count() {
        let scene = Arc::new(soup(51, 3000));
        let rays = random_rays(&scene, 52, 700);
        let a = crate::with_threads(1, || KdIntersector::new(&scene, &spec(&[])).unwrap()).unwrap();
        let b = crate::with_threads(2, || KdIntersector::new(&scene, &spec(&[])).unwrap()).unwrap();
        assert_eq!(a.tree(), b.tree());
        same_for_one_and_two_threads(&a, &rays);
    }

    fn four_of(t: &TestCounts) -> (u64, u64, u64, u64) {
        (t.bounds, t.ray_triangle, t.inner_nodes, t.leaves)
    }

    /// Per-ray counts: the batch's are the rays' sums; a hit was found in a visited leaf;
    /// tests happen only in visited leaves; a ray missing the root box visits nothing.
    #[test]
    fn visit_counts_add_up() {
        for name in crsh_scene::builtin::STATIC_NAMES {
            let scene = crsh_scene::builtin::build(name).unwrap();
            let x = kd(&scene, Build::Sah, TestKind::MollerTrumbore);
            let rays = builtin_rays(&scene, 71, 300);
            for mode in [HitMode::Closest, HitMode::Any] {
                let mut sum = TestCounts::default();
                for (i, ray) in rays.iter().enumerate() {
                    let (h, c) = one(&x, ray, mode);
                    assert_eq!(c.bounds, c.inner_nodes, "{name} {mode:?} ray {i}");
                    assert!(c.leaves > 0 || c.ray_triangle == 0, "{name} ray {i}: {c:?}");
                    if h.is_hit() {
                        assert!(c.leaves >= 1, "{name} {mode:?} ray {i}: {c:?}");
                    }
                    sum.bounds += c.bounds;
                    sum.ray_triangle += c.ray_triangle;
                    sum.inner_nodes += c.inner_nodes;
                    sum.leaves += c.leaves;
                }
                let (_, batch) = run(&x, &rays, mode);
                assert_eq!(four_of(&batch.tests), four_of(&sum), "{name} {mode:?}");
            }
            let bounds = x.tree().bounds;
            let away = test_ray(
                bounds.max + Vec3::ONE,
                Vec3::ONE.normalize(),
                0.0,
                f32::INFINITY,
                0,
            );
            let (h, c) = one(&x, &away, HitMode::Closest);
            assert!(!h.is_hit());
            assert_eq!(four_of(&c), (0, 0, 0, 0));
        }
    }
}

/// Camera rays on the shared scenes against the BVH (`cargo test --release -p crsh-cpu --lib
/// intersect::kdtree::bench -- --ignored --nocapture`); skipped when the scenes are absent.
#[cfg(test)]
mod bench {
    use super::*;
    use crate::intersect::bvh::{BuildQuality, CwBvh};

    #[test]
    #[ignore = "a measurement: run in release with --ignored --nocapture"]
    fn camera_rays_against_the_bvh() {
        let dir = std::env::var_os("CRSH_SCENES")
            .map(std::path::PathBuf::from)
            .unwrap_or_else(|| {
                std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/scenes")
            });
        for rel in ["sponza/sponza.toml", "dining-room/dining-room.toml"] {
            let path = dir.join(rel);
            if !path.is_file() {
                eprintln!("SKIP: {} not found (set CRSH_SCENES)", path.display());
                continue;
            }
            let scene = Arc::new(crsh_scene::load_path(&path).unwrap());
            let (w, h) = (512u32, 512u32);
            let rays: Vec<Ray> = (0..w * h)
                .map(|p| {
                    let (o, d) =
                        crate::primary::raycast::camera_ray(&scene.camera, p % w, p / w, w, h);
                    crate::intersect::brute::tests::test_ray(o, d, 0.0, f32::INFINITY, p as usize)
                })
                .collect();
            let kd = KdIntersector::build(
                &scene,
                Build::Sah,
                &SahParams::default(),
                TestKind::MollerTrumbore,
            );
            let t0 = Instant::now();
            let bvh = CwBvh::build(&scene, BuildQuality::Medium);
            let bvh_build = t0.elapsed();
            for (name, x, build) in [
                ("kdtree", &kd as &dyn Intersector<Cpu>, kd.build_time()),
                ("bvh", &bvh, bvh_build),
            ] {
                for mode in [HitMode::Closest, HitMode::Any] {
                    let mut hits = vec![Hit::MISS; rays.len()];
                    let mut stats = Stats::default();
                    let t0 = Instant::now();
                    x.intersect(&Cpu, &rays, Query::Scene, mode, &mut hits, &mut stats)
                        .unwrap();
                    let ms = t0.elapsed().as_secs_f64() * 1e3;
                    let n = rays.len() as f64;
                    let t = &stats.tests;
                    eprintln!(
                        "{rel} {name} {mode:?} (build {:.0} ms): {:.2} triangle tests, {:.2} \
                         inner nodes, {:.2} leaves, {:.2} bounds per ray; {:.0} ms for {} rays; \
                         {} hits",
                        build.as_secs_f64() * 1e3,
                        t.ray_triangle as f64 / n,
                        t.inner_nodes as f64 / n,
                        t.leaves as f64 / n,
                        t.bounds as f64 / n,
                        ms,
                        rays.len(),
                        hits.iter().filter(|h| h.is_hit()).count()
                    );
                }
            }
        }
    }
}
