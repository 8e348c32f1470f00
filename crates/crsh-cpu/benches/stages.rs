//! Criterion benches of the hot CPU stages on one fixed batch of shadow rays.
//!
//! The batch: the shared Sponza scene (`$CRSH_SCENES/sponza/sponza.toml`, else
//! `../shared/scenes` next to the workspace) when present, else the built-in `cornell-mirrors`
//! (the choice is printed); a 256×256 G-buffer from the `raster` primary stage, and the shadow
//! rays `raygen::whitted` spawns from it. Every group reports throughput in rays of that batch.
//!
//! Groups (see the README's "Benchmarks"):
//! - `hashing`: `thesis` with layout `interleave` and `concat`, `morton`, and `tile` with
//!   4-pixel tiles in Z-order (`tile_morton`, the `dual_screen` preset's keys);
//! - `sorting`: `compress` and `radix` on the keys of each hasher;
//! - `hierarchy`: `sphere_cone` over the thesis-sorted rays at subdivision 8, depth 2, and at
//!   16/3 with each `leaf_cone` (`incremental`, `extremes`);
//! - `traversal`: the `crsh` traverser and the `dual` traverser with objects `lbvh` and
//!   `grid` (object hierarchies built once, outside the timing), with a sink that only counts
//!   the candidates; and `dual_lbvh_inline`, the `lbvh` traversal with inline final tests
//!   (`final_tests = inline`: traversal and final tests in one, compare with `dual_lbvh` plus
//!   `final_tests/brute_dual_candidates_mt`);
//! - `final_tests`: the `brute` intersector on the candidate batches of the `crsh` traversal,
//!   with each ray-triangle test (`intersect.test` = `mt`, `watertight`, `projected`), and on
//!   those of `dual_lbvh` (lane masks included) with `mt`;
//! - `bvh`: the whole-scene `bvh` any-hit query of the same rays, the baseline, with each test;
//! - `reflection`: the closest-hit reflection rays of a 1024² G-buffer of the shared dining
//!   room (else the built-in `cornell-mirrors`), traced by `dual_lbvh_inline` (the
//!   `dual_inline` preset) and by the `dual_screen_bvh` preset, and of the shared cornell-mirror (when present), traced by the
//!   `dual_screen_bvh` preset; each batch also by the whole-scene `bvh`, side by side;
//! - `object_update`: the `dual` traverser's object side for frame 4 of `sponza-animated`
//!   (`scenes/sponza-animated.toml`, which needs the shared scenes; else the built-in
//!   `cornell-mirrors-animated`), built anew (`object_update/build/{objects}/{tag}`) and
//!   refitted from frame 0's (`traverse.update = refit`, `object_update/refit/...`), for
//!   `objects = lbvh`, `bvh`, and `bvh` with `wide_cone = 60` (`bvh_wide`: the
//!   `dual_screen_bvh` preset's, whose 8-wide BVH is compressed again either way).
//!
//! Run with `cargo bench -p crsh-cpu --bench stages` (add `-- --quick` for a short run, or a
//! group name to filter).

use std::sync::Arc;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BatchSize, Criterion, Throughput};
use crsh_core::{
    CandidateBatch, FrameSize, Hit, PipelineConfig, Query, Ray, RayHierarchy, RayKind, Registry,
    StageContext, Stages, Stats,
};
use crsh_cpu::triangle::TEST_NAMES;
use crsh_cpu::Cpu;
use crsh_scene::Scene;

mod common;
use common::shared_scene;

/// G-buffer size of the batch.
const SIZE: u32 = 256;

/// G-buffer size of the `reflection` group's batch (the dining room's mirrors and glossy
/// surfaces cover a small part of the frame).
const REFLECTION_SIZE: u32 = 1024;

/// The fixed batch every group works on.
struct Batch {
    /// `sponza` or `cornell-mirrors`: the last part of every benchmark id, so criterion never
    /// compares results of one scene with the other's.
    tag: &'static str,
    scene: Arc<Scene>,
    rays: Vec<Ray>,
    /// The rays' order by their thesis keys (layout `interleave`, compress sorter: the `crsh`
    /// preset's).
    order: Vec<u32>,
    /// The hierarchy over `order`.
    hierarchy: RayHierarchy<Cpu>,
    /// The candidate batches of the `crsh` traversal of `hierarchy`.
    candidates: Vec<CandidateBatch<Cpu>>,
}

/// The stage context of the batch: `scene` at `SIZE × SIZE`.
fn context(scene: &Arc<Scene>) -> StageContext<'_, Cpu> {
    StageContext::new(&Cpu, scene, FrameSize::new(SIZE, SIZE).expect("valid size"))
}

/// The `crsh` preset with `sets` applied (`stage.param=value`), built for `scene`.
fn stages(scene: &Arc<Scene>, sets: &[&str]) -> Stages<Cpu> {
    let registry = Registry::<Cpu>::builtin();
    let mut cfg: PipelineConfig = registry.preset("crsh").expect("the crsh preset exists");
    for s in sets {
        cfg.set(s).unwrap_or_else(|e| panic!("--set {s}: {e}"));
    }
    registry
        .build(&context(scene), &cfg)
        .unwrap_or_else(|e| panic!("building {sets:?}: {e}"))
        .stages
}

/// The rays of `kind` that `st`'s ray generation spawns from its primary stage's `size × size`
/// G-buffer.
fn spawn(st: &Stages<Cpu>, size: u32, kind: RayKind, stats: &mut Stats) -> Vec<Ray> {
    let surfaces = st
        .primary
        .gbuffer(&Cpu, size, size, stats)
        .expect("G-buffer");
    st.raygen
        .generate(&Cpu, &surfaces, kind, stats)
        .unwrap_or_else(|e| panic!("{kind:?} rays: {e}"))
}

/// `rays` (of `kind`) hashed, sorted and built into a hierarchy by `st`'s stages: the order
/// and the hierarchy.
fn hierarchy_of(
    st: &Stages<Cpu>,
    rays: &Vec<Ray>,
    kind: RayKind,
    stats: &mut Stats,
) -> (Vec<u32>, RayHierarchy<Cpu>) {
    let hasher = st.hasher.as_ref().expect("the pipeline hashes");
    let keys = hasher.hash(&Cpu, rays, kind, stats).expect("keys");
    let order = st
        .sorter
        .as_ref()
        .expect("the pipeline sorts")
        .sort(&Cpu, &keys, hasher.key_bits(), stats)
        .expect("order");
    let hierarchy = st
        .hierarchy
        .as_ref()
        .expect("the pipeline builds a hierarchy")
        .build(&Cpu, rays, order.clone(), stats)
        .expect("hierarchy");
    (order, hierarchy)
}

fn prepare() -> Batch {
    let (tag, scene) = match shared_scene("sponza/sponza.toml") {
        Some(path) => {
            let scene = crsh_scene::load_path(&path)
                .unwrap_or_else(|e| panic!("loading {}: {e}", path.display()));
            eprintln!("bench scene: sponza ({})", path.display());
            ("sponza", scene)
        }
        None => {
            eprintln!(
                "bench scene: built-in cornell-mirrors (sponza/sponza.toml not found under \
                 CRSH_SCENES or ../shared/scenes)"
            );
            (
                "cornell-mirrors",
                crsh_scene::load("cornell-mirrors").expect("built-in scene"),
            )
        }
    };
    let scene = Arc::new(scene);
    let st = stages(&scene, &[]);
    let mut stats = Stats::default();
    let rays = spawn(&st, SIZE, RayKind::Shadow, &mut stats);
    assert!(!rays.is_empty(), "the bench scene spawns no shadow rays");
    let (order, hierarchy) = hierarchy_of(&st, &rays, RayKind::Shadow, &mut stats);
    let mut candidates = Vec::new();
    st.traverser
        .as_ref()
        .expect("crsh traverses")
        .traverse(
            &Cpu,
            &rays,
            RayKind::Shadow,
            &hierarchy,
            &mut |batch, _| {
                candidates.push(batch);
                Ok(())
            },
            &mut stats,
        )
        .expect("traversal");
    let pairs: usize = candidates.iter().map(|b| b.pairs.len()).sum();
    eprintln!(
        "bench batch: {} triangles, {SIZE}x{SIZE} G-buffer, {} shadow rays, {} hierarchy \
         levels, {} candidate batches, {pairs} candidate pairs",
        scene.triangle_count(),
        rays.len(),
        hierarchy.levels.len(),
        candidates.len(),
    );
    Batch {
        tag,
        scene,
        rays,
        order,
        hierarchy,
        candidates,
    }
}

fn benches(c: &mut Criterion) {
    let b = prepare();
    let n = b.rays.len() as u64;
    let scene = &b.scene;

    let mut g = c.benchmark_group("hashing");
    g.throughput(Throughput::Elements(n));
    let hashers = [
        ("thesis_interleave", vec!["hash.layout=interleave"]),
        ("thesis_concat", vec!["hash.layout=concat"]),
        ("morton", vec!["hash.kind=morton"]),
        (
            "tile_morton",
            vec!["hash.kind=tile", "hash.tile_size=4", "hash.order=morton"],
        ),
    ];
    let mut keysets = Vec::new();
    for (name, sets) in &hashers {
        let st = stages(scene, sets);
        let h = st.hasher.expect("a hasher");
        g.bench_function(format!("{name}/{}", b.tag), |bench| {
            bench.iter(|| {
                h.hash(&Cpu, &b.rays, RayKind::Shadow, &mut Stats::default())
                    .unwrap()
            })
        });
        keysets.push((
            *name,
            h.hash(&Cpu, &b.rays, RayKind::Shadow, &mut Stats::default())
                .unwrap(),
            h.key_bits(),
        ));
    }
    g.finish();

    let mut g = c.benchmark_group("sorting");
    g.throughput(Throughput::Elements(n));
    for sorter in ["compress", "radix"] {
        let st = stages(scene, &[&format!("sort.kind={sorter}")]);
        let s = st.sorter.expect("a sorter");
        for (keys_name, keys, bits) in &keysets {
            g.bench_function(format!("{sorter}/{keys_name}/{}", b.tag), |bench| {
                bench.iter(|| s.sort(&Cpu, keys, *bits, &mut Stats::default()).unwrap())
            });
        }
    }
    g.finish();

    let mut g = c.benchmark_group("hierarchy");
    g.throughput(Throughput::Elements(n));
    let shapes: [(&str, &[&str]); 3] = [
        ("sphere_cone_s8_d2", &[]),
        (
            "sphere_cone_s16_d3",
            &["hierarchy.subdivision=16", "hierarchy.depth=3"],
        ),
        (
            "sphere_cone_s16_d3_extremes",
            &[
                "hierarchy.subdivision=16",
                "hierarchy.depth=3",
                "hierarchy.leaf_cone=extremes",
            ],
        ),
    ];
    for (name, sets) in shapes {
        let st = stages(scene, sets);
        let builder = st.hierarchy.as_ref().expect("a builder");
        g.bench_function(format!("{name}/{}", b.tag), |bench| {
            bench.iter_batched(
                || b.order.clone(),
                |order| {
                    builder
                        .build(&Cpu, &b.rays, order, &mut Stats::default())
                        .unwrap()
                },
                BatchSize::LargeInput,
            )
        });
    }
    g.finish();

    let st = stages(scene, &[]);
    let mut g = c.benchmark_group("traversal");
    g.throughput(Throughput::Elements(n));
    g.sample_size(10);
    let traverser = st.traverser.as_ref().expect("a traverser");
    // The dual traversals, each with its object hierarchy built once (as a frame's stage).
    let duals: Vec<(&str, Stages<Cpu>)> = [
        ("dual_lbvh", "traverse.objects=lbvh"),
        ("dual_grid", "traverse.objects=grid"),
    ]
    .into_iter()
    .map(|(name, set)| (name, stages(scene, &["traverse.kind=dual", set])))
    .collect();
    let traversers = std::iter::once(("crsh", traverser)).chain(
        duals
            .iter()
            .map(|(name, st)| (*name, st.traverser.as_ref().expect("a traverser"))),
    );
    for (name, traverser) in traversers {
        g.bench_function(format!("{name}/{}", b.tag), |bench| {
            bench.iter(|| {
                let mut pairs = 0usize;
                traverser
                    .traverse(
                        &Cpu,
                        &b.rays,
                        RayKind::Shadow,
                        &b.hierarchy,
                        &mut |batch, _| {
                            pairs += batch.pairs.len();
                            Ok(())
                        },
                        &mut Stats::default(),
                    )
                    .unwrap();
                pairs
            })
        });
    }
    // `dual_lbvh` with inline final tests: traversal and final tests in one call.
    let inline = stages(
        scene,
        &["traverse.kind=dual", "traverse.final_tests=inline"],
    );
    let inline_traverser = inline.traverser.as_ref().expect("a traverser");
    g.bench_function(format!("dual_lbvh_inline/{}", b.tag), |bench| {
        bench.iter(|| {
            let mut hits = vec![Hit::MISS; b.rays.len()];
            inline_traverser
                .trace(
                    &Cpu,
                    &b.rays,
                    RayKind::Shadow,
                    RayKind::Shadow.hit_mode(),
                    &*inline.intersector,
                    &b.hierarchy,
                    &mut hits,
                    &mut Stats::default(),
                )
                .expect("inline final tests")
                .unwrap();
            hits
        })
    });
    g.finish();
    // The `dual_lbvh` traversal's candidate batches (with their lane masks).
    let mut dual_candidates = Vec::new();
    duals[0]
        .1
        .traverser
        .as_ref()
        .expect("a traverser")
        .traverse(
            &Cpu,
            &b.rays,
            RayKind::Shadow,
            &b.hierarchy,
            &mut |batch, _| {
                dual_candidates.push(batch);
                Ok(())
            },
            &mut Stats::default(),
        )
        .expect("dual traversal");

    let mut g = c.benchmark_group("final_tests");
    g.throughput(Throughput::Elements(n));
    g.sample_size(10);
    let mode = RayKind::Shadow.hit_mode();
    let runs = TEST_NAMES
        .iter()
        .map(|t| ("brute_candidates", *t, &b.candidates))
        .chain(std::iter::once((
            "brute_dual_candidates",
            "mt",
            &dual_candidates,
        )));
    for (name, test, candidates) in runs {
        let intersector = stages(scene, &[&format!("intersect.test={test}")]).intersector;
        g.bench_function(format!("{name}_{test}/{}", b.tag), |bench| {
            bench.iter(|| {
                let mut hits = vec![Hit::MISS; b.rays.len()];
                let mut stats = Stats::default();
                for batch in candidates {
                    let q = Query::Candidates {
                        hierarchy: &b.hierarchy,
                        batch,
                    };
                    intersector
                        .intersect(&Cpu, &b.rays, q, mode, &mut hits, &mut stats)
                        .unwrap();
                }
                hits
            })
        });
    }
    g.finish();

    let mut g = c.benchmark_group("bvh");
    g.throughput(Throughput::Elements(n));
    g.sample_size(10);
    for test in TEST_NAMES {
        // A whole-scene intersector: built on its own (a pipeline with a hierarchy rejects it).
        let mut spec = crsh_core::StageSpec::new("bvh");
        spec.params
            .insert("test".into(), crsh_core::ParamValue::Str(test.to_string()));
        let bvh = Registry::<Cpu>::builtin()
            .build_intersector(&context(scene), &spec)
            .unwrap_or_else(|e| panic!("building bvh with {test}: {e}"));
        g.bench_function(format!("whole_scene_any_hit_{test}/{}", b.tag), |bench| {
            bench.iter(|| {
                let mut hits = vec![Hit::MISS; b.rays.len()];
                bvh.intersect(
                    &Cpu,
                    &b.rays,
                    Query::Scene,
                    mode,
                    &mut hits,
                    &mut Stats::default(),
                )
                .unwrap();
                hits
            })
        });
    }
    g.finish();
}

/// The `reflection` group: first-bounce reflection rays of a [`REFLECTION_SIZE`]² G-buffer,
/// traced to their closest hits by a ray-hierarchy preset with inline final tests (hashed,
/// sorted and built into a hierarchy once, outside the timing) and by the whole-scene `bvh`
/// (the CWBVH), side by side, on two batches:
/// - the shared dining room (else the built-in `cornell-mirrors`) with the `dual_inline`
///   preset, id `dual_lbvh_inline` (wide cones, most of the dining room's lowest nodes descend
///   to single rays), and with the `dual_screen_bvh` preset, id `dual_screen_bvh` (whose
///   lowest nodes of 60° and more go through the 8-wide BVH, `traverse.wide_cone`);
/// - the shared cornell-mirror with the `dual_screen_bvh` preset, id `dual_screen_bvh`
///   (skipped with a printed reason when the shared scenes are absent): coherent rays off
///   flat mirrors, where the ray side's segment boxes and the node pairs are the cost.
fn reflection_benches(c: &mut Criterion) {
    let wide = match shared_scene("dining-room/dining-room.toml") {
        Some(path) => {
            let scene = crsh_scene::load_path(&path)
                .unwrap_or_else(|e| panic!("loading {}: {e}", path.display()));
            ("dining-room", scene)
        }
        None => {
            eprintln!(
                "reflection bench scene: built-in cornell-mirrors (dining-room/dining-room.toml \
                 not found under CRSH_SCENES or ../shared/scenes)"
            );
            (
                "cornell-mirrors",
                crsh_scene::load("cornell-mirrors").expect("built-in scene"),
            )
        }
    };
    reflection_batch(
        c,
        wide,
        &[
            ("dual_inline", "dual_lbvh_inline"),
            ("dual_screen_bvh", "dual_screen_bvh"),
        ],
    );
    match shared_scene("cornell/cornell-mirror.toml") {
        Some(path) => {
            let scene = crsh_scene::load_path(&path)
                .unwrap_or_else(|e| panic!("loading {}: {e}", path.display()));
            reflection_batch(
                c,
                ("cornell-mirror", scene),
                &[("dual_screen_bvh", "dual_screen_bvh")],
            );
        }
        None => eprintln!(
            "reflection bench: the cornell-mirror batch is skipped (cornell/cornell-mirror.toml \
             not found under CRSH_SCENES or ../shared/scenes)"
        ),
    }
}

/// One batch of the `reflection` group: `scene`'s (named `tag`) first-bounce reflection rays
/// (spawned by the first preset's stages) traced by each preset of `presets` (`(preset, id)`,
/// inline final tests, its own keys and hierarchy; benchmark id `reflection/{id}/{tag}`) and by
/// the whole-scene `bvh` (`reflection/bvh/{tag}`).
fn reflection_batch(c: &mut Criterion, (tag, scene): (&str, Scene), presets: &[(&str, &str)]) {
    let scene = Arc::new(scene);
    let ctx = StageContext::new(
        &Cpu,
        &scene,
        FrameSize::new(REFLECTION_SIZE, REFLECTION_SIZE).expect("valid size"),
    );
    let registry = Registry::<Cpu>::builtin();
    let stages_of = |preset: &str| {
        let cfg = registry
            .preset(preset)
            .unwrap_or_else(|| panic!("the {preset} preset exists"));
        registry
            .build(&ctx, &cfg)
            .unwrap_or_else(|e| panic!("building {preset}: {e}"))
            .stages
    };
    let kind = RayKind::Reflection;
    let mut stats = Stats::default();
    let stages: Vec<Stages<Cpu>> = presets
        .iter()
        .map(|&(preset, _)| stages_of(preset))
        .collect();
    let rays = spawn(&stages[0], REFLECTION_SIZE, kind, &mut stats);
    if rays.is_empty() {
        eprintln!("reflection bench: {tag} spawns no reflection rays, skipped");
        return;
    }
    let mut spec = crsh_core::StageSpec::new("bvh");
    spec.params
        .insert("test".into(), crsh_core::ParamValue::Str("mt".to_string()));
    let bvh = registry
        .build_intersector(&ctx, &spec)
        .expect("building bvh");
    let mut g = c.benchmark_group("reflection");
    g.throughput(Throughput::Elements(rays.len() as u64));
    g.sample_size(10);
    for (st, &(preset, id)) in stages.iter().zip(presets) {
        let (_, hierarchy) = hierarchy_of(st, &rays, kind, &mut stats);
        eprintln!(
            "reflection bench batch: {tag}, {} triangles, {REFLECTION_SIZE}x{REFLECTION_SIZE} \
             G-buffer, {} reflection rays, {preset}",
            scene.triangle_count(),
            rays.len()
        );
        let traverser = st.traverser.as_ref().expect("a traverser");
        g.bench_function(format!("{id}/{tag}"), |bench| {
            bench.iter(|| {
                let mut hits = vec![Hit::MISS; rays.len()];
                traverser
                    .trace(
                        &Cpu,
                        &rays,
                        kind,
                        kind.hit_mode(),
                        &*st.intersector,
                        &hierarchy,
                        &mut hits,
                        &mut Stats::default(),
                    )
                    .expect("inline final tests")
                    .unwrap();
                hits
            })
        });
    }
    g.bench_function(format!("bvh/{tag}"), |bench| {
        bench.iter(|| {
            let mut hits = vec![Hit::MISS; rays.len()];
            bvh.intersect(
                &Cpu,
                &rays,
                Query::Scene,
                kind.hit_mode(),
                &mut hits,
                &mut Stats::default(),
            )
            .unwrap();
            hits
        })
    });
    g.finish();
}

/// Short runs: the machine this was written on has 2 shared cores.
fn config() -> Criterion {
    Criterion::default()
        .sample_size(20)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(3))
}

/// The `object_update` group (module doc).
fn object_update_benches(c: &mut Criterion) {
    use crsh_core::{ParamValue, StageSpec};
    use crsh_cpu::traverse::dual::{info, Dual};
    let manifest = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenes/sponza-animated.toml");
    let (tag, anim) = match shared_scene("sponza/sponza.toml")
        .and_then(|_| crsh_scene::load_animated(manifest.to_str()?).ok())
    {
        Some((anim, _)) => ("sponza-animated", anim),
        None => {
            eprintln!(
                "object_update bench scene: built-in cornell-mirrors-animated \
                 (sponza-animated needs sponza/sponza.toml under CRSH_SCENES or ../shared/scenes)"
            );
            let (anim, _) =
                crsh_scene::load_animated("cornell-mirrors-animated").expect("built-in scene");
            ("cornell-mirrors-animated", anim)
        }
    };
    let first = Arc::new(anim.scene().clone());
    let mut moved = anim.scene().clone();
    anim.update(&mut moved, 4, true).expect("frame 4");
    let moved = Arc::new(moved);
    let mut g = c.benchmark_group("object_update");
    g.throughput(Throughput::Elements(moved.triangle_count() as u64));
    for (id, objects, wide) in [
        ("lbvh", "lbvh", 180.0),
        ("bvh", "bvh", 180.0),
        ("bvh_wide", "bvh", 60.0),
    ] {
        let spec = |update: &str| {
            let mut spec: StageSpec = info().defaults();
            for (k, v) in [
                ("objects", ParamValue::Str(objects.into())),
                ("final_tests", ParamValue::Str("inline".into())),
                ("wide_cone", ParamValue::Float(wide)),
                ("update", ParamValue::Str(update.into())),
            ] {
                spec.params.insert(k.into(), v);
            }
            spec
        };
        let (rebuild, refit) = (spec("rebuild"), spec("refit"));
        g.bench_function(format!("build/{id}/{tag}"), |b| {
            b.iter(|| Dual::new(&moved, &rebuild).expect("dual"))
        });
        // A refit takes what its traverser kept: each one refits a fresh frame-0 traverser.
        g.bench_function(format!("refit/{id}/{tag}"), |b| {
            b.iter_batched(
                || Dual::new(&first, &refit).expect("dual"),
                |t| t.refitted(&moved).expect("a refit"),
                BatchSize::PerIteration,
            )
        });
    }
    g.finish();
}

criterion_group! {
    name = stages_group;
    config = config();
    targets = benches, reflection_benches, object_update_benches
}
criterion_main!(stages_group);
