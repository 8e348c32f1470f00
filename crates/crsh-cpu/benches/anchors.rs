//! Criterion group `anchors`: the tracers users pick, called directly, beside crsh's stages on
//! the very same rays.
//!
//! The batch: the shadow rays of a 1024² G-buffer of the shared Sponza
//! (`$CRSH_SCENES/sponza/sponza.toml`, else `../shared/scenes`), else of a 256² G-buffer of
//! the built-in `cornell-mirrors` (the choice is printed), spawned by the `bvh` preset's
//! `raster` primaries and `whitted` generator, in generation order and shuffled
//! (`raygen.order = shuffled`'s permutation).
//!
//! Ids `anchors/{tracer}/{order}/{scene}`, throughput in rays:
//! - `obvhs_direct_{quality}`: obvhs 0.4 as its README and examples use it, with nothing of
//!   crsh in the loop: `build_cwbvh_from_tris` with the preset, leaf triangles in primitive
//!   order, `CwBvh::ray_traverse_miss` with `Triangle::intersect`, rayon over 64-ray chunks;
//! - `bvh_{quality}`: the `bvh` intersector stage (`intersect.kind = bvh`) with the same
//!   preset on the same rays, exact hits (brute force's), its counters included, into a
//!   `Hit` buffer allocated once and reset to misses in every iteration (the stage merges
//!   into the hits it is given);
//! - `embree_{mode}` (with the `embree` feature): the `embree` stage in single rays and
//!   16-wide coherent packets.
//!
//! Before timing, the bench prints how many rays obvhs direct and `bvh` disagree on (obvhs
//! clamps its node test at `t = 1e-4` and ignores `t_min`, see the `bvh` module doc).
//!
//! Run with `cargo bench -p crsh-cpu --bench anchors` (add `--features embree` for Embree,
//! `-- --quick` for a short run).

use std::sync::Arc;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use crsh_core::glam::Vec3A;
use crsh_core::{
    FrameSize, Hit, HitMode, PipelineConfig, Query, Ray, RayKind, RayOrder, Registry, StageContext,
    StageSpec, Stats,
};
use crsh_cpu::intersect::bvh::BuildQuality;
use crsh_cpu::Cpu;
use crsh_scene::Scene;
use obvhs::cwbvh::builder::build_cwbvh_from_tris;
use obvhs::triangle::Triangle;
use rayon::prelude::*;

mod common;
use common::shared_scene;

/// obvhs called directly: its own CWBVH builder and traversal, its own triangle test.
struct ObvhsDirect {
    bvh: obvhs::cwbvh::CwBvh,
    tris: Vec<Triangle>,
}

impl ObvhsDirect {
    fn new(scene: &Scene, quality: BuildQuality) -> ObvhsDirect {
        let tris: Vec<Triangle> = (0..scene.triangle_count())
            .map(|t| {
                let [a, b, c] = scene.triangle(t);
                Triangle {
                    v0: a.into(),
                    v1: b.into(),
                    v2: c.into(),
                }
            })
            .collect();
        let bvh = build_cwbvh_from_tris(&tris, quality.params(), &mut Duration::default());
        let tris = bvh
            .primitive_indices
            .iter()
            .map(|&i| tris[i as usize])
            .collect();
        ObvhsDirect { bvh, tris }
    }

    /// The `t` of `ray`'s hit on leaf triangle `id` inside `(tmin, tmax]`, else infinity:
    /// what `ray_traverse_miss` asks of its closure.
    #[inline(always)]
    fn hit_t(&self, ray: &obvhs::ray::Ray, id: usize) -> f32 {
        let t = self.tris[id].intersect(ray);
        if t > ray.tmin {
            t
        } else {
            f32::INFINITY
        }
    }

    /// Triangle tests of [`ObvhsDirect::occluded`] on `rays` (untimed, for the printout).
    fn tests(&self, rays: &[Ray]) -> u64 {
        use std::sync::atomic::{AtomicU64, Ordering};
        let n = AtomicU64::new(0);
        rays.par_iter().for_each(|r| {
            let ray = obvhs::ray::Ray::new(r.origin.into(), r.dir.into(), r.t_min, r.t_max);
            let mut k = 0;
            self.bvh.ray_traverse_miss(ray, |ray, id| {
                k += 1;
                self.hit_t(ray, id)
            });
            n.fetch_add(k, Ordering::Relaxed);
        });
        n.into_inner()
    }

    /// Sets `out[i]` to whether ray `i` is occluded (any hit in its interval).
    fn occluded(&self, rays: &[Ray], out: &mut [bool]) {
        rays.par_chunks(64)
            .zip(out.par_chunks_mut(64))
            .for_each(|(rs, os)| {
                for (r, o) in rs.iter().zip(os) {
                    let ray = obvhs::ray::Ray::new(
                        Vec3A::from(r.origin),
                        Vec3A::from(r.dir),
                        r.t_min,
                        r.t_max,
                    );
                    *o = !self
                        .bvh
                        .ray_traverse_miss(ray, |ray, id| self.hit_t(ray, id));
                }
            });
    }
}

fn benches(c: &mut Criterion) {
    let (tag, size, scene) = match shared_scene("sponza/sponza.toml") {
        Some(path) => {
            let scene = crsh_scene::load_path(&path)
                .unwrap_or_else(|e| panic!("loading {}: {e}", path.display()));
            eprintln!("anchors scene: sponza ({})", path.display());
            ("sponza", 1024, scene)
        }
        None => {
            eprintln!(
                "anchors scene: built-in cornell-mirrors (sponza/sponza.toml not found under \
                 CRSH_SCENES or ../shared/scenes)"
            );
            (
                "cornell-mirrors",
                256,
                crsh_scene::load("cornell-mirrors").expect("built-in scene"),
            )
        }
    };
    let scene = Arc::new(scene);
    let ctx = StageContext::new(&Cpu, &scene, FrameSize::new(size, size).expect("size"));
    let registry = Registry::<Cpu>::builtin();
    let cfg: PipelineConfig = registry.preset("bvh").expect("the bvh preset");
    let st = registry.build(&ctx, &cfg).expect("bvh pipeline").stages;
    let mut stats = Stats::default();
    let surfaces = st
        .primary
        .gbuffer(&Cpu, size, size, &mut stats)
        .expect("G-buffer");
    let rays = st
        .raygen
        .generate(&Cpu, &surfaces, RayKind::Shadow, &mut stats)
        .expect("shadow rays");
    let perm = RayOrder::Shuffled { seed: 1 }
        .permutation(rays.len(), RayKind::Shadow, 1)
        .expect("a permutation");
    let shuffled = crsh_core::order::gather(&rays, &perm).expect("a permutation of the batch");
    eprintln!(
        "anchors batch: {} triangles, {size}x{size} G-buffer, {} shadow rays",
        scene.triangle_count(),
        rays.len()
    );

    let mut g = c.benchmark_group("anchors");
    g.throughput(Throughput::Elements(rays.len() as u64));
    g.sample_size(10);
    for quality in [BuildQuality::Medium, BuildQuality::VerySlow] {
        let q = BuildQuality::NAMES[quality as usize];
        let direct = ObvhsDirect::new(&scene, quality);
        let mut spec = StageSpec::new("bvh");
        spec.params.insert(
            "build_quality".into(),
            crsh_core::ParamValue::Str(q.to_string()),
        );
        let bvh = registry
            .build_intersector(&ctx, &spec)
            .expect("the bvh stage");
        // Into the caller's buffer, which the stage's contract has start as misses.
        let traced = |rays: &Vec<Ray>, hits: &mut Vec<Hit>, stats: &mut Stats| {
            hits.fill(Hit::MISS);
            bvh.intersect(&Cpu, rays, Query::Scene, HitMode::Any, hits, stats)
                .expect("bvh");
        };
        let mut counted = Stats::default();
        let mut ours = vec![Hit::MISS; rays.len()];
        traced(&rays, &mut ours, &mut counted);
        let mut theirs = vec![false; rays.len()];
        direct.occluded(&rays, &mut theirs);
        let differ = ours
            .iter()
            .zip(&theirs)
            .filter(|(h, o)| h.is_hit() != **o)
            .count();
        eprintln!(
            "anchors {q}: obvhs direct and bvh disagree on {differ} of {} rays; triangle \
             tests: obvhs direct {}, bvh {} (and {} box tests)",
            rays.len(),
            direct.tests(&rays),
            counted.tests.ray_triangle,
            counted.tests.bounds,
        );
        for (order, batch) in [("generation", &rays), ("shuffled", &shuffled)] {
            g.bench_function(format!("obvhs_direct_{q}/{order}/{tag}"), |b| {
                b.iter(|| direct.occluded(batch, &mut theirs))
            });
            g.bench_function(format!("bvh_{q}/{order}/{tag}"), |b| {
                b.iter(|| traced(batch, &mut ours, &mut Stats::default()))
            });
        }
    }
    if crsh_cpu::intersect::embree::AVAILABLE {
        let mut hits = vec![Hit::MISS; rays.len()];
        for (mode, coherent) in [("single", false), ("packet16", true)] {
            let mut spec = StageSpec::new("embree");
            spec.params
                .insert("mode".into(), crsh_core::ParamValue::Str(mode.into()));
            spec.params
                .insert("coherent".into(), crsh_core::ParamValue::Bool(coherent));
            let embree = registry
                .build_intersector(&ctx, &spec)
                .expect("the embree stage");
            for (order, batch) in [("generation", &rays), ("shuffled", &shuffled)] {
                g.bench_function(format!("embree_{mode}/{order}/{tag}"), |b| {
                    b.iter(|| {
                        hits.fill(Hit::MISS);
                        embree
                            .intersect(
                                &Cpu,
                                batch,
                                Query::Scene,
                                HitMode::Any,
                                &mut hits,
                                &mut Stats::default(),
                            )
                            .expect("embree");
                    })
                });
            }
        }
    } else {
        eprintln!("anchors: no Embree ids (built without the `embree` feature)");
    }
    g.finish();
}

criterion_group!(anchors, benches);
criterion_main!(anchors);
