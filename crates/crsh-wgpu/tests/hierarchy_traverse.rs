//! The GPU sphere-cone hierarchy and CRSH traversal against their CPU twins, on rays from the
//! CPU pipeline of the built-in scenes: nodes within the stated tolerance and containing every
//! ray (checked in f64); candidates containing every CPU candidate, hence every intersecting
//! pair; level counters; several candidate batches under a small budget.
//!
//! Without an adapter every test prints `SKIP:` and passes, unless `CRSH_REQUIRE_GPU=1`.

use std::sync::Arc;

use crsh_core::{
    Backend, HierarchyBuilder, Ray, RayHierarchy, RayKind, SphereCone, StageSpec, Stats, Surface,
};
use crsh_cpu::hierarchy::sphere_cone::covers;
use crsh_cpu::Cpu;
use crsh_scene::Scene;
use crsh_wgpu::hierarchy::sphere_cone::SphereConeBuilder;
use crsh_wgpu::{GpuScene, Wgpu};

fn scene(name: &str) -> Arc<Scene> {
    Arc::new(crsh_scene::builtin::build(name).unwrap())
}

/// Rays of `kind` from the CPU pipeline's G-buffer (primary bounce), and the CPU crsh preset's
/// order for them (thesis hash, compress sort).
fn cpu_rays(s: &Arc<Scene>, kind: RayKind) -> (Vec<Ray>, Vec<u32>) {
    let cfg = crsh_wgpu::testing::cpu_preset("crsh");
    let stages = crsh_wgpu::testing::cpu_stages(&cfg, s, 40, 30);
    let mut st = Stats::default();
    let g: Vec<Surface> = stages.primary.gbuffer(&Cpu, 40, 30, &mut st).unwrap();
    let rays = stages.raygen.generate(&Cpu, &g, kind, &mut st).unwrap();
    let keys = stages
        .hasher
        .as_ref()
        .unwrap()
        .hash(&Cpu, &rays, kind, &mut st)
        .unwrap();
    let bits = stages.hasher.as_ref().unwrap().key_bits();
    let order = stages
        .sorter
        .as_ref()
        .unwrap()
        .sort(&Cpu, &keys, bits, &mut st)
        .unwrap();
    (rays, order)
}

/// One ray set of these tests: a built-in scene, its upload, a ray kind, and the CPU's rays of
/// that kind in the CPU's order ([`cpu_rays`]).
struct RaySet {
    name: &'static str,
    scene: Arc<Scene>,
    gpu: Arc<GpuScene>,
    kind: RayKind,
    rays: Vec<Ray>,
    order: Vec<u32>,
}

/// The shadow and reflection rays of `cornell-mirrors` and `office-boxes`, each scene uploaded
/// once.
fn ray_sets(b: &Wgpu) -> Vec<RaySet> {
    let mut out = Vec::new();
    for name in ["cornell-mirrors", "office-boxes"] {
        let scene = scene(name);
        let gpu = GpuScene::new(b, &scene).unwrap();
        for kind in [RayKind::Shadow, RayKind::Reflection] {
            let (rays, order) = cpu_rays(&scene, kind);
            out.push(RaySet {
                name,
                scene: Arc::clone(&scene),
                gpu: Arc::clone(&gpu),
                kind,
                rays,
                order,
            });
        }
    }
    out
}

fn spec(sub: i64, depth: i64) -> StageSpec {
    let mut s = crsh_cpu::hierarchy::sphere_cone::info().defaults();
    s.params
        .insert("subdivision".into(), crsh_core::ParamValue::Int(sub));
    s.params
        .insert("depth".into(), crsh_core::ParamValue::Int(depth));
    s
}

fn gpu_hierarchy(
    b: &Wgpu,
    g: &Arc<GpuScene>,
    rays: &[Ray],
    order: &[u32],
    sub: i64,
    depth: i64,
) -> RayHierarchy<Wgpu> {
    gpu_build(b, g, rays, order, &spec(sub, depth))
}

/// The GPU `sphere_cone` hierarchy of `rays` in `order`, configured by `spec`.
fn gpu_build(
    b: &Wgpu,
    g: &Arc<GpuScene>,
    rays: &[Ray],
    order: &[u32],
    spec: &StageSpec,
) -> RayHierarchy<Wgpu> {
    SphereConeBuilder::new(g, spec)
        .unwrap()
        .build(
            b,
            &b.upload(rays).unwrap(),
            b.upload(order).unwrap(),
            &mut Stats::default(),
        )
        .unwrap()
}

#[test]
fn hierarchy_nodes_match_the_cpu_and_contain_their_rays() {
    let Some(b) =
        crsh_wgpu::testing::shared_backend("hierarchy_nodes_match_the_cpu_and_contain_their_rays")
    else {
        return;
    };
    for RaySet {
        name,
        scene: s,
        gpu: g,
        kind,
        rays,
        order,
    } in ray_sets(&b)
    {
        let diag = s.bounds.diagonal();
        assert!(rays.len() > 20, "{name} {kind:?}: {} rays", rays.len());
        for (sub, depth) in [(8, 2), (4, 3), (64, 2), (2, 8)] {
            let cpu = crsh_cpu::hierarchy::sphere_cone::SphereConeBuilder::with_params(
                sub as u32,
                depth as u32,
            )
            .unwrap();
            let want = cpu
                .build(&Cpu, &rays, order.clone(), &mut Stats::default())
                .unwrap();
            let got = gpu_hierarchy(&b, &g, &rays, &order, sub, depth);
            assert_eq!(got.levels.len(), want.levels.len());
            let what = format!("{name} {kind:?} sub {sub} depth {depth}");
            for (li, (gl, wl)) in got.levels.iter().zip(&want.levels).enumerate() {
                let gl = b.download(gl).unwrap();
                assert_eq!(gl.len(), wl.len(), "{what}: level {li}");
                for (i, (gn, wn)) in gl.iter().zip(wl).enumerate() {
                    let tol = 2e-4 * diag.max(1.0);
                    assert!(
                        (gn.sphere.center - wn.sphere.center).length() <= tol
                            && (gn.sphere.radius - wn.sphere.radius).abs() <= tol
                            && (gn.cone.half_angle - wn.cone.half_angle).abs() <= 1e-3,
                        "{what}: level {li} node {i}: gpu {gn:?} cpu {wn:?}"
                    );
                    if wn.cone.half_angle < 3.0 {
                        assert!(
                            gn.cone.axis.dot(wn.cone.axis) > 1.0 - 1e-5,
                            "{what}: node {i} axis"
                        );
                    }
                }
                // Containment, in f64: every ray of every lowest node; every child of
                // every upper node (its sphere and cone).
                if li == 0 {
                    for (leaf, &r) in order.iter().enumerate() {
                        let node = &gl[leaf / sub as usize];
                        let ray = &rays[r as usize];
                        assert!(
                            covers(node, ray.origin, ray.dir),
                            "{what}: leaf {leaf} not covered by {node:?}"
                        );
                    }
                }
            }
            let reach = b.download(&got.reach[0]).unwrap();
            for (leaf, &r) in order.iter().enumerate() {
                let node = &b.download(&got.levels[0]).unwrap()[leaf / sub as usize];
                let ray = &rays[r as usize];
                let end = ray.origin.as_dvec3() + ray.dir.as_dvec3() * ray.t_max as f64;
                if ray.t_max.is_finite() {
                    assert!(
                        (end - node.sphere.center.as_dvec3()).length()
                            <= reach[leaf / sub as usize] as f64,
                        "{what}: reach"
                    );
                }
                if leaf > 64 {
                    break;
                }
            }
        }
    }
}

/// The lowest levels of the GPU's and the CPU's hierarchies over `set` at `sub`/`depth` with
/// the sphere-cone parameter `param` set to `value` (the same spec for both twins), after
/// checking that both have the same level and node counts and that every ray is covered by its
/// GPU node; with the description of the case for messages.
fn lowest_levels_with(
    b: &Wgpu,
    set: &RaySet,
    (sub, depth): (i64, i64),
    (param, value): (&str, &str),
) -> (Vec<SphereCone>, Vec<SphereCone>, String) {
    let mut sp = spec(sub, depth);
    sp.params
        .insert(param.into(), crsh_core::ParamValue::Str(value.into()));
    let cpu = crsh_cpu::hierarchy::sphere_cone::SphereConeBuilder::new(&set.scene, &sp).unwrap();
    let want = cpu
        .build(&Cpu, &set.rays, set.order.clone(), &mut Stats::default())
        .unwrap();
    let got = gpu_build(b, &set.gpu, &set.rays, &set.order, &sp);
    let what = format!(
        "{} {:?} sub {sub} depth {depth} {param} {value}",
        set.name, set.kind
    );
    assert_eq!(got.levels.len(), want.levels.len(), "{what}");
    let gl = b.download(&got.levels[0]).unwrap();
    assert_eq!(gl.len(), want.levels[0].len(), "{what}");
    for (leaf, &r) in set.order.iter().enumerate() {
        let node = &gl[leaf / sub as usize];
        let ray = &set.rays[r as usize];
        assert!(
            covers(node, ray.origin, ray.dir),
            "{what}: leaf {leaf} not covered by {node:?}"
        );
    }
    (gl, want.levels[0].clone(), what)
}

/// `leaf_cone = extremes`: the GPU's lowest cones contain their rays and match the CPU's widths
/// on (nearly) every node; a node whose candidate axes nearly tie may be decided the other way
/// in `f32`, so up to 1 % of the nodes may differ, never by losing a ray.
#[test]
fn extreme_ray_leaf_cones_match_the_cpu_and_contain_their_rays() {
    let Some(b) = crsh_wgpu::testing::shared_backend(
        "extreme_ray_leaf_cones_match_the_cpu_and_contain_their_rays",
    ) else {
        return;
    };
    for set in ray_sets(&b) {
        for shape in [(16, 3), (8, 2), (4, 3)] {
            let (gl, wl, what) = lowest_levels_with(&b, &set, shape, ("leaf_cone", "extremes"));
            let differ = gl
                .iter()
                .zip(&wl)
                .filter(|(gn, wn)| (gn.cone.half_angle - wn.cone.half_angle).abs() > 1e-3)
                .count();
            assert!(
                differ * 100 <= gl.len(),
                "{what}: {differ} of {} lowest cones differ",
                gl.len()
            );
        }
    }
}

/// `leaf_sphere = box`: the GPU's lowest spheres have the CPU's centres exactly (the same `f32`
/// box centre), radii within the device's wider margins, contain every ray's origin, and
/// differ from Welzl's where the origins do not share a point.
#[test]
fn box_centred_leaf_spheres_match_the_cpu() {
    let Some(b) = crsh_wgpu::testing::shared_backend("box_centred_leaf_spheres_match_the_cpu")
    else {
        return;
    };
    for set in ray_sets(&b) {
        for shape in [(16, 3), (8, 2)] {
            let (gl, wl, what) = lowest_levels_with(&b, &set, shape, ("leaf_sphere", "box"));
            let (welzl, _, _) = lowest_levels_with(&b, &set, shape, ("leaf_sphere", "welzl"));
            let mut moved = 0;
            for (k, (gn, wn)) in gl.iter().zip(&wl).enumerate() {
                assert_eq!(gn.sphere.center, wn.sphere.center, "{what}: node {k}");
                let r = wn.sphere.radius;
                let scale = 1.0 + gn.sphere.center.abs().max_element();
                assert!(
                    (gn.sphere.radius - r).abs() <= 1e-5 * r + 3e-6 * scale,
                    "{what}: node {k} radius {} against {r}",
                    gn.sphere.radius
                );
                moved += usize::from(gn.sphere.center != welzl[k].sphere.center);
            }
            if set.kind == RayKind::Reflection {
                assert!(moved > 0, "{what}: no box centre differs from Welzl's");
            }
        }
    }
}

/// `origins = start` (seed 001's offset rays): the GPU nodes bound the segment starts as the
/// CPU's do, within the same tolerance, and contain every moved ray; its reach covers every
/// segment end.
#[test]
fn hierarchy_over_segment_starts_matches_the_cpu() {
    let Some(b) =
        crsh_wgpu::testing::shared_backend("hierarchy_over_segment_starts_matches_the_cpu")
    else {
        return;
    };
    let s = scene("cornell-mirrors");
    let g = GpuScene::new(&b, &s).unwrap();
    let diag = s.bounds.diagonal();
    for kind in [RayKind::Shadow, RayKind::Reflection] {
        let (mut rays, order) = cpu_rays(&s, kind);
        // Offset-like starts: a third of each finite segment, or 5 % of the diagonal.
        for r in &mut rays {
            let len = if r.t_max.is_finite() {
                r.t_max
            } else {
                0.15 * diag
            };
            r.t_min = r.t_min.max(len / 3.0);
        }
        let cpu = crsh_cpu::hierarchy::sphere_cone::SphereConeBuilder::with_params(8, 2)
            .unwrap()
            .bounding_starts(true);
        let want = cpu
            .build(&Cpu, &rays, order.clone(), &mut Stats::default())
            .unwrap();
        let mut sp = spec(8, 2);
        sp.params
            .insert("origins".into(), crsh_core::ParamValue::Str("start".into()));
        let got = gpu_build(&b, &g, &rays, &order, &sp);
        let moved = crsh_cpu::hierarchy::sphere_cone::segment_starts(&rays);
        let gl = b.download(&got.levels[0]).unwrap();
        let reach = b.download(&got.reach[0]).unwrap();
        for (i, (gn, wn)) in gl.iter().zip(&want.levels[0]).enumerate() {
            let tol = 2e-4 * diag.max(1.0);
            assert!(
                (gn.sphere.center - wn.sphere.center).length() <= tol
                    && (gn.sphere.radius - wn.sphere.radius).abs() <= tol,
                "{kind:?} node {i}: gpu {gn:?} cpu {wn:?}"
            );
        }
        for (leaf, &r) in order.iter().enumerate() {
            let node = &gl[leaf / 8];
            let m = &moved[r as usize];
            assert!(covers(node, m.origin, m.dir), "{kind:?} leaf {leaf}");
            if m.t_max.is_finite() {
                let end = m.origin.as_dvec3() + m.dir.as_dvec3() * m.t_max as f64;
                assert!(
                    (end - node.sphere.center.as_dvec3()).length() <= reach[leaf / 8] as f64,
                    "{kind:?} leaf {leaf}: reach"
                );
            }
        }
    }
}

/// The CPU hierarchy `h` on the device.
fn upload_hierarchy(b: &Wgpu, h: &RayHierarchy<Cpu>) -> RayHierarchy<Wgpu> {
    RayHierarchy {
        leaf_offsets: None,
        order: b.upload(&h.order).unwrap(),
        levels: h.levels.iter().map(|l| b.upload(l).unwrap()).collect(),
        subdivision: h.subdivision,
        reach: h.reach.iter().map(|l| b.upload(l).unwrap()).collect(),
    }
}

fn traverse_spec(mesh_culling: bool, budget_mb: f64) -> StageSpec {
    let mut s = StageSpec::new("crsh");
    s.params.insert(
        "mesh_culling".into(),
        crsh_core::ParamValue::Bool(mesh_culling),
    );
    s.params.insert(
        "candidate_budget_mb".into(),
        crsh_core::ParamValue::Float(budget_mb),
    );
    s
}

/// On the CPU's own hierarchy (uploaded), the GPU traversal keeps every pair the CPU keeps
/// (so every intersecting pair) and at most a few more, in (node, triangle) order; its level
/// rows are within that excess of the CPU's; a tiny budget gives several batches with the same
/// union.
#[test]
fn traversal_keeps_every_cpu_candidate() {
    use crsh_core::{Candidate, Traverser};
    let Some(b) = crsh_wgpu::testing::shared_backend("traversal_keeps_every_cpu_candidate") else {
        return;
    };
    for RaySet {
        name,
        scene: s,
        gpu: g,
        kind,
        rays,
        order,
    } in ray_sets(&b)
    {
        let cpu_h = crsh_cpu::hierarchy::sphere_cone::SphereConeBuilder::with_params(8, 2)
            .unwrap()
            .build(&Cpu, &rays, order, &mut Stats::default())
            .unwrap();
        let gpu_h = upload_hierarchy(&b, &cpu_h);
        let gpu_rays = b.upload(&rays).unwrap();
        for (culling, budget) in [(true, 64.0), (false, 64.0), (true, 0.002)] {
            let what = format!("{name} {kind:?} culling {culling} budget {budget}");
            let cpu =
                crsh_cpu::traverse::crsh::Crsh::new(&s, &traverse_spec(culling, budget)).unwrap();
            let mut want: Vec<Candidate> = Vec::new();
            let mut cpu_stats = Stats::default();
            cpu.traverse(
                &Cpu,
                &rays,
                kind,
                &cpu_h,
                &mut |batch, _| {
                    want.extend(batch.pairs);
                    Ok(())
                },
                &mut cpu_stats,
            )
            .unwrap();
            let gpu =
                crsh_wgpu::traverse::crsh::Crsh::new(&g, &traverse_spec(culling, budget)).unwrap();
            let mut got: Vec<Candidate> = Vec::new();
            let mut batches = 0;
            let mut gpu_stats = Stats::default();
            gpu.traverse(
                &b,
                &gpu_rays,
                kind,
                &gpu_h,
                &mut |batch, _| {
                    let pairs = b.download(&batch.pairs).unwrap();
                    assert!(
                        pairs.windows(2).all(|w| w[0] < w[1]),
                        "{what}: pairs not increasing"
                    );
                    got.extend(pairs);
                    batches += 1;
                    Ok(())
                },
                &mut gpu_stats,
            )
            .unwrap();
            got.sort_unstable();
            want.sort_unstable();
            let mut gi = got.iter().peekable();
            for w in &want {
                while gi.peek().is_some_and(|g| *g < w) {
                    gi.next();
                }
                assert_eq!(
                    gi.peek(),
                    Some(&w),
                    "{what}: CPU candidate {w:?} missing on the GPU"
                );
            }
            assert!(!want.is_empty(), "{what}: no candidates");
            assert!(
                (got.len() as f64) <= want.len() as f64 * 1.05 + 10.0,
                "{what}: GPU {} candidates, CPU {}",
                got.len(),
                want.len()
            );
            if budget < 1.0 {
                assert!(batches > 1, "{what}: one batch");
            }
            assert_eq!(gpu_stats.mesh_culling.is_empty(), !culling);
            for (k, c) in &cpu_stats.mesh_culling {
                let gm = &gpu_stats.mesh_culling[k];
                assert_eq!(gm.tests, c.tests, "{what}: mesh culling tests");
                assert!(
                    gm.hits >= c.hits,
                    "{what}: the GPU culled a mesh the CPU kept"
                );
            }
            assert_eq!(gpu_stats.levels.len(), cpu_stats.levels.len(), "{what}");
            // The top level tests the same pairs; below, the GPU's few extra survivors
            // add tests and hits. (Under a tiny budget the batches abandoned and retried
            // differ: the CPU sizes them from its arrays' capacities, the GPU from their
            // lengths, and abandoned batches' tests count; only the rows are compared.)
            let top = cpu_h.levels.len() as u32;
            let within = |g: u64, c: u64| g >= c && g as f64 <= c as f64 * 1.05 + 10.0;
            for (gl, cl) in gpu_stats.levels.iter().zip(&cpu_stats.levels) {
                assert_eq!(gl.level, cl.level, "{what}");
                // (With mesh culling the GPU may keep a mesh more for a node: more tests.)
                if gl.level == top && budget >= 1.0 && !culling {
                    assert_eq!(gl.tests, cl.tests, "{what}: top level tests");
                }
                assert!(
                    budget < 1.0 || (within(gl.tests, cl.tests) && within(gl.hits, cl.hits)),
                    "{what}: {gl:?} vs {cl:?}"
                );
            }
        }
    }
}

fn dual_spec(objects: &str, box_test: bool, single_rays: bool, budget_mb: f64) -> StageSpec {
    use crsh_core::ParamValue;
    let mut s = crsh_cpu::traverse::dual::info().defaults();
    s.params
        .insert("objects".into(), ParamValue::Str(objects.into()));
    s.params
        .insert("box_test".into(), ParamValue::Bool(box_test));
    s.params
        .insert("single_rays".into(), ParamValue::Bool(single_rays));
    s.params
        .insert("candidate_budget_mb".into(), ParamValue::Float(budget_mb));
    s
}

/// The sum of `rows`' tests and whether every row has `tests = hits + misses`.
fn row_sum(rows: &[crsh_core::LevelStats]) -> u64 {
    for r in rows {
        assert_eq!(r.tests, r.hits + r.misses, "{r:?}");
    }
    rows.iter().map(|r| r.tests).sum()
}

/// The GPU `dual` traversal against its CPU twin on the CPU's own hierarchy (uploaded), each
/// followed by its backend's brute-force candidate query, for every object side (`lbvh`,
/// `bvh`, `grid`, and `meshes`), with and without boxes and single rays, and under a tiny
/// budget: exactly the hits of the GPU's own whole-scene brute force, the CPU twin's hits,
/// batches strictly increasing with a non-empty lane mask per pair, counter rows on both sides
/// that account for every test and stay within a few percent of the CPU's, several batches
/// under the tiny budget.
#[test]
fn dual_traversal_gives_the_brute_force_hits() {
    use crsh_core::{Candidate, Hit, HitMode, Intersector, Query, Traverser};
    use crsh_wgpu::intersect::brute::BruteForce;
    let Some(b) = crsh_wgpu::testing::shared_backend("dual_traversal_gives_the_brute_force_hits")
    else {
        return;
    };
    let mut brute_spec = StageSpec::new("brute");
    brute_spec
        .params
        .insert("test".into(), crsh_core::ParamValue::Str("mt".into()));
    for name in ["cornell-mirrors", "office-boxes"] {
        let s = scene(name);
        let g = GpuScene::new(&b, &s).unwrap();
        let gpu_brute = BruteForce::new(&g, &brute_spec).unwrap();
        let cpu_brute = crsh_wgpu::testing::cpu_intersector(&StageSpec::new("brute"), &s);
        for (kind, mode) in [
            (RayKind::Shadow, HitMode::Any),
            (RayKind::Reflection, HitMode::Closest),
        ] {
            let (rays, order) = cpu_rays(&s, kind);
            let cpu_h = crsh_cpu::hierarchy::sphere_cone::SphereConeBuilder::with_params(8, 2)
                .unwrap()
                .build(&Cpu, &rays, order, &mut Stats::default())
                .unwrap();
            let gpu_h = upload_hierarchy(&b, &cpu_h);
            let gpu_rays = b.upload(&rays).unwrap();
            let mut scene_hits = b.filled(rays.len(), Hit::MISS).unwrap();
            gpu_brute
                .intersect(
                    &b,
                    &gpu_rays,
                    Query::Scene,
                    mode,
                    &mut scene_hits,
                    &mut Stats::default(),
                )
                .unwrap();
            let scene_hits = b.download(&scene_hits).unwrap();
            assert!(scene_hits.iter().any(|h| h.is_hit()), "{name}: no hits");
            for (objects, boxes, single, budget) in [
                ("lbvh", true, true, 64.0),
                ("bvh", true, true, 64.0),
                ("grid", true, true, 64.0),
                ("lbvh", false, false, 64.0),
                ("lbvh", false, true, 64.0),
                ("lbvh", true, true, 0.002),
                ("grid", true, true, 0.002),
                ("meshes", true, true, 64.0),
            ] {
                let what =
                    format!("{name} {kind:?} {objects} boxes {boxes} single {single} {budget}");
                let spec = dual_spec(objects, boxes, single, budget);
                let cpu = crsh_cpu::traverse::dual::Dual::new(&s, &spec).unwrap();
                let mut want = vec![Hit::MISS; rays.len()];
                let mut cpu_stats = Stats::default();
                cpu.traverse(
                    &Cpu,
                    &rays,
                    kind,
                    &cpu_h,
                    &mut |batch, st| {
                        let q = Query::Candidates {
                            hierarchy: &cpu_h,
                            batch: &batch,
                        };
                        cpu_brute.intersect(&Cpu, &rays, q, mode, &mut want, st)
                    },
                    &mut cpu_stats,
                )
                .unwrap();
                let gpu = crsh_wgpu::traverse::dual::Dual::new(&g, &spec).unwrap();
                assert_eq!(gpu.objects(), objects);
                let mut hits = b.filled(rays.len(), Hit::MISS).unwrap();
                let mut gpu_stats = Stats::default();
                let mut batches = 0;
                gpu.traverse(
                    &b,
                    &gpu_rays,
                    kind,
                    &gpu_h,
                    &mut |batch, st| {
                        let pairs: Vec<Candidate> = b.download(&batch.pairs).unwrap();
                        assert!(
                            pairs.windows(2).all(|w| w[0] < w[1]),
                            "{what}: pairs not increasing"
                        );
                        if let Some(l) = &batch.lanes {
                            assert!(single, "{what}: lane masks without single rays");
                            let l = b.download(l).unwrap();
                            assert_eq!(l.len(), pairs.len());
                            assert!(l.iter().all(|&m| m != 0), "{what}: an empty lane mask");
                        }
                        batches += 1;
                        let q = Query::Candidates {
                            hierarchy: &gpu_h,
                            batch: &batch,
                        };
                        gpu_brute.intersect(&b, &gpu_rays, q, mode, &mut hits, st)
                    },
                    &mut gpu_stats,
                )
                .unwrap_or_else(|e| panic!("{what}: {e}"));
                let got = b.download(&hits).unwrap();
                for (i, (g, w)) in got.iter().zip(&scene_hits).enumerate() {
                    match mode {
                        HitMode::Any => assert_eq!(g.is_hit(), w.is_hit(), "{what}: ray {i}"),
                        _ => assert_eq!(g, w, "{what}: ray {i}"),
                    }
                }
                let agree = got
                    .iter()
                    .zip(&want)
                    .filter(|(g, w)| {
                        g.is_hit() == w.is_hit() && (mode == HitMode::Any || g.tri == w.tri)
                    })
                    .count();
                assert!(
                    agree * 1000 >= rays.len() * 999,
                    "{what}: {agree} of {} agree with the CPU",
                    rays.len()
                );
                if budget < 1.0 {
                    assert!(batches > 1, "{what}: one batch");
                } else {
                    let peak = gpu_stats.peak_candidate_bytes;
                    assert!(
                        peak > 0 && peak as f64 <= budget * 1024.0 * 1024.0,
                        "{what}: peak {peak} bytes"
                    );
                }
                let (gb, cb) = (gpu_stats.tests.bounds, cpu_stats.tests.bounds);
                println!(
                    "{what}: bounds GPU {gb} CPU {cb}, ray-triangle GPU {} CPU {}, {batches} \
                     batches",
                    gpu_stats.tests.ray_triangle, cpu_stats.tests.ray_triangle
                );
                assert!(
                    (gb as f64 - cb as f64).abs() <= 0.05 * cb as f64 + 50.0,
                    "{what}: bounds tests GPU {gb} CPU {cb}"
                );
                // (Under the tiny budget the batches differ: a grid triangle's repeats split
                // over two batches are tested twice, and any-hit rays skip what an earlier
                // batch hit, so only whole batches compare.)
                let rt = |st: &Stats| st.tests.ray_triangle as f64;
                assert!(
                    budget < 1.0
                        || (rt(&gpu_stats) - rt(&cpu_stats)).abs() <= 0.05 * rt(&cpu_stats) + 50.0,
                    "{what}: ray-triangle tests"
                );
                if objects == "meshes" {
                    assert!(gpu_stats.object_levels.is_empty());
                    assert!(!gpu_stats.mesh_culling.is_empty());
                    continue;
                }
                // Both tables account for every test (level 0 is the final tests' row).
                let ray_rows: Vec<_> = gpu_stats
                    .levels
                    .iter()
                    .filter(|r| r.level > 0)
                    .cloned()
                    .collect();
                assert_eq!(row_sum(&ray_rows), gb, "{what}: ray rows");
                assert_eq!(row_sum(&gpu_stats.object_levels), gb, "{what}: object rows");
                assert_eq!(
                    gpu_stats.object_levels.len(),
                    cpu_stats.object_levels.len(),
                    "{what}"
                );
            }
        }
    }
}

/// A bad hierarchy is an error, no rays call no sink, and the GPU `dual` is what the wgpu
/// registry builds for `traverse.kind = dual`.
#[test]
fn dual_traversal_refuses_bad_hierarchies() {
    use crsh_core::{SphereCone, Traverser};
    let Some(b) = crsh_wgpu::testing::shared_backend("dual_traversal_refuses_bad_hierarchies")
    else {
        return;
    };
    let s = scene("cornell-mirrors");
    let g = GpuScene::new(&b, &s).unwrap();
    let (rays, order) = cpu_rays(&s, RayKind::Shadow);
    let mut cpu_h = crsh_cpu::hierarchy::sphere_cone::SphereConeBuilder::with_params(8, 2)
        .unwrap()
        .build(&Cpu, &rays, order, &mut Stats::default())
        .unwrap();
    let trav =
        crsh_wgpu::traverse::dual::Dual::new(&g, &dual_spec("lbvh", true, true, 64.0)).unwrap();
    cpu_h.levels[1][0].sphere.radius = f32::NAN;
    let h = upload_hierarchy(&b, &cpu_h);
    let r = trav.traverse(
        &b,
        &b.upload(&rays).unwrap(),
        RayKind::Shadow,
        &h,
        &mut |_, _| Ok(()),
        &mut Stats::default(),
    );
    assert!(
        matches!(&r, Err(crsh_core::CoreError::InvalidInput(m)) if m.contains("non-finite")),
        "{r:?}"
    );
    let empty: Vec<Ray> = Vec::new();
    let h0: RayHierarchy<Wgpu> = RayHierarchy {
        leaf_offsets: None,
        order: b.upload::<u32>(&[]).unwrap(),
        levels: vec![b.upload::<SphereCone>(&[]).unwrap()],
        subdivision: 8,
        reach: Vec::new(),
    };
    trav.traverse(
        &b,
        &b.upload(&empty).unwrap(),
        RayKind::Shadow,
        &h0,
        &mut |_, _| panic!("a sink call without rays"),
        &mut Stats::default(),
    )
    .unwrap();
}

/// The `f32` node test of the GPU traversals keeps every pair the CPU's `f64` test keeps, on
/// pairs placed at its boundary: for each triangle sphere of a scene, nodes whose cone axis
/// makes exactly the angle α + β with the direction to the sphere (β = asin(ρ / D), ρ the
/// CPU's margin-widened radius sum), give or take 1e-7 to 1e-3 rad, with half-angles from
/// 1e-5 rad to nearly π, distances from just above ρ to 2000 and centres far from the origin;
/// and nodes whose sphere almost reaches the triangle's (D = ρ·(1 ± 1e-6)), some behind their
/// apex. A one-level hierarchy without mesh culling makes the candidates exactly the pairs
/// that pass. The GPU may keep a few more, not many.
#[test]
fn gpu_node_test_keeps_every_pair_the_cpu_keeps_at_the_boundary() {
    use crsh_core::glam::{DVec3, Vec3};
    use crsh_core::{Candidate, Cone, Sphere, SphereCone, Traverser};
    let Some(b) = crsh_wgpu::testing::shared_backend(
        "gpu_node_test_keeps_every_pair_the_cpu_keeps_at_the_boundary",
    ) else {
        return;
    };
    let s = scene("office-boxes");
    let g = GpuScene::new(&b, &s).unwrap();
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut unit = move || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut nodes: Vec<SphereCone> = Vec::new();
    let tris = &s.tri_spheres;
    for k in 0..3000 {
        let t = &tris[(k * 7919) % tris.len()];
        let p = t.center.as_dvec3();
        // A random direction from the sphere to the node's centre, at distance d.
        let dir = DVec3::new(unit() - 0.5, unit() - 0.5, unit() - 0.5).normalize();
        let r = [0.0, 0.01, 0.3][k % 3] * unit();
        let half = [1e-5, 1e-3, 0.05, 0.7, 1.5, 2.5, 3.0][k % 7] as f32;
        let alpha = half as f64 + 1e-4;
        let d_far = [2.0, 30.0, 2000.0][(k / 7) % 3] * (0.5 + unit());
        let c0 = p + dir * d_far;
        let scale = |c: DVec3| c.abs().max_element().max(p.abs().max_element()).max(1.0);
        let rho = (t.radius as f64 + r) * (1.0 + 1e-4) + 1e-5 * scale(c0);
        let (c, d) = if k % 11 == 0 {
            // The node's sphere almost reaching the triangle's.
            let d = rho * (1.0 + [-1e-6, 1e-6, 3e-6][k % 3]);
            (p + dir * d, d)
        } else {
            (c0, d_far)
        };
        let v = (p - c).normalize();
        let beta = (rho / d).min(1.0).asin();
        let delta = [1e-7, 1e-6, 1e-5, 1e-3][k % 4] * if k % 2 == 0 { 1.0 } else { -1.0 };
        let phi = (alpha + beta + delta).clamp(0.0, std::f64::consts::PI);
        // An axis at angle phi from v.
        let w = v
            .cross(DVec3::new(unit() - 0.5, unit() - 0.5, unit() - 0.5))
            .normalize();
        let axis = v * phi.cos() + w * phi.sin();
        nodes.push(SphereCone {
            sphere: Sphere {
                center: c.as_vec3(),
                radius: r as f32,
            },
            cone: Cone {
                axis: axis.as_vec3(),
                half_angle: half,
            },
        });
    }
    let n = nodes.len();
    let order: Vec<u32> = (0..n as u32).collect();
    let cpu_h: RayHierarchy<Cpu> = RayHierarchy {
        order: order.clone(),
        levels: vec![nodes.clone()],
        subdivision: 1,
        leaf_offsets: None,
        reach: Vec::new(),
    };
    let gpu_h = upload_hierarchy(&b, &cpu_h);
    // The traversal reads no ray; the hierarchy's shape needs one per leaf.
    let ray = crsh_wgpu::testing::ray(Vec3::ZERO, Vec3::X, 0.0, 1.0, RayKind::Shadow, 0);
    let rays = vec![ray; n];
    let spec = traverse_spec(false, 64.0);
    let cpu = crsh_cpu::traverse::crsh::Crsh::new(&s, &spec).unwrap();
    let mut want: Vec<Candidate> = Vec::new();
    cpu.traverse(
        &Cpu,
        &rays,
        RayKind::Shadow,
        &cpu_h,
        &mut |batch, _| {
            want.extend(batch.pairs);
            Ok(())
        },
        &mut Stats::default(),
    )
    .unwrap();
    let gpu = crsh_wgpu::traverse::crsh::Crsh::new(&g, &spec).unwrap();
    let mut got: Vec<Candidate> = Vec::new();
    gpu.traverse(
        &b,
        &b.upload(&rays).unwrap(),
        RayKind::Shadow,
        &gpu_h,
        &mut |batch, _| {
            got.extend(b.download(&batch.pairs).unwrap());
            Ok(())
        },
        &mut Stats::default(),
    )
    .unwrap();
    let have: std::collections::HashSet<Candidate> = got.iter().copied().collect();
    let missing: Vec<&Candidate> = want.iter().filter(|c| !have.contains(c)).collect();
    println!(
        "{n} nodes × {} triangles: CPU keeps {}, GPU {}",
        tris.len(),
        want.len(),
        got.len()
    );
    assert!(
        missing.is_empty(),
        "{} pairs the CPU keeps are culled on the GPU, e.g. {:?}",
        missing.len(),
        &missing[..missing.len().min(5)]
    );
    // Pairs placed just inside and just outside: the GPU passes at most a few more.
    assert!(want.len() > n / 4, "too few pairs at the boundary pass");
    assert!(
        got.len() as f64 <= want.len() as f64 * 1.01 + 10.0,
        "GPU keeps {} pairs, CPU {}",
        got.len(),
        want.len()
    );
}
