//! Runs the stability suite ([`crsh_scene::stress`]) against CPU pipelines: one
//! [`StressOutcome`] per case × pipeline × `intersect.test` × `raygen.offset`.
//!
//! For a [`Probe::Rays`] case the explicit rays go through the pipeline's tracing stages
//! ([`trace_batch`]: hash, sort, hierarchy, traversal and final tests, or the intersector on
//! the whole scene); for a [`Probe::Frame`] case the pipeline's primary stage renders the
//! G-buffer, its ray generator makes every secondary kind from it (one bounce), and each batch
//! is traced the same way (shadow rays with any-hit semantics). Everything runs under
//! `catch_unwind`, so a panic becomes a row, not a crash. The truth is the case's own
//! expectation, or the f64 reference intersector `brute64` on the very same rays.
//!
//! Counting rules (each ray lands in at most one column):
//! - **escape**: a ray that must hit (inside a closed mesh, aimed at a shared edge or vertex)
//!   missed;
//! - **false miss**: the truth hits, the pipeline missed (rays that are not escapes);
//! - **self-intersection**: a secondary ray found the surface it leaves (any hit in an
//!   [`FrameTruth::Unoccluded`] frame; a hit on the source triangle the reference does not
//!   report in a [`FrameTruth::Reference`] frame);
//! - **false hit**: the truth misses (or the ray is invalid), the pipeline hit;
//! - **wrong nearest**: both hit, on different triangles at `t` more than 1e-6 relative apart
//!   ([`Hit::nearest_differs`], the rule of `crsh_core::pipeline::compare_hits`; closest-hit
//!   queries only).

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::Arc;
use std::time::{Duration, Instant};

use crsh_core::{
    trace_batch, CoreError, FrameSize, Hit, HitMode, Intersector, PipelineConfig, Query, Ray,
    RayKind, Registry, Result, StageContext, StageKind, StageSpec, Stats, Surface,
};
use crsh_scene::stress::{Expect, FrameTruth, Probe, StressCase};
use crsh_scene::Scene;
use serde::{Deserialize, Serialize};

use crate::backend::Cpu;

/// What one case did under one pipeline configuration.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StressOutcome {
    /// Rays traced (explicit rays, or every secondary ray of the frame).
    pub rays: u64,
    /// The truth hits, the pipeline missed (escapes excluded).
    pub false_misses: u64,
    /// The truth misses (or the ray is invalid), the pipeline hit.
    pub false_hits: u64,
    /// Both hit, on different triangles at a `t` more than 1e-6 relative apart.
    pub wrong_nearest: u64,
    /// Secondary rays that found the surface they leave.
    pub self_intersections: u64,
    /// Rays that had to hit (closed mesh, shared edge or vertex) and missed.
    pub escapes: u64,
    /// Bounding tests of the tracing (BVH nodes, hierarchy nodes, grid cells visited; the
    /// truth excluded).
    #[serde(default)]
    pub bounds_tests: u64,
    /// Ray-triangle tests of the tracing (the truth excluded).
    #[serde(default)]
    pub triangle_tests: u64,
    /// Wall time of the tracing (stage construction, primary visibility and ray generation
    /// excluded; the truth excluded), milliseconds.
    pub time_ms: f64,
    /// The error that stopped the case (scene rejected, stage refused the input), if any.
    pub error: Option<String>,
    /// Whether a stage panicked (always a bug).
    pub panicked: bool,
}

impl StressOutcome {
    /// Sum of every wrong-answer column.
    pub fn failures(&self) -> u64 {
        self.false_misses
            + self.false_hits
            + self.wrong_nearest
            + self.self_intersections
            + self.escapes
    }

    /// `count / rays` (0 when no rays were traced).
    pub fn rate(&self, count: u64) -> f64 {
        if self.rays == 0 {
            0.0
        } else {
            count as f64 / self.rays as f64
        }
    }

    /// Bounding plus ray-triangle tests per traced ray (0 when no rays were traced): the cost
    /// of an acceleration structure on the case, e.g. a uniform grid's on a detailed object in
    /// a huge sparse scene (seed 002's teapot in a stadium, `stadium/teapot`).
    pub fn tests_per_ray(&self) -> f64 {
        self.rate(self.bounds_tests + self.triangle_tests)
    }

    /// Adds `other`'s counts and time (not its error or panic flag).
    pub fn accumulate(&mut self, other: &StressOutcome) {
        self.rays += other.rays;
        self.false_misses += other.false_misses;
        self.false_hits += other.false_hits;
        self.wrong_nearest += other.wrong_nearest;
        self.self_intersections += other.self_intersections;
        self.escapes += other.escapes;
        self.bounds_tests += other.bounds_tests;
        self.triangle_tests += other.triangle_tests;
        self.time_ms += other.time_ms;
    }
}

/// One pipeline configuration of the suite: a preset with an optional `intersect.test` and
/// `raygen.offset` (`None`: the registry's default, or a registry without that parameter).
#[derive(Clone, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
pub struct Variant {
    /// Preset name (one of the registry's presets).
    pub pipeline: String,
    /// `intersect.test` choice.
    pub test: Option<String>,
    /// `raygen.offset` choice.
    pub offset: Option<String>,
}

/// One row of the suite's table.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StressRow {
    /// Case name.
    pub case: String,
    /// Case family.
    pub family: String,
    /// The configuration it ran under. `offset` is `None` for ray probes, which do not use
    /// the ray generator.
    pub variant: Variant,
    /// What happened.
    pub outcome: StressOutcome,
}

fn choices(registry: &Registry<Cpu>, stage: StageKind, variant: &str, param: &str) -> Vec<String> {
    registry
        .variant(stage, variant)
        .into_iter()
        .flat_map(|v| v.params.iter())
        .filter(|p| p.name == param)
        .flat_map(|p| p.choices.iter().map(|c| c.to_string()))
        .collect()
}

/// The ray-triangle test policies `registry` offers (choices of `intersect.test` on the `brute`
/// intersector); empty in a registry without that parameter.
pub fn intersect_tests(registry: &Registry<Cpu>) -> Vec<String> {
    choices(registry, StageKind::Intersect, "brute", "test")
}

/// The presets the suite's expectations are for: those this build can construct whose
/// intersector runs one of crsh's ray-triangle tests (it takes the `intersect.test`
/// parameter). Embree's own test is checked against brute force in its unit tests instead,
/// where the rays it answers differently (in a triangle's plane) are asserted by kind.
pub fn suite_presets(registry: &Registry<Cpu>) -> Vec<String> {
    registry
        .available_presets()
        .filter(|p| {
            registry
                .variant(StageKind::Intersect, &p.config.intersect.kind)
                .is_some_and(|v| v.params.iter().any(|q| q.name == "test"))
        })
        .map(|p| p.name.clone())
        .collect()
}

/// The origin-offset policies `registry` offers (choices of `raygen.offset` on `whitted`);
/// empty in a registry without that parameter.
pub fn offset_policies(registry: &Registry<Cpu>) -> Vec<String> {
    choices(registry, StageKind::Raygen, "whitted", "offset")
}

/// The pipeline of `variant`: the registry's preset with `intersect.test` and `raygen.offset`
/// set the way `--set` does, resolved against the registry (unknown names are errors).
pub fn configure(registry: &Registry<Cpu>, variant: &Variant) -> Result<PipelineConfig> {
    let mut cfg = registry
        .preset(&variant.pipeline)
        .ok_or_else(|| CoreError::UnknownVariant {
            stage: "pipeline".into(),
            name: variant.pipeline.clone(),
            known: registry
                .presets()
                .iter()
                .map(|p| p.name.as_str())
                .collect::<Vec<_>>()
                .join(", "),
        })?;
    if let Some(t) = &variant.test {
        cfg.set(&format!("intersect.test={t}"))?;
    }
    if let Some(o) = &variant.offset {
        cfg.set(&format!("raygen.offset={o}"))?;
    }
    registry.resolve(&mut cfg)?;
    Ok(cfg)
}

/// Runs `case` under pipeline `cfg` (built by `registry`), catching panics.
pub fn run_case(
    registry: &Registry<Cpu>,
    case: &StressCase,
    cfg: &PipelineConfig,
) -> StressOutcome {
    let scene = match &case.scene {
        Ok(s) => s,
        Err(e) => {
            return StressOutcome {
                error: Some(format!("scene rejected: {e}")),
                ..StressOutcome::default()
            }
        }
    };
    match catch_unwind(AssertUnwindSafe(|| {
        run_probe(registry, scene, &case.probe, cfg)
    })) {
        Ok(Ok(outcome)) => outcome,
        Ok(Err((e, rays))) => StressOutcome {
            rays,
            error: Some(e.to_string()),
            ..StressOutcome::default()
        },
        Err(payload) => {
            let msg = crsh_core::panic_message(payload.as_ref());
            StressOutcome {
                error: Some(format!("panic: {msg}")),
                panicked: true,
                ..StressOutcome::default()
            }
        }
    }
}

type ProbeResult = std::result::Result<StressOutcome, (CoreError, u64)>;

/// The frame size stages are built for when a probe has no frame (explicit rays).
const RAY_PROBE_FRAME: u32 = 64;

fn run_probe(
    registry: &Registry<Cpu>,
    scene: &Arc<Scene>,
    probe: &Probe,
    cfg: &PipelineConfig,
) -> ProbeResult {
    let frame = match probe {
        Probe::Frame { width, height, .. } => FrameSize::new(*width, *height),
        Probe::Rays { .. } => FrameSize::new(RAY_PROBE_FRAME, RAY_PROBE_FRAME),
    }
    .map_err(|e| (e, 0))?;
    let ctx = StageContext::new(&Cpu, scene, frame);
    let pipeline = registry.build(&ctx, cfg).map_err(|e| (e, 0))?;
    let stages = &pipeline.stages;
    // The f64 reference, prepared only for the probes whose truth it is (once per probe).
    let mut reference: Option<Box<dyn Intersector<Cpu>>> = None;
    let mut reference_hits = |rays: &[Ray], kind: RayKind| -> Result<Vec<Hit>> {
        let reference = match &mut reference {
            Some(r) => r,
            none => none.insert(registry.build_intersector(&ctx, &StageSpec::new("brute64"))?),
        };
        let mut hits = vec![Hit::MISS; rays.len()];
        reference.intersect(
            &Cpu,
            &rays.to_vec(),
            Query::Scene,
            kind.hit_mode(),
            &mut hits,
            &mut Stats::default(),
        )?;
        Ok(hits)
    };
    let mut out = StressOutcome::default();
    let mut stats = Stats::default();
    let mut traced = Duration::ZERO;
    // Tests made before tracing (a primary stage that casts rays) are not the probe's.
    let mut base = stats.tests;
    match probe {
        Probe::Rays { kind, rays, expect } => {
            out.rays = rays.len() as u64;
            let t0 = Instant::now();
            let hits = trace_batch(&Cpu, stages, *kind, rays, &mut stats)
                .map_err(|e| (e, rays.len() as u64))?;
            traced += t0.elapsed();
            let truth = if expect.contains(&Expect::Reference) {
                reference_hits(rays, *kind).map_err(|e| (e, out.rays))?
            } else {
                vec![Hit::MISS; rays.len()]
            };
            for (i, (hit, want)) in hits.iter().zip(expect).enumerate() {
                score_expect(&mut out, *want, hit, &truth[i], kind.hit_mode());
            }
        }
        Probe::Frame {
            width,
            height,
            truth,
        } => {
            let surfaces = stages
                .primary
                .gbuffer(&Cpu, *width, *height, &mut stats)
                .map_err(|e| (e, 0))?;
            base = stats.tests;
            for kind in [RayKind::Shadow, RayKind::Reflection, RayKind::Refraction] {
                let rays = stages
                    .raygen
                    .generate(&Cpu, &surfaces, kind, &mut stats)
                    .map_err(|e| (e, out.rays))?;
                if rays.is_empty() {
                    continue;
                }
                out.rays += rays.len() as u64;
                let t0 = Instant::now();
                let hits = trace_batch(&Cpu, stages, kind, &rays, &mut stats)
                    .map_err(|e| (e, out.rays))?;
                traced += t0.elapsed();
                match truth {
                    FrameTruth::Unoccluded => {
                        out.self_intersections += hits.iter().filter(|h| h.is_hit()).count() as u64
                    }
                    FrameTruth::Reference => {
                        let want = reference_hits(&rays, kind).map_err(|e| (e, out.rays))?;
                        for ((ray, hit), want) in rays.iter().zip(&hits).zip(&want) {
                            score_frame(&mut out, ray, hit, want, &surfaces, kind.hit_mode());
                        }
                    }
                }
            }
        }
    }
    out.time_ms = traced.as_secs_f64() * 1e3;
    // Only the traced batches count (the reference has its own stats).
    out.bounds_tests = stats.tests.bounds - base.bounds;
    out.triangle_tests = stats.tests.ray_triangle - base.ray_triangle;
    Ok(out)
}

fn score_expect(
    out: &mut StressOutcome,
    expect: Expect,
    got: &Hit,
    reference: &Hit,
    mode: HitMode,
) {
    match expect {
        Expect::MustHit => out.escapes += u64::from(!got.is_hit()),
        Expect::Miss | Expect::Invalid => out.false_hits += u64::from(got.is_hit()),
        Expect::Nearest { tri, t } => {
            if !got.is_hit() {
                out.false_misses += 1;
            } else if mode == HitMode::Closest
                && got.nearest_differs(&Hit {
                    t,
                    tri,
                    u: 0.0,
                    v: 0.0,
                })
            {
                out.wrong_nearest += 1;
            }
        }
        Expect::Reference => match (got.is_hit(), reference.is_hit()) {
            (false, true) => out.false_misses += 1,
            (true, false) => out.false_hits += 1,
            (true, true) if mode == HitMode::Closest && got.nearest_differs(reference) => {
                out.wrong_nearest += 1
            }
            _ => {}
        },
    }
}

fn score_frame(
    out: &mut StressOutcome,
    ray: &Ray,
    got: &Hit,
    want: &Hit,
    surfaces: &[Surface],
    mode: HitMode,
) {
    let source_tri = surfaces
        .get(ray.source as usize)
        .filter(|s| s.is_hit())
        .map(|s| s.tri);
    if got.is_hit() && Some(got.tri) == source_tri && want.tri != got.tri {
        out.self_intersections += 1;
        return;
    }
    match (got.is_hit(), want.is_hit()) {
        (false, true) => out.false_misses += 1,
        (true, false) => out.false_hits += 1,
        (true, true) if mode == HitMode::Closest && got.nearest_differs(want) => {
            out.wrong_nearest += 1
        }
        _ => {}
    }
}

/// Every configuration of `pipelines` × `tests` × `offsets` (an empty `tests` or `offsets`
/// list means the catalogue default only).
pub fn variants(pipelines: &[String], tests: &[String], offsets: &[String]) -> Vec<Variant> {
    let opt = |v: &[String]| -> Vec<Option<String>> {
        if v.is_empty() {
            vec![None]
        } else {
            v.iter().cloned().map(Some).collect()
        }
    };
    let mut out = Vec::new();
    for p in pipelines {
        for t in opt(tests) {
            for o in opt(offsets) {
                out.push(Variant {
                    pipeline: p.clone(),
                    test: t.clone(),
                    offset: o,
                });
            }
        }
    }
    out
}

/// Runs every case under every variant: rows in case order, then variant order. Ray probes
/// ignore the offset, so they run once per pipeline × test (with the default offset, shown as
/// `offset: None`). `progress` is called before each row with (row, total, case name).
pub fn run_suite(
    registry: &Registry<Cpu>,
    cases: &[StressCase],
    variants: &[Variant],
    progress: &mut dyn FnMut(usize, usize, &str),
) -> Result<Vec<StressRow>> {
    // Configurations are checked up front, so a bad name fails before any work.
    let mut configs = Vec::with_capacity(variants.len());
    for v in variants {
        configs.push((v.clone(), configure(registry, v)?));
    }
    let mut plan = Vec::new();
    for case in cases {
        let mut seen: Vec<Variant> = Vec::new();
        for (v, cfg) in &configs {
            let shown = if case.probe.is_frame() {
                v.clone()
            } else {
                Variant {
                    offset: None,
                    ..v.clone()
                }
            };
            if seen.contains(&shown) {
                continue;
            }
            let cfg = if case.probe.is_frame() || v.offset.is_none() {
                cfg.clone()
            } else {
                configure(registry, &shown)?
            };
            seen.push(shown.clone());
            plan.push((case, shown, cfg));
        }
    }
    let total = plan.len();
    let mut rows = Vec::with_capacity(total);
    for (i, (case, variant, cfg)) in plan.into_iter().enumerate() {
        progress(i, total, &case.name);
        rows.push(StressRow {
            case: case.name.clone(),
            family: case.family.to_string(),
            variant,
            outcome: run_case(registry, case, &cfg),
        });
    }
    Ok(rows)
}
