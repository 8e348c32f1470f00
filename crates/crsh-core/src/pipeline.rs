//! The backend-generic frame driver: seed 000 fig. 3.1 as a loop over ray batches.
//!
//! ```text
//! primary visibility ─► surfaces ─┬► shadow rays ─► trace (any hit) ─► shade direct light
//!                                 └► reflection / refraction rays ─► trace (nearest) ─► resolve
//!                                        └──────────── next surfaces, up to max_depth ──┘
//! trace = [hash ─► sort ─► build hierarchy ─► traverse ─►] intersect
//! ```
//!
//! Batches are processed one ray kind at a time. The driver times every stage (after
//! [`Backend::sync`]), counts rays, attributes test counts to ray kinds, and, when a reference
//! intersector is given, traces the very same rays with it to measure agreement.

use std::collections::BTreeMap;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::backend::Backend;
use crate::config::{PipelineConfig, StageKind};
use crate::error::{CoreError, Result};
use crate::order::RayOrder;
use crate::ray::{Hit, HitMode, Ray, RayKind, Surface};
use crate::stage::{
    Hasher, HierarchyBuilder, Intersector, PrimaryVisibility, Query, RayGen, Shader, Sorter,
    Traverser,
};
use crate::stats::{AccuracyCounts, Stats};

/// The stage objects of one pipeline on backend `B`.
///
/// Fields are public so a caller can swap a stage of a built [`Pipeline`]; the frame's
/// [`Stats::stages`] records the names of the objects that actually ran, and [`Stages::check`]
/// (run by [`render_frame`]) refuses combinations that do not fit.
pub struct Stages<B: Backend> {
    /// Primary visibility.
    pub primary: Box<dyn PrimaryVisibility<B>>,
    /// Secondary ray creation.
    pub raygen: Box<dyn RayGen<B>>,
    /// Ray hashing (with `sorter`), optional.
    pub hasher: Option<Box<dyn Hasher<B>>>,
    /// Ray sorting (with `hasher`), optional.
    pub sorter: Option<Box<dyn Sorter<B>>>,
    /// Ray-space hierarchy creation (with `traverser`), optional.
    pub hierarchy: Option<Box<dyn HierarchyBuilder<B>>>,
    /// Hierarchy traversal (with `hierarchy`), optional.
    pub traverser: Option<Box<dyn Traverser<B>>>,
    /// Exact ray-triangle tests.
    pub intersector: Box<dyn Intersector<B>>,
    /// Shading.
    pub shader: Box<dyn Shader<B>>,
    /// The order [`render_frame`] traces each batch in (`raygen.order`); hits are put back in
    /// generation order before shading either way.
    pub order: RayOrder,
}

impl<B: Backend> Stages<B> {
    /// Checks that the stage objects fit together, naming the slots when they do not
    /// ([`CoreError::Incompatible`]): a hasher comes with a sorter, a hierarchy with a
    /// traverser, and the intersector of a hierarchy answers candidate queries
    /// ([`Intersector::supports_candidates`]). A hasher and sorter without a hierarchy put
    /// each batch in sorted order for the whole-scene intersector.
    pub fn check(&self) -> Result<()> {
        let incompatible = |slots: &str, reason: String| CoreError::Incompatible {
            slots: slots.to_string(),
            reason,
        };
        if self.hasher.is_some() != self.sorter.is_some() {
            return Err(incompatible(
                "hash, sort",
                "a hasher needs a sorter and a sorter a hasher".into(),
            ));
        }
        if self.hierarchy.is_some() != self.traverser.is_some() {
            return Err(incompatible(
                "hierarchy, traverse",
                "a ray-space hierarchy needs a traverser and a traverser a hierarchy".into(),
            ));
        }
        let visibility = self.raygen.visibility_kind();
        if !self.shader.shades(visibility) {
            return Err(incompatible(
                "raygen, shade",
                format!(
                    "shade `{}` does not shade the {} rays of raygen `{}` (pair `ao` with `ao`)",
                    self.shader.name(),
                    visibility.name(),
                    self.raygen.name()
                ),
            ));
        }
        if let Some(h) = &self.hierarchy {
            if !self.intersector.supports_candidates() {
                return Err(incompatible(
                    "hierarchy, intersect",
                    format!(
                        "intersect `{}` answers whole-scene queries only and cannot run the final tests of hierarchy `{}`",
                        self.intersector.name(),
                        h.name()
                    ),
                ));
            }
        }
        Ok(())
    }

    /// The variant name of every filled slot (`slot key → name`), from the stage objects
    /// themselves.
    pub fn names(&self) -> BTreeMap<String, String> {
        let mut m = BTreeMap::new();
        let mut put = |slot: StageKind, name: Option<&str>| {
            if let Some(n) = name {
                m.insert(slot.key().to_string(), n.to_string());
            }
        };
        put(StageKind::Primary, Some(self.primary.name()));
        put(StageKind::Raygen, Some(self.raygen.name()));
        put(StageKind::Hash, self.hasher.as_ref().map(|s| s.name()));
        put(StageKind::Sort, self.sorter.as_ref().map(|s| s.name()));
        put(
            StageKind::Hierarchy,
            self.hierarchy.as_ref().map(|s| s.name()),
        );
        put(
            StageKind::Traverse,
            self.traverser.as_ref().map(|s| s.name()),
        );
        put(StageKind::Intersect, Some(self.intersector.name()));
        put(StageKind::Shade, Some(self.shader.name()));
        m
    }
}

/// The image a pipeline renders, `1..=`[`MAX_IMAGE_SIDE`] pixels per side.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct FrameSize {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
}

impl FrameSize {
    /// A frame of `width × height` pixels.
    ///
    /// # Errors
    /// [`CoreError::InvalidInput`] when a side is 0 or above [`MAX_IMAGE_SIDE`].
    pub fn new(width: u32, height: u32) -> Result<FrameSize> {
        if width == 0 || height == 0 || width > MAX_IMAGE_SIDE || height > MAX_IMAGE_SIDE {
            return Err(CoreError::InvalidInput(format!(
                "image size {width}x{height} is outside 1..={MAX_IMAGE_SIDE} per side"
            )));
        }
        Ok(FrameSize { width, height })
    }

    /// Pixels in the frame.
    pub fn pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }
}

impl std::fmt::Display for FrameSize {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}x{}", self.width, self.height)
    }
}

/// Per-frame settings besides the frame size (which the [`Pipeline`] was built for).
///
/// ```
/// use crsh_core::FrameOptions;
/// let o = FrameOptions::default().with_max_depth(1);
/// assert_eq!(o.max_depth, 1);
/// assert_eq!(FrameOptions::default().max_depth, 3);
/// ```
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub struct FrameOptions {
    /// Reflection / refraction bounces after the primary hit (0: direct light only),
    /// `0..=`[`MAX_DEPTH`]; 3 by default.
    pub max_depth: u32,
    /// Whether [`Frame::primary_triangles`] is filled: the triangle each pixel sees, read
    /// back (untimed) for comparing the primary visibility with a reference's. Off by
    /// default.
    pub primary_triangles: bool,
}

impl Default for FrameOptions {
    fn default() -> Self {
        FrameOptions {
            max_depth: 3,
            primary_triangles: false,
        }
    }
}

impl FrameOptions {
    /// The defaults (3 bounces).
    pub fn new() -> FrameOptions {
        FrameOptions::default()
    }

    /// The same options with `max_depth` bounces.
    pub fn with_max_depth(self, max_depth: u32) -> FrameOptions {
        FrameOptions { max_depth, ..self }
    }

    /// The same options, keeping the primary triangles when `keep` ([`Frame::primary_triangles`]).
    pub fn with_primary_triangles(self, keep: bool) -> FrameOptions {
        FrameOptions {
            primary_triangles: keep,
            ..self
        }
    }
}

/// A built pipeline: the resolved description, its stage objects, and what they were built
/// for (the frame size and the scene's triangle count, so no caller has to repeat them).
pub struct Pipeline<B: Backend> {
    /// The pipeline description the stages were built from, resolved (every parameter
    /// present). A stage swapped into [`Pipeline::stages`] afterwards is not reflected here;
    /// the frame's [`Stats::stages`] names what actually ran.
    pub config: PipelineConfig,
    /// The stage objects.
    pub stages: Stages<B>,
    /// The frame the stages were built for.
    pub frame: FrameSize,
    /// Triangles in the scene the stages were built for: the `M` of brute force's `N × M`.
    pub triangles: u64,
    /// What building each stage did and took, in construction order (empty for a pipeline
    /// assembled by hand).
    pub builds: Vec<StageBuild>,
}

/// What building one stage of a [`Pipeline`] did and took: for an intersector that is its
/// acceleration structure over the scene (an object BVH, a grid), built or refitted; for the
/// other stages little more than keeping the scene's arrays. The per-frame rebuild cost of a
/// dynamic scene ([`crate::Registry::rebuild`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StageBuild {
    /// The slot key (`intersect`, `traverse`, ...).
    pub slot: String,
    /// The variant built.
    pub variant: String,
    /// Wall time, ms (after a backend sync, so device work is included).
    pub ms: f64,
    /// Whether the stage refitted the previous frame's structure instead of building anew
    /// ([`crate::Intersector::refit`]).
    pub refit: bool,
    /// Bytes of the tables the stage built for the scene, where it reports them (a ray
    /// generator's hemisphere set, [`crate::RayGen::table_bytes`]); 0 otherwise.
    #[serde(default)]
    pub bytes: u64,
}

impl<B: Backend> Pipeline<B> {
    /// Renders one frame ([`render_frame`]).
    pub fn render(
        &self,
        backend: &B,
        opts: &FrameOptions,
        reference: Option<&dyn Intersector<B>>,
        progress: &mut dyn FnMut(Progress),
    ) -> Result<Frame<B>> {
        render_frame(backend, self, opts, reference, progress)
    }
}

/// A progress report, sent before each batch.
#[derive(Clone, Debug)]
pub struct Progress {
    /// Steps done so far.
    pub step: u32,
    /// Steps in the frame, if every bounce runs.
    pub total_steps: u32,
    /// What is about to run (`primary`, `shadow d=1`, ...).
    pub message: String,
}

/// A rendered frame.
pub struct Frame<B: Backend> {
    /// Linear HDR RGBA, row-major, `y = 0` the top row.
    pub image: B::Buffer<[f32; 4]>,
    /// What the frame measured.
    pub stats: Stats,
    /// With [`FrameOptions::primary_triangles`]: the triangle each pixel's primary hit is on,
    /// row-major ([`crate::NO_HIT`] for the background).
    pub primary_triangles: Option<Vec<u32>>,
}

/// Maximum image side the driver accepts (guards absurd sizes before allocation).
pub const MAX_IMAGE_SIDE: u32 = 16384;

/// Maximum bounce depth the driver accepts: deeper Whitted trees only add rays that carry no
/// light.
pub const MAX_DEPTH: u32 = 64;

/// Renders one frame of `pipeline` on `backend`, at the frame size it was built for. With
/// `reference`, every traced batch is also traced by the reference intersector (untimed) and
/// [`Stats::accuracy`] is filled. [`Stats::stages`] records the name of every stage that ran.
pub fn render_frame<B: Backend>(
    backend: &B,
    pipeline: &Pipeline<B>,
    opts: &FrameOptions,
    reference: Option<&dyn Intersector<B>>,
    progress: &mut dyn FnMut(Progress),
) -> Result<Frame<B>> {
    let stages = &pipeline.stages;
    let size = FrameSize::new(pipeline.frame.width, pipeline.frame.height)?;
    if opts.max_depth > MAX_DEPTH {
        return Err(CoreError::InvalidInput(format!(
            "bounce depth {} is above {MAX_DEPTH}",
            opts.max_depth
        )));
    }
    stages.check()?;
    let mut driver = Driver {
        backend,
        stages,
        triangles: pipeline.triangles,
        reference,
        stats: Stats {
            stages: stages.names(),
            ..Stats::default()
        },
        step: 0,
        total_steps: 1
            + (opts.max_depth + 1)
            + stages.raygen.bounce_kinds().len() as u32 * opts.max_depth,
        untimed_ms: 0.0,
    };
    if reference.is_some() {
        driver.stats.accuracy = Some(AccuracyCounts::default());
    }
    let frame_start = Instant::now();
    let pixels = size.pixels();
    let mut image = backend.filled(pixels, [0.0f32; 4])?;

    driver.report(progress, "primary visibility".into());
    let tests_before = driver.stats.tests;
    let t_primary = Instant::now();
    let mut surfaces = driver.timed("primary", |s| {
        stages
            .primary
            .gbuffer_with(backend, size.width, size.height, &*stages.intersector, s)
    })?;
    let primary_ms = t_primary.elapsed().as_secs_f64() * 1e3;
    let primary_triangles = if opts.primary_triangles {
        let t = Instant::now();
        let tris = backend
            .download(&surfaces)?
            .iter()
            .map(|s| s.tri)
            .collect::<Vec<u32>>();
        driver.untimed_ms += t.elapsed().as_secs_f64() * 1e3;
        Some(tris)
    } else {
        None
    };
    driver.stats.rays.add(RayKind::Primary, pixels as u64);
    let casts = stages.primary.casts_rays();
    if casts {
        driver.stats.traced_rays += pixels as u64;
        driver.stats.tests.brute_force += pixels as u64 * driver.triangles;
    }
    let after = driver.stats.tests;
    let ks = driver.stats.per_kind.entry("primary".into()).or_default();
    ks.rays += pixels as u64;
    ks.bounds += after.bounds - tests_before.bounds;
    ks.ray_triangle += after.ray_triangle - tests_before.ray_triangle;
    ks.inner_nodes += after.inner_nodes - tests_before.inner_nodes;
    ks.leaves += after.leaves - tests_before.leaves;
    if casts {
        ks.trace_ms += primary_ms;
    }
    let g = driver.stats.generation_mut(0, RayKind::Primary);
    g.rays += pixels as u64;
    g.bounds += after.bounds - tests_before.bounds;
    g.ray_triangle += after.ray_triangle - tests_before.ray_triangle;
    if casts {
        g.trace_ms += primary_ms;
    }

    let visibility = stages.raygen.visibility_kind();
    let visibility_mode = stages.raygen.visibility_mode();
    if visibility_mode == HitMode::Closest {
        return Err(CoreError::Incompatible {
            slots: "raygen".into(),
            reason: format!(
                "raygen `{}` asks for nearest hits of its {} rays; direct light needs an \
                 any-hit or edge-width query",
                stages.raygen.name(),
                visibility.name()
            ),
        });
    }
    if visibility.hit_mode() != HitMode::Any {
        return Err(CoreError::Incompatible {
            slots: "raygen".into(),
            reason: format!(
                "raygen `{}` shades with {} rays, which need the nearest hit; direct light needs an any-hit kind",
                stages.raygen.name(),
                visibility.name()
            ),
        });
    }
    let bounce_kinds = stages.raygen.bounce_kinds().to_vec();
    for depth in 0..=opts.max_depth {
        driver.report(
            progress,
            format!("{} rays, bounce {depth}", visibility.name()),
        );
        let shadow = driver.timed("ray_creation", |s| {
            stages.raygen.generate(backend, &surfaces, visibility, s)
        })?;
        let shadow_hits =
            driver.trace(visibility, visibility_mode, depth + 1, &shadow, &surfaces)?;
        driver.timed("shading", |s| {
            stages.shader.shade_direct(
                backend,
                &surfaces,
                &shadow,
                &shadow_hits,
                visibility_mode,
                &mut image,
                s,
            )
        })?;
        if depth == opts.max_depth {
            break;
        }
        if bounce_kinds.is_empty() {
            break;
        }
        let mut next = Vec::new();
        for &kind in &bounce_kinds {
            driver.report(
                progress,
                format!("{} rays, bounce {}", kind.name(), depth + 1),
            );
            let rays = driver.timed("ray_creation", |s| {
                stages.raygen.generate(backend, &surfaces, kind, s)
            })?;
            if backend.len(&rays) == 0 {
                continue;
            }
            let hits = driver.trace(kind, kind.hit_mode(), depth + 1, &rays, &surfaces)?;
            next.push(driver.timed("shading", |s| {
                stages.shader.resolve(backend, &rays, &hits, s)
            })?);
        }
        surfaces = backend.concat(next)?;
        if backend.len(&surfaces) == 0 {
            break;
        }
    }
    backend.sync()?;
    let untimed_ms = driver.untimed_ms;
    let mut stats = driver.stats;
    let reference_ms = stats.timings_ms.get("reference").copied().unwrap_or(0.0);
    stats.timings_ms.insert(
        "total".into(),
        frame_start.elapsed().as_secs_f64() * 1e3 - reference_ms - untimed_ms,
    );
    progress(Progress {
        step: driver.total_steps,
        total_steps: driver.total_steps,
        message: "done".into(),
    });
    Ok(Frame {
        image,
        stats,
        primary_triangles,
    })
}

struct Driver<'a, B: Backend> {
    backend: &'a B,
    stages: &'a Stages<B>,
    triangles: u64,
    reference: Option<&'a dyn Intersector<B>>,
    stats: Stats,
    step: u32,
    total_steps: u32,
    /// Measuring work outside the stages (the node half-angle histograms), left out of
    /// `total` as the reference tracing is.
    untimed_ms: f64,
}

impl<B: Backend> Driver<'_, B> {
    fn report(&mut self, progress: &mut dyn FnMut(Progress), message: String) {
        progress(Progress {
            step: self.step,
            total_steps: self.total_steps,
            message,
        });
        self.step += 1;
    }

    /// [`timed`] on the frame's stats.
    fn timed<T>(&mut self, key: &str, f: impl FnOnce(&mut Stats) -> Result<T>) -> Result<T> {
        timed(self.backend, &mut self.stats, key, f)
    }

    /// Traces one batch of `kind` rays of bounce depth `generation` with hit query `mode`
    /// through the optional hierarchy stages and the intersector. `surfaces` are the records
    /// the rays were spawned from (their [`Ray::source`]), for the self-hit count of the
    /// accuracy pass.
    fn trace(
        &mut self,
        kind: RayKind,
        mode: HitMode,
        generation: u32,
        rays: &B::Buffer<Ray>,
        surfaces: &B::Buffer<Surface>,
    ) -> Result<B::Buffer<Hit>> {
        let backend = self.backend;
        let n = backend.len(rays);
        // `raygen.order = shuffled`: trace the batch permuted, hand the hits back in
        // generation order. The permutation is how the rays are posed, not a stage of the
        // pipeline, so it is left out of the frame's time like the reference pass.
        let t = Instant::now();
        let shuffle = match self.stages.order.permutation(n, kind, generation) {
            Some(perm) => {
                let perm = backend.upload(&perm)?;
                let shuffled = backend.gather(rays, &perm)?;
                backend.sync()?;
                Some((perm, shuffled))
            }
            None => None,
        };
        self.untimed_ms += t.elapsed().as_secs_f64() * 1e3;
        let rays = shuffle.as_ref().map_or(rays, |(_, r)| r);
        let tests_before = self.stats.tests;
        let t0 = Instant::now();
        let (hits, histogram_ms) = trace_batch_in(
            backend,
            self.stages,
            kind,
            mode,
            Some(generation),
            rays,
            &mut self.stats,
        )?;
        let elapsed = t0.elapsed().as_secs_f64() * 1e3 - histogram_ms;
        self.untimed_ms += histogram_ms;
        let after = self.stats.tests;
        let g = self.stats.generation_mut(generation, kind);
        g.rays += n as u64;
        g.bounds += after.bounds - tests_before.bounds;
        g.ray_triangle += after.ray_triangle - tests_before.ray_triangle;
        g.trace_ms += elapsed;
        self.stats.rays.add(kind, n as u64);
        self.stats.traced_rays += n as u64;
        self.stats.tests.brute_force += n as u64 * self.triangles;
        let ks = self.stats.per_kind.entry(kind.name().into()).or_default();
        ks.rays += n as u64;
        ks.bounds += after.bounds - tests_before.bounds;
        ks.ray_triangle += after.ray_triangle - tests_before.ray_triangle;
        ks.inner_nodes += after.inner_nodes - tests_before.inner_nodes;
        ks.leaves += after.leaves - tests_before.leaves;
        ks.trace_ms += elapsed;

        if let (Some(reference), true) = (self.reference, n > 0) {
            let t = Instant::now();
            let mut ref_hits = backend.filled(n, Hit::MISS)?;
            let mut scratch = Stats::default();
            reference.intersect(
                backend,
                rays,
                Query::Scene,
                mode,
                &mut ref_hits,
                &mut scratch,
            )?;
            let got = backend.download(&hits)?;
            let want = backend.download(&ref_hits)?;
            let acc = self
                .stats
                .accuracy
                .get_or_insert_with(AccuracyCounts::default);
            compare_hits(&got, &want, mode, acc);
            let rays = backend.download(rays)?;
            let surfaces = backend.download(surfaces)?;
            acc.self_hits += count_self_hits(&rays, &got, &surfaces);
            self.stats.add_time("reference", t.elapsed());
        }
        match shuffle {
            Some((perm, _)) => {
                let t = Instant::now();
                let hits = backend.scatter(&hits, &perm)?;
                backend.sync()?;
                self.untimed_ms += t.elapsed().as_secs_f64() * 1e3;
                Ok(hits)
            }
            None => Ok(hits),
        }
    }
}

/// Traces one batch of rays of `kind` with the tracing stages of `stages`: hash, sort, build the
/// ray-space hierarchy and traverse it, with the intersector's final tests on the candidates
/// (when the pipeline has a hierarchy), or the intersector on the whole scene, on the batch in
/// sorted order when the pipeline hashes and sorts without a hierarchy (`reordering` times
/// the gather and the scatter of the hits back). Returns one hit
/// per ray (any hit for shadow rays, the nearest for the others). Adds the counters and the
/// stage times (`hashing`, `sorting`, `hierarchy_creation`, `traversal`, `final_tests` or
/// `intersection`) to `stats`, but not the per-kind ray counts, which [`render_frame`] keeps.
///
/// This is what [`render_frame`] runs for every batch; tools that make their own rays (the
/// stability suite, benchmarks of one stage) call it directly.
pub fn trace_batch<B: Backend>(
    backend: &B,
    stages: &Stages<B>,
    kind: RayKind,
    rays: &B::Buffer<Ray>,
    stats: &mut Stats,
) -> Result<B::Buffer<Hit>> {
    trace_batch_in(backend, stages, kind, kind.hit_mode(), None, rays, stats).map(|(hits, _)| hits)
}

/// [`trace_batch`] with the hit query `mode`; with `generation`, also adds the cone
/// half-angles of the hierarchy's lowest nodes to that generation's
/// [`crate::GenerationStats`] (a download of `levels[0]`, outside every stage timer). Returns
/// the hits and the ms that took.
fn trace_batch_in<B: Backend>(
    backend: &B,
    stages: &Stages<B>,
    kind: RayKind,
    mode: HitMode,
    generation: Option<u32>,
    rays: &B::Buffer<Ray>,
    stats: &mut Stats,
) -> Result<(B::Buffer<Hit>, f64)> {
    stages.check()?;
    let n = backend.len(rays);
    let mut hits = backend.filled(n, Hit::MISS)?;
    let mut histogram_ms = 0.0;
    if n == 0 {
        return Ok((hits, histogram_ms));
    }
    if let (Some(builder), Some(traverser)) = (&stages.hierarchy, &stages.traverser) {
        let order = match sorted_order(backend, stages, kind, rays, stats)? {
            Some(order) => order,
            None => backend.upload(&(0..n as u32).collect::<Vec<u32>>())?,
        };
        let hierarchy = timed(backend, stats, "hierarchy_creation", |s| {
            builder.build(backend, rays, order, s)
        })?;
        if let (Some(generation), Some(lowest)) = (generation, hierarchy.levels.first()) {
            let t = Instant::now();
            let nodes = backend.download(lowest)?;
            stats
                .generation_mut(generation, kind)
                .add_half_angles(nodes.iter().map(|n| n.cone.half_angle));
            histogram_ms = t.elapsed().as_secs_f64() * 1e3;
        }
        let intersector = &stages.intersector;
        if intersector.candidate_test().is_some() {
            // A traverser that runs the final tests itself: one `traversal` stage.
            let traced = timed(backend, stats, "traversal", |s| {
                traverser
                    .trace(
                        backend,
                        rays,
                        kind,
                        mode,
                        &**intersector,
                        &hierarchy,
                        &mut hits,
                        s,
                    )
                    .transpose()
            })?;
            if traced.is_some() {
                return Ok((hits, histogram_ms));
            }
        }
        let mut final_tests = std::time::Duration::ZERO;
        let t_trav = Instant::now();
        backend.begin_stage("traversal");
        let traversed = traverser
            .traverse(
                backend,
                rays,
                kind,
                &hierarchy,
                &mut |batch, stats| {
                    let t = Instant::now();
                    backend.begin_stage("final_tests");
                    let q = Query::Candidates {
                        hierarchy: &hierarchy,
                        batch: &batch,
                    };
                    let done = intersector
                        .intersect(backend, rays, q, mode, &mut hits, stats)
                        .and_then(|_| backend.sync());
                    let device = backend.end_stage();
                    done?;
                    add_device_times(stats, device?);
                    final_tests += t.elapsed();
                    Ok(())
                },
                stats,
            )
            .and_then(|_| backend.sync());
        let device = backend.end_stage();
        traversed?;
        add_device_times(stats, device?);
        stats.add_time("traversal", t_trav.elapsed().saturating_sub(final_tests));
        stats.add_time("final_tests", final_tests);
    } else if let Some(order) = sorted_order(backend, stages, kind, rays, stats)? {
        // Sorted whole-scene tracing: the intersector sees the batch in key order (coherent
        // packets for a packet tracer), and the hits go back to the batch's order.
        let sorted = timed(backend, stats, "reordering", |_| {
            backend.gather(rays, &order)
        })?;
        let mut sorted_hits = backend.filled(n, Hit::MISS)?;
        timed(backend, stats, "intersection", |s| {
            stages
                .intersector
                .intersect(backend, &sorted, Query::Scene, mode, &mut sorted_hits, s)
        })?;
        hits = timed(backend, stats, "reordering", |_| {
            backend.scatter(&sorted_hits, &order)
        })?;
    } else {
        timed(backend, stats, "intersection", |s| {
            stages
                .intersector
                .intersect(backend, rays, Query::Scene, mode, &mut hits, s)
        })?;
    }
    Ok((hits, histogram_ms))
}

/// The batch's order by the keys of the pipeline's hasher and sorter (stages `hashing` and
/// `sorting`), or `None` when it has neither.
fn sorted_order<B: Backend>(
    backend: &B,
    stages: &Stages<B>,
    kind: RayKind,
    rays: &B::Buffer<Ray>,
    stats: &mut Stats,
) -> Result<Option<B::Buffer<u32>>> {
    let (Some(hasher), Some(sorter)) = (&stages.hasher, &stages.sorter) else {
        return Ok(None);
    };
    let keys = timed(backend, stats, "hashing", |s| {
        hasher.hash(backend, rays, kind, s)
    })?;
    timed(backend, stats, "sorting", |s| {
        sorter.sort(backend, &keys, hasher.key_bits(), s)
    })
    .map(Some)
}

/// Runs `f` as stage `key`: adds its wall time (after a backend sync) to `stats.timings_ms[key]`,
/// less whatever sub-stage times `f` recorded in `stats` itself (the compress sorter's
/// `compression` / `decompression`, ray generation's `trimming`), so stage keys never overlap
/// and add up to the frame time; and brackets it with [`Backend::begin_stage`] /
/// [`Backend::end_stage`], adding the device times the backend measured to
/// `stats.device_timings_ms`. Stages call it themselves for their sub-stages.
pub fn timed<B: Backend, T>(
    backend: &B,
    stats: &mut Stats,
    key: &str,
    f: impl FnOnce(&mut Stats) -> Result<T>,
) -> Result<T> {
    let recorded = |s: &Stats| s.timings_ms.values().sum::<f64>();
    let before = recorded(stats);
    let t0 = Instant::now();
    backend.begin_stage(key);
    let out = f(stats).and_then(|out| backend.sync().map(|_| out));
    let device = backend.end_stage();
    let out = out?;
    add_device_times(stats, device?);
    let nested = (recorded(stats) - before).max(0.0);
    let own = (t0.elapsed().as_secs_f64() * 1e3 - nested).max(0.0);
    *stats.timings_ms.entry(key.to_string()).or_insert(0.0) += own;
    Ok(out)
}

fn add_device_times(stats: &mut Stats, times: Vec<(String, f64)>) {
    for (key, ms) in times {
        *stats.device_timings_ms.entry(key).or_insert(0.0) += ms;
    }
}

/// Secondary rays whose reported hit is the very triangle of the surface they were spawned
/// from ([`Ray::source`] into `surfaces`): a straight ray meets a plane once, at its origin
/// surface point, so such a hit is always a self-intersection (shadow acne, a reflection that
/// finds its own face). A lower bound: hits on a neighbouring triangle of a curved mesh, or an
/// any-hit query that reports another occluder first, are not counted.
pub fn count_self_hits(rays: &[Ray], hits: &[Hit], surfaces: &[Surface]) -> u64 {
    rays.iter()
        .zip(hits)
        .filter(|(r, h)| {
            h.is_hit()
                && surfaces
                    .get(r.source as usize)
                    .is_some_and(|s| s.is_hit() && s.tri == h.tri)
        })
        .count() as u64
}

/// Adds the agreement of `got` with `want` (same rays) to `acc`: hit/miss must agree, for
/// closest-hit queries the triangle must match unless both `t` agree within 1e-6 relative,
/// and for edge-width queries the occlusion (`u`) must be the same bit for bit (a different
/// one counts in [`AccuracyCounts::nearest_mismatches`]).
pub fn compare_hits(got: &[Hit], want: &[Hit], mode: HitMode, acc: &mut AccuracyCounts) {
    for (a, b) in got.iter().zip(want) {
        acc.rays += 1;
        if a.is_hit() != b.is_hit() {
            acc.hit_miss_mismatches += 1;
        } else if (mode == HitMode::Closest && a.is_hit() && a.nearest_differs(b))
            || (mode.is_edge_width() && a.is_hit() && a.u.to_bits() != b.u.to_bits())
        {
            acc.nearest_mismatches += 1;
        } else {
            acc.agreeing += 1;
            if mode == HitMode::Closest && a.is_hit() {
                acc.t_compared += 1;
                acc.t_abs_error_sum += (a.t as f64 - b.t as f64).abs();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bytemuck::Zeroable;

    fn hit(t: f32, tri: u32) -> Hit {
        Hit {
            t,
            tri,
            u: 0.0,
            v: 0.0,
        }
    }

    #[test]
    fn comparison_rules() {
        let mut acc = AccuracyCounts::default();
        compare_hits(
            &[hit(1.0, 1), hit(1.0, 2), Hit::MISS, hit(2.0, 3)],
            &[hit(1.0, 1), hit(1.0000001, 5), hit(1.0, 1), hit(3.0, 4)],
            HitMode::Closest,
            &mut acc,
        );
        assert_eq!(acc.rays, 4);
        assert_eq!(acc.agreeing, 2);
        assert_eq!(acc.hit_miss_mismatches, 1);
        assert_eq!(acc.nearest_mismatches, 1);
        assert_eq!(acc.t_compared, 2);
        assert!((acc.mean_abs_t_error() - 0.5e-7).abs() < 1e-8);
        let mut any = AccuracyCounts::default();
        compare_hits(&[hit(2.0, 3)], &[hit(3.0, 4)], HitMode::Any, &mut any);
        assert_eq!(any.hit_agreement(), 1.0);
    }

    #[test]
    fn self_hits_are_hits_on_the_source_triangle() {
        let surface = |tri| Surface {
            tri,
            ..Surface::background(0, glam::Vec3::Z, glam::Vec3::ONE, 0)
        };
        let surfaces = [surface(7), surface(8), surface(crate::NO_HIT)];
        let ray = |source| Ray {
            source,
            ..Ray::zeroed()
        };
        let rays = [ray(0), ray(0), ray(1), ray(2), ray(9)];
        let hits = [
            hit(1e-6, 7),
            hit(1.0, 3),
            Hit::MISS,
            hit(1.0, 7),
            hit(1.0, 7),
        ];
        // Only the first: the second hits another triangle, the third misses, the fourth's
        // source is a background record and the fifth's source does not exist.
        assert_eq!(count_self_hits(&rays, &hits, &surfaces), 1);
    }
}
