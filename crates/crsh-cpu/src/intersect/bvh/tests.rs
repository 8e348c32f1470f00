//! Tests of the `bvh` intersector (and helpers the other obvhs intersectors' tests share).

use super::*;
use crate::intersect::brute::tests::{random_rays, soup, test_ray};
use crate::intersect::brute::BruteForce;
use crate::surface::tests::raw_scene;
use crate::triangle::tests::TestRng;
use crsh_core::{CandidateBatch, ParamValue, RayHierarchy, RayKind, TestCounts};

/// `x`'s hits and stats for `rays` (all misses before).
pub(crate) fn run(x: &dyn Intersector<Cpu>, rays: &Vec<Ray>, mode: HitMode) -> (Vec<Hit>, Stats) {
    let mut hits = vec![Hit::MISS; rays.len()];
    let mut stats = Stats::default();
    x.intersect(&Cpu, rays, Query::Scene, mode, &mut hits, &mut stats)
        .unwrap();
    (hits, stats)
}

/// Ray `ray` against scene triangle `tri` alone, with test `test`.
fn single_hit(scene: &Scene, test: TestKind, tri: u32, ray: &Ray) -> Option<Hit> {
    fn with<T: TriangleTest>(scene: &Scene, tri: u32, ray: &Ray) -> Option<Hit> {
        let [a, b, c] = scene.triangle(tri as usize);
        T::hit(
            &T::prepare(a, b, c),
            &T::ray_of(ray),
            ray.t_min,
            ray.t_max,
            tri,
        )
    }
    match test {
        TestKind::MollerTrumbore => with::<MollerTrumbore>(scene, tri, ray),
        TestKind::Watertight => with::<Watertight>(scene, tri, ray),
        TestKind::Projected => with::<Projected>(scene, tri, ray),
    }
}

fn check_against_brute(scene: &Scene, rays: &Vec<Ray>, quality: BuildQuality) {
    for test in TestKind::ALL {
        let bvh = CwBvh::build_with_test(scene, quality, test);
        assert_eq!(bvh.test(), test);
        check_exact(scene, rays, test, &bvh, &format!("bvh {quality:?}"));
    }
}

/// `got` (of `what`) against brute force's `want` for `rays` in `mode`: closest hits
/// bit for bit (triangle, `t`, `u`, `v`), any hits hit or miss alike.
pub(crate) fn assert_same_hits(rays: &[Ray], got: &[Hit], want: &[Hit], mode: HitMode, what: &str) {
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        match mode {
            HitMode::Closest | HitMode::EdgeWidth(_) => assert_eq!(
                (g.tri, g.t.to_bits(), g.u.to_bits(), g.v.to_bits()),
                (w.tri, w.t.to_bits(), w.u.to_bits(), w.v.to_bits()),
                "{what} ray {i}: {:?}: got {g:?} brute {w:?}",
                rays[i]
            ),
            HitMode::Any => {
                assert_eq!(g.is_hit(), w.is_hit(), "{what} any ray {i}: {:?}", rays[i])
            }
        }
    }
}

/// `x` (built on `scene` for test `test`; `what` names it) finds brute force's closest
/// hits bit for bit and its any-hit answers, each any hit a hit of its triangle as the
/// scalar test computes it; any-hit rays test no more triangles than closest-hit ones.
pub(crate) fn check_exact(
    scene: &Scene,
    rays: &Vec<Ray>,
    test: TestKind,
    x: &dyn Intersector<Cpu>,
    what: &str,
) {
    let brute = BruteForce::with_test(scene, test);
    let what = format!("{what} {test:?}");
    let (want, _) = run(&brute, rays, HitMode::Closest);
    let (got, stats) = run(x, rays, HitMode::Closest);
    assert_same_hits(rays, &got, &want, HitMode::Closest, &what);
    assert!(stats.tests.bounds > 0);
    let (want, _) = run(&brute, rays, HitMode::Any);
    let (got, any_stats) = run(x, rays, HitMode::Any);
    assert_same_hits(rays, &got, &want, HitMode::Any, &what);
    for (i, g) in got.iter().enumerate() {
        if g.is_hit() {
            assert_eq!(
                single_hit(scene, test, g.tri, &rays[i]),
                Some(*g),
                "{what} any ray {i}"
            );
        }
    }
    assert!(any_stats.tests.ray_triangle <= stats.tests.ray_triangle);
}

/// A refitted BVH (kept binary tree, moved triangles) answers exactly as brute force on the
/// moved scene, for every test; a BVH built to rebuild keeps nothing to refit, and the
/// kept tree is used once.
#[test]
fn refitted_trees_are_identical_to_brute_force_on_the_moved_scene() {
    let (anim, _) = crsh_scene::load_animated("cornell-mirrors-animated").unwrap();
    for test in TestKind::ALL {
        let mut bvh = CwBvh::build_with_test(anim.scene(), BuildQuality::Medium, test);
        let rebuild_only = CwBvh {
            refit: None,
            ..CwBvh::build_with_test(anim.scene(), BuildQuality::Fast, test)
        };
        assert!(rebuild_only.refitted(anim.scene()).is_none());
        let mut scene = anim.scene().clone();
        for frame in [3, 7, 11] {
            anim.update(&mut scene, frame, false).unwrap();
            let refitted = bvh.refitted(&scene).expect("a kept tree");
            assert!(bvh.refitted(&scene).is_none(), "the kept tree moved on");
            check_moved_frame(&scene, frame, test, &refitted);
            bvh = refitted;
        }
    }
}

/// A tree refitted to `scene` (frame `frame` of an animation, for test `test`) answers
/// exactly as brute force on it.
pub(crate) fn check_moved_frame(
    scene: &Scene,
    frame: u32,
    test: TestKind,
    x: &dyn Intersector<Cpu>,
) {
    let rays = random_rays(scene, frame as u64, 3000);
    let brute = BruteForce::with_test(scene, test);
    for mode in [HitMode::Closest, HitMode::Any] {
        let (want, _) = run(&brute, &rays, mode);
        let (got, stats) = run(x, &rays, mode);
        assert!(stats.tests.bounds > 0);
        assert_same_hits(&rays, &got, &want, mode, &format!("{test:?} frame {frame}"));
    }
}

#[test]
fn identical_to_brute_force_on_random_soups() {
    for (seed, n) in [(21u64, 500usize), (22, 60), (23, 1)] {
        let scene = soup(seed, n);
        let rays = random_rays(&scene, seed + 100, 1500);
        for q in [
            BuildQuality::Fast,
            BuildQuality::Medium,
            BuildQuality::Slow,
            BuildQuality::VerySlow,
        ] {
            check_against_brute(&scene, &rays, q);
        }
    }
}

/// An axis-aligned box room (flat boxes: zero-thickness node slabs) with rays grazing
/// along the walls, starting on them, and axis-parallel directions (zero components).
pub(crate) fn box_room() -> (Scene, Vec<Ray>) {
    let mut positions = Vec::new();
    let mut indices = Vec::new();
    // A 6x6 grid of unit quads on each of three planes, plus exactly overlapping copies.
    for (axis, offset) in [(0usize, 0.0f32), (1, 0.0), (2, 0.0), (2, 3.0), (0, 3.0)] {
        for i in 0..6 {
            for j in 0..6 {
                let corner = |di: f32, dj: f32| {
                    let mut p = [0.0f32; 3];
                    p[axis] = offset;
                    p[(axis + 1) % 3] = (i as f32 + di) * 0.5;
                    p[(axis + 2) % 3] = (j as f32 + dj) * 0.5;
                    Vec3::from_array(p)
                };
                let b = positions.len() as u32;
                positions.extend([
                    corner(0.0, 0.0),
                    corner(1.0, 0.0),
                    corner(1.0, 1.0),
                    corner(0.0, 1.0),
                ]);
                indices.extend([[b, b + 1, b + 2], [b, b + 2, b + 3]]);
            }
        }
    }
    let n = positions.len();
    let scene = raw_scene(positions, vec![Vec3::Z; n], indices);
    let mut rng = TestRng(31);
    let mut rays = Vec::new();
    let axes = [Vec3::X, Vec3::Y, Vec3::Z, -Vec3::X, -Vec3::Y, -Vec3::Z];
    for i in 0..3000 {
        let grid = |rng: &mut TestRng| (rng.next_u64() % 13) as f32 * 0.25;
        let mut o = Vec3::new(grid(&mut rng), grid(&mut rng), grid(&mut rng));
        if i % 3 == 0 {
            o = rng.vec3(-0.5, 3.5);
        }
        let dir = match i % 4 {
            0 => axes[i % 6],
            1 => (axes[i % 6] + axes[(i / 6) % 6] * 0.5).normalize_or(Vec3::X),
            2 => rng.unit(),
            _ => (axes[i % 6] + rng.unit() * 1e-3).normalize(),
        };
        rays.push(Ray {
            origin: o,
            t_min: if i % 5 == 0 { 0.0 } else { 1e-5 },
            dir,
            t_max: if i % 7 == 0 { 1.0 } else { f32::INFINITY },
            throughput: Vec3::ONE,
            kind: RayKind::Reflection as u32,
            pixel: 0,
            light: u32::MAX,
            depth: 1,
            source: 0,
        });
    }
    (scene, rays)
}

#[test]
fn identical_to_brute_force_on_grazing_axis_aligned_rays() {
    let (scene, rays) = box_room();
    for q in [BuildQuality::Fast, BuildQuality::Medium] {
        check_against_brute(&scene, &rays, q);
    }
}

/// Built-in scenes (axis-aligned walls and boxes): rays leaving surfaces in random
/// directions, as reflection and shadow rays do.
#[test]
fn identical_to_brute_force_on_builtin_scenes() {
    for name in crsh_scene::builtin::STATIC_NAMES {
        let scene = crsh_scene::builtin::build(name).unwrap_or_else(|e| panic!("{name}: {e}"));
        let rays = builtin_rays(&scene, 61, 1200);
        check_against_brute(&scene, &rays, BuildQuality::Medium);
    }
}

#[test]
fn candidates_are_unsupported_and_bad_params_rejected() {
    let scene = Arc::new(soup(41, 20));
    let mut spec = StageSpec::new("bvh");
    assert!(CwBvh::new(&scene, &spec).is_err(), "unresolved spec");
    spec.params
        .insert("build_quality".into(), ParamValue::Str("ultra".into()));
    assert!(matches!(
        CwBvh::new(&scene, &spec),
        Err(CoreError::InvalidParam { .. })
    ));
    spec.params
        .insert("build_quality".into(), ParamValue::Str("fast".into()));
    assert!(CwBvh::new(&scene, &spec).is_err(), "no test given");
    spec.params
        .insert("test".into(), ParamValue::Str("square".into()));
    assert!(matches!(
        CwBvh::new(&scene, &spec),
        Err(CoreError::InvalidParam { .. })
    ));
    spec.params
        .insert("test".into(), ParamValue::Str("watertight".into()));
    assert!(CwBvh::new(&scene, &spec).is_err(), "no update given");
    spec.params
        .insert("update".into(), ParamValue::Str("sometimes".into()));
    assert!(matches!(
        CwBvh::new(&scene, &spec),
        Err(CoreError::InvalidParam { .. })
    ));
    spec.params
        .insert("update".into(), ParamValue::Str("rebuild".into()));
    assert!(CwBvh::new(&scene, &spec).is_err(), "no exact given");
    spec.params.insert("exact".into(), ParamValue::Bool(true));
    let bvh = CwBvh::new(&scene, &spec).unwrap();
    assert_eq!(bvh.test(), TestKind::Watertight);
    assert_eq!(bvh.quality(), BuildQuality::Fast);
    assert!(bvh.exact());
    rejects_candidates_and_bad_rays(&bvh, &scene);
    spec.params.insert("exact".into(), ParamValue::Bool(false));
    let stock = CwBvh::new(&scene, &spec).unwrap();
    assert!(!stock.exact());
    rejects_candidates_and_bad_rays(&stock, &scene);
}

/// `bvh` on `scene` with `exact = false` (obvhs's own tests), through the registry.
fn stock_bvh(scene: &Arc<Scene>) -> Box<dyn Intersector<Cpu>> {
    let ctx = StageContext::new(&Cpu, scene, crsh_core::FrameSize::new(8, 8).unwrap());
    let mut spec = StageSpec::new("bvh");
    spec.params.insert("exact".into(), ParamValue::Bool(false));
    Registry::<Cpu>::builtin()
        .build_intersector(&ctx, &spec)
        .unwrap()
}

/// `exact = false` is obvhs's traversal: on the built-in scenes (rays hugging the walls'
/// edges on purpose) it finds brute force's triangle on at least 90 % of the rays (93.75 %
/// on `glass-sphere`), with `t`, `u`, `v` equal up to rounding (obvhs's arithmetic cancels on
/// grazing rays: `t` within `1e-3` relative, `u`, `v` within `1e-2`), answers any-hit
/// queries alike as often, and reports its tests as unknown, never as 0. The differences
/// are obvhs's (the next two tests).
#[test]
fn stock_traversal_agrees_with_brute_force_up_to_obvhs_failures() {
    for name in crsh_scene::builtin::STATIC_NAMES {
        let scene = Arc::new(crsh_scene::builtin::build(name).unwrap());
        let rays = builtin_rays(&scene, 61, 1200);
        let brute = BruteForce::with_test(&scene, TestKind::MollerTrumbore);
        let stock = stock_bvh(&scene);
        for mode in [HitMode::Closest, HitMode::Any] {
            let (want, _) = run(&brute, &rays, mode);
            let (got, stats) = run(stock.as_ref(), &rays, mode);
            assert!(stats.tests.uncounted, "{name}: counted");
            let mut differ = 0;
            for (g, w) in got.iter().zip(&want) {
                if mode == HitMode::Any {
                    differ += usize::from(g.is_hit() != w.is_hit());
                } else if g.tri != w.tri {
                    differ += 1;
                } else if g.is_hit() {
                    assert!(
                        (g.t - w.t).abs() <= 1e-3 * w.t.max(1.0),
                        "{name}: {g:?} {w:?}"
                    );
                    assert!((g.u - w.u).abs() <= 1e-2, "{name}: {g:?} {w:?}");
                    assert!((g.v - w.v).abs() <= 1e-2, "{name}: {g:?} {w:?}");
                }
            }
            assert!(
                differ * 10 <= rays.len(),
                "{name} {mode:?}: {differ} differ"
            );
        }
    }
}

/// obvhs's triangle test where it fails: a ray parallel to the triangle's plane to `f32`
/// precision (`n·d/|n| ≈ -2e-7`; one of `cornell-mirrors`' sphere triangles) gets a hit at
/// `t = 0.5`, where crsh's Möller-Trumbore (and exact arithmetic) put the plane at `0.84` and
/// the crossing far outside the triangle (`u ≈ -0.8`).
#[test]
fn obvhs_triangle_test_hits_a_triangle_the_ray_runs_beside() {
    let [a, b, c] = [
        Vec3::new(0.199_999_99, -0.723_606_8, -0.523_606_8),
        Vec3::new(0.170_130_16, -0.835_114_1, -0.475_276_4),
        Vec3::new(0.103_956_76, -0.773_555_46, -0.545_067_4),
    ];
    let (o, d) = (
        Vec3::new(0.383_545_64, 0.094_621_48, -0.896_834_2),
        Vec3::new(-0.238_676_86, -0.891_006_6, 0.386_187_08),
    );
    let t =
        obvhs_triangle([a, b, c]).intersect(&obvhs::ray::Ray::new(o.into(), d.into(), 0.0, 100.0));
    assert!(t.is_finite(), "obvhs reports a hit");
    let ray = test_ray(o, d, 0.0, 100.0, 0);
    let ours = MollerTrumbore::hit(
        &MollerTrumbore::prepare(a, b, c),
        &MollerTrumbore::ray_of(&ray),
        0.0,
        100.0,
        0,
    );
    assert_eq!(ours, None);
}

/// Where obvhs's node test fails, `exact = false` fails with it, while the exact `bvh` (and
/// brute force) hit: obvhs clamps the boxes' entry distance to `1e-4` whatever the ray's
/// `t_min`, so a triangle `5e-5` ahead of the origin is lost; and a direction component of
/// `-0.0` (as `-Vec3::Z` has) gets an inverse of `-1/ε` while the plane order takes it as
/// positive, so the ray misses every box it crosses along that axis.
#[test]
fn stock_traversal_loses_hits_closer_than_obvhs_clamp() {
    let scene = Arc::new(raw_scene(
        vec![
            Vec3::new(-1.0, -1.0, 0.0),
            Vec3::new(1.0, -1.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ],
        vec![Vec3::Z; 3],
        vec![[0, 1, 2]],
    ));
    let rays = vec![test_ray(Vec3::new(0.0, 0.0, 5e-5), -Vec3::Z, 0.0, 10.0, 0)];
    let exact = CwBvh::build(&scene, BuildQuality::Medium);
    let stock = stock_bvh(&scene);
    for mode in [HitMode::Closest, HitMode::Any] {
        assert!(run(&exact, &rays, mode).0[0].is_hit(), "exact {mode:?}");
        assert!(
            !run(stock.as_ref(), &rays, mode).0[0].is_hit(),
            "stock {mode:?}"
        );
    }
    let signed_zero = vec![test_ray(Vec3::new(0.1, 0.2, 2.0), -Vec3::Z, 0.0, 10.0, 0)];
    assert!(run(&exact, &signed_zero, HitMode::Closest).0[0].is_hit());
    assert!(!run(stock.as_ref(), &signed_zero, HitMode::Closest).0[0].is_hit());
    // The same ray with `+0.0` components, or tilted: both hit the same triangle alike.
    let far = vec![test_ray(
        Vec3::new(0.1, 0.2, 2.0),
        Vec3::new(0.0, 0.0, -1.0),
        0.0,
        10.0,
        0,
    )];
    let (a, b) = (
        run(&exact, &far, HitMode::Closest).0[0],
        run(stock.as_ref(), &far, HitMode::Closest).0[0],
    );
    assert_eq!(a.tri, b.tri);
    assert!(
        (a.t - b.t).abs() < 1e-6 && (a.u - b.u).abs() < 1e-6 && (a.v - b.v).abs() < 1e-6,
        "{a:?} {b:?}"
    );
}

/// `x` (built on `scene`) refuses candidate queries and batches with an invalid ray.
pub(crate) fn rejects_candidates_and_bad_rays(x: &dyn Intersector<Cpu>, scene: &Scene) {
    assert!(!x.supports_candidates());
    let rays = random_rays(scene, 42, 8);
    let h = RayHierarchy::<Cpu> {
        leaf_offsets: None,
        order: (0..8).collect(),
        levels: vec![vec![bytemuck::Zeroable::zeroed(); 1]],
        subdivision: 8,
        reach: vec![],
    };
    let batch = CandidateBatch::<Cpu>::new(vec![]);
    let mut hits = vec![Hit::MISS; 8];
    let r = x.intersect(
        &Cpu,
        &rays,
        Query::Candidates {
            hierarchy: &h,
            batch: &batch,
        },
        HitMode::Closest,
        &mut hits,
        &mut Stats::default(),
    );
    assert!(matches!(r, Err(CoreError::Unsupported { .. })));
    // The one message every whole-scene intersector gives.
    let q: Query<Cpu> = Query::Candidates {
        hierarchy: &h,
        batch: &batch,
    };
    assert_eq!(
        r.unwrap_err().to_string(),
        q.whole_scene_only(x.name()).unwrap_err().to_string()
    );
    assert!(Query::<Cpu>::Scene.whole_scene_only(x.name()).is_ok());
    let mut bad = rays.clone();
    bad[0].origin.x = f32::INFINITY;
    assert!(x
        .intersect(
            &Cpu,
            &bad,
            Query::Scene,
            HitMode::Any,
            &mut hits,
            &mut Stats::default()
        )
        .is_err());
}

#[test]
fn all_degenerate_scene_never_hits() {
    let scene = degenerate_scene();
    let bvh = CwBvh::build(&scene, BuildQuality::Medium);
    assert_eq!(bvh.node_count(), 0);
    check_never_hits(&bvh, &scene);
}

/// A scene of one degenerate triangle (nothing to put in a tree).
pub(crate) fn degenerate_scene() -> Scene {
    raw_scene(
        vec![Vec3::ZERO, Vec3::X, Vec3::X * 2.0],
        vec![Vec3::Z; 3],
        vec![[0, 1, 2]],
    )
}

/// `x` (an empty tree over `scene`) hits nothing and counts nothing.
pub(crate) fn check_never_hits(x: &dyn Intersector<Cpu>, scene: &Scene) {
    let rays = random_rays(scene, 43, 16);
    for mode in [HitMode::Closest, HitMode::Any] {
        let (hits, stats) = run(x, &rays, mode);
        assert!(hits.iter().all(|h| !h.is_hit()));
        assert_eq!(stats.tests, TestCounts::default());
    }
}

#[test]
fn same_result_for_any_thread_count() {
    let scene = soup(51, 400);
    let bvh = CwBvh::build(&scene, BuildQuality::Medium);
    let rays = random_rays(&scene, 52, 700);
    same_for_one_and_two_threads(&bvh, &rays);
    // The BVH does far fewer triangle tests than brute force.
    let (_, stats) = run(&bvh, &rays, HitMode::Closest);
    assert!(stats.tests.ray_triangle * 5 < (rays.len() * scene.triangle_count()) as u64);
}

/// `x` gives the same hits and counts (all of them, visits included) on pools of 1 and 2
/// threads, and visits nodes and leaves.
pub(crate) fn same_for_one_and_two_threads(x: &dyn Intersector<Cpu>, rays: &Vec<Ray>) {
    for mode in [HitMode::Closest, HitMode::Any] {
        let a = crate::with_threads(1, || run(x, rays, mode)).unwrap();
        let b = crate::with_threads(2, || run(x, rays, mode)).unwrap();
        assert_eq!(a.0, b.0, "{mode:?}");
        assert_eq!(a.1.tests, b.1.tests, "{mode:?}");
        assert!(
            a.1.tests.inner_nodes > 0 && a.1.tests.leaves > 0,
            "{mode:?}"
        );
    }
}

/// The counts of `ray` traced alone.
pub(crate) fn one(x: &dyn Intersector<Cpu>, ray: &Ray, mode: HitMode) -> (Hit, TestCounts) {
    let (h, s) = run(x, &vec![*ray], mode);
    (h[0], s.tests)
}

/// Per-ray visit invariants of `x` on `rays` (module doc, "Counting"): every ray traced
/// visits at least `min_inner` inner nodes (the root), a leaf is counted only when a
/// primitive of it is tested, a closest hit was found in a visited leaf, and the batch
/// counts are the sums of the rays' own.
pub(crate) fn check_visit_counts(x: &dyn Intersector<Cpu>, rays: &Vec<Ray>, min_inner: u64) {
    for mode in [HitMode::Closest, HitMode::Any] {
        let mut sum = TestCounts::default();
        for (i, ray) in rays.iter().enumerate() {
            let (h, c) = one(x, ray, mode);
            assert!(c.inner_nodes >= min_inner, "{mode:?} ray {i}: {c:?}");
            assert!(c.leaves <= c.ray_triangle, "{mode:?} ray {i}: {c:?}");
            assert!(
                c.leaves > 0 || c.ray_triangle == 0,
                "{mode:?} ray {i}: {c:?}"
            );
            if h.is_hit() {
                assert!(c.leaves >= 1, "{mode:?} ray {i} hit without a leaf: {c:?}");
            }
            sum.bounds += c.bounds;
            sum.ray_triangle += c.ray_triangle;
            sum.inner_nodes += c.inner_nodes;
            sum.leaves += c.leaves;
        }
        let (_, batch) = run(x, rays, mode);
        assert_eq!(
            (
                batch.tests.bounds,
                batch.tests.ray_triangle,
                batch.tests.inner_nodes,
                batch.tests.leaves
            ),
            (sum.bounds, sum.ray_triangle, sum.inner_nodes, sum.leaves),
            "{mode:?}"
        );
    }
}

/// Built-in scenes: rays from random points and rays leaving surfaces.
pub(crate) fn builtin_rays(scene: &Scene, seed: u64, n: usize) -> Vec<Ray> {
    let mut rays = random_rays(scene, seed, n);
    let eps = scene.bounds.diagonal() * 1e-5;
    for r in rays.iter_mut().skip(1).step_by(4) {
        r.t_min = eps;
    }
    rays
}

#[test]
fn visit_counts_on_builtin_scenes() {
    for name in crsh_scene::builtin::STATIC_NAMES {
        let scene = crsh_scene::builtin::build(name).unwrap();
        let bvh = CwBvh::build(&scene, BuildQuality::Medium);
        let rays = builtin_rays(&scene, 71, 300);
        check_visit_counts(&bvh, &rays, 1);
        same_for_one_and_two_threads(&bvh, &rays);
    }
}

/// For closest hits every leaf child in a visited node's hit mask has all its primitives
/// tested: an independent recount from the hit masks (leaf children whose primitive bits
/// are set) gives the same inner and leaf visits, and those leaves' sizes add up to the
/// primitives tested. A ray that misses every box visits the root alone.
#[test]
fn leaf_visits_are_the_hit_leaf_children() {
    let scene = soup(81, 300);
    let bvh = CwBvh::build(&scene, BuildQuality::Medium);
    let leaf_tris = bvh.leaf_triangles_mt().unwrap();
    let mut rays = random_rays(&scene, 82, 400);
    rays.push(test_ray(
        Vec3::splat(5.0),
        Vec3::ONE.normalize(),
        0.0,
        f32::INFINITY,
        0,
    ));
    let mut seen_multi = false;
    for (i, ray) in rays.iter().enumerate() {
        let (hit, c) = one(&bvh, ray, HitMode::Closest);
        let r = MollerTrumbore::ray_of(ray);
        let nr = NodeRay::new(ray.origin, ray.dir);
        let t_lo = entry_bound(ray.t_min);
        let mut best = Hit::MISS;
        let mut t_hi = cull_distance(ray.t_max);
        let (mut inner, mut leaves, mut cluster_prims, mut prims) = (0u64, 0u64, 0u64, 0u64);
        let tree = &bvh.bvh;
        let mut state = tree.new_traversal(Vec3A::from(ray.dir));
        let mut node: &CwBvhNode;
        obvhs::traverse!(
            tree,
            node,
            state,
            {
                inner += 1;
                let mask = child_hits(node, &nr, state.oct_inv4, t_lo, t_hi);
                for c in 0..8 {
                    let m = node.child_meta[c];
                    if m != 0 && node.is_leaf(c) && (mask >> (m & 0x1f)) & 1 != 0 {
                        leaves += 1;
                        cluster_prims += u64::from((m >> 5).count_ones());
                        seen_multi |= m >> 5 != 1;
                    }
                }
                mask
            },
            {
                let slot = state.primitive_id as usize;
                prims += 1;
                let id = bvh.leaf_ids()[slot];
                if let Some(h) = MollerTrumbore::hit(&leaf_tris[slot], &r, ray.t_min, ray.t_max, id)
                {
                    if h.closer_than(&best) {
                        best = h;
                        t_hi = cull_distance(ray.t_max.min(best.t));
                    }
                }
            }
        );
        assert_eq!(best, hit, "ray {i}");
        assert_eq!(
            (c.inner_nodes, c.leaves, c.ray_triangle),
            (inner, leaves, prims),
            "ray {i}"
        );
        assert_eq!(cluster_prims, prims, "ray {i}");
    }
    assert!(seen_multi, "no leaf of 2 or 3 primitives was visited");
    let away = rays.last().unwrap();
    let (_, c) = one(&bvh, away, HitMode::Closest);
    let root = bvh.nodes()[0]
        .child_meta
        .iter()
        .filter(|&&m| m != 0)
        .count() as u64;
    assert_eq!(
        (c.inner_nodes, c.leaves, c.ray_triangle, c.bounds),
        (1, 0, 0, root)
    );
}

/// Any hit: a leaf is counted when its first-tested primitive is tested, so the leaves of
/// the last node that a stopping ray never reached are not (an independent recount that
/// marks each primitive that starts its leaf from the per-child definition).
#[test]
fn any_hit_leaf_visits_stop_where_the_ray_stops() {
    let scene = soup(83, 400);
    let bvh = CwBvh::build(&scene, BuildQuality::VerySlow);
    let leaf_tris = bvh.leaf_triangles_mt().unwrap();
    let rays = random_rays(&scene, 84, 600);
    let mut stopped_early = 0;
    for (i, ray) in rays.iter().enumerate() {
        let (hit, c) = one(&bvh, ray, HitMode::Any);
        let r = MollerTrumbore::ray_of(ray);
        let nr = NodeRay::new(ray.origin, ray.dir);
        let (t_lo, t_hi) = (entry_bound(ray.t_min), cull_distance(ray.t_max));
        let (mut inner, mut leaves, mut prims) = (0u64, 0u64, 0u64);
        let mut tops = 0u32;
        let mut found = Hit::MISS;
        let tree = &bvh.bvh;
        let mut state = tree.new_traversal(Vec3A::from(ray.dir));
        let mut node: &CwBvhNode;
        'trace: {
            obvhs::traverse!(
                tree,
                node,
                state,
                {
                    inner += 1;
                    tops = 0;
                    for (c, &m) in node.child_meta.iter().enumerate() {
                        if m != 0 && node.is_leaf(c) {
                            tops |= 1 << (u32::from(m & 0x1f) + (m >> 5).count_ones() - 1);
                        }
                    }
                    child_hits(node, &nr, state.oct_inv4, t_lo, t_hi)
                },
                {
                    let slot = state.primitive_id as usize;
                    let rel = state.primitive_id - state.primitive_group.x;
                    prims += 1;
                    leaves += u64::from((tops >> rel) & 1);
                    let id = bvh.leaf_ids()[slot];
                    if let Some(h) =
                        MollerTrumbore::hit(&leaf_tris[slot], &r, ray.t_min, ray.t_max, id)
                    {
                        found = h;
                        if state.primitive_group.y & tops != 0 {
                            stopped_early += 1;
                        }
                        break 'trace;
                    }
                }
            );
        }
        assert_eq!(found, hit, "ray {i}");
        assert_eq!(
            (c.inner_nodes, c.leaves, c.ray_triangle),
            (inner, leaves, prims),
            "ray {i}"
        );
    }
    assert!(
        stopped_early > 0,
        "no ray stopped before a leaf of its last node"
    );
}

/// The SSE node test is the scalar one bit for bit: every node of a random tree against rays
/// of every octant, axis-parallel rays (zero direction components), rays from inside and far
/// outside, with open, empty and ordinary intervals.
#[test]
fn simd_node_test_is_the_scalar_one() {
    let scene = soup(91, 400);
    let bvh = CwBvh::build(&scene, BuildQuality::Medium);
    let mut rays = random_rays(&scene, 92, 300);
    for dir in [Vec3::X, -Vec3::Y, Vec3::Z, Vec3::new(1.0, 1e-30, 0.0)] {
        rays.push(test_ray(Vec3::splat(0.3), dir, 0.0, f32::INFINITY, 0));
        rays.push(test_ray(Vec3::splat(-1e6), dir, 1e-3, 1e7, 0));
    }
    let mut compared = 0;
    for ray in &rays {
        let nr = NodeRay::new(ray.origin, ray.dir);
        let oct = bvh.bvh.new_traversal(Vec3A::from(ray.dir)).oct_inv4;
        for node in bvh.nodes() {
            for (t_lo, t_hi) in [
                (entry_bound(ray.t_min), cull_distance(ray.t_max)),
                (0.0, f32::INFINITY),
                (0.5, 0.25),
                (-1.0, 1.0),
            ] {
                assert_eq!(
                    child_test(node, &nr, oct, t_lo, t_hi),
                    child_test_scalar(node, &nr, oct, t_lo, t_hi),
                    "{ray:?} [{t_lo}, {t_hi}]"
                );
                compared += 1;
            }
        }
    }
    assert!(compared > 10_000, "{compared}");
}

/// The loop-free child and leaf masks are the per-child definitions on every node of a tree.
#[test]
fn child_masks_are_the_per_child_definitions() {
    let scene = soup(93, 500);
    let bvh = CwBvh::build(&scene, BuildQuality::Medium);
    for node in bvh.nodes() {
        let mut children = 0u32;
        let mut tops = 0u32;
        for (c, &m) in node.child_meta.iter().enumerate() {
            if m != 0 {
                children |= 1 << c;
                if node.is_leaf(c) {
                    tops |= 1 << (u32::from(m & 0x1f) + (m >> 5).count_ones() - 1);
                }
            }
        }
        assert_eq!(child_mask(node), children, "{node:?}");
        assert_eq!(leaf_top_bits(node, children), tops, "{node:?}");
    }
    for meta in [
        [0u8; 8],
        [1, 0, 0, 0, 0, 0, 0, 0x80],
        [0xff; 8],
        [0, 0x7f, 0, 1, 0, 0, 0, 0],
    ] {
        let node = CwBvhNode {
            child_meta: meta,
            ..bvh.nodes()[0]
        };
        let want = meta
            .iter()
            .enumerate()
            .fold(0u32, |m, (c, &b)| m | (u32::from(b != 0) << c));
        assert_eq!(child_mask(&node), want, "{meta:?}");
    }
}
