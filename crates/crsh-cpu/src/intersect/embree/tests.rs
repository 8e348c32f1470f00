//! Tests of the `embree` intersector: its parameters in every build; with the `embree`
//! feature, its hits against brute force in every mode, merging, refusals and determinism.

use std::sync::Arc;

use crsh_core::{CoreError, FrameSize, ParamValue, Registry, StageContext, StageKind, StageSpec};

use crate::backend::Cpu;
use crate::intersect::brute::tests::soup;

fn spec(mode: &str, coherent: bool, quality: &str) -> StageSpec {
    let mut s = StageSpec::new("embree");
    s.params.insert("mode".into(), ParamValue::Str(mode.into()));
    s.params
        .insert("coherent".into(), ParamValue::Bool(coherent));
    s.params
        .insert("quality".into(), ParamValue::Str(quality.into()));
    s
}

fn build(spec: &StageSpec) -> crsh_core::Result<Box<dyn crsh_core::Intersector<Cpu>>> {
    let registry = Registry::<Cpu>::builtin();
    let scene = Arc::new(soup(3, 40));
    let ctx = StageContext::new(&Cpu, &scene, FrameSize::new(8, 8).unwrap());
    registry.build_intersector(&ctx, spec)
}

/// Listed in every build, whole-scene only, with its defaults; bad values are refused by
/// name.
#[test]
fn catalogue_entry_and_bad_params() {
    let registry = Registry::<Cpu>::builtin();
    let v = registry.variant(StageKind::Intersect, "embree").unwrap();
    assert!(v.scene_only);
    for (mode, quality, key) in [("packet32", "high", "mode"), ("single", "best", "quality")] {
        let e = build(&spec(mode, false, quality)).err().unwrap();
        assert!(
            matches!(&e, CoreError::InvalidParam { key: k, .. } if k.ends_with(key)),
            "{e}"
        );
    }
}

/// Without the feature the variant refuses to build, naming the feature and the package.
#[cfg(not(feature = "embree"))]
#[test]
fn without_the_feature_it_names_the_feature_and_the_package() {
    let e = build(&StageSpec::new("embree")).err().unwrap().to_string();
    assert!(e.contains("`embree` cargo feature"), "{e}");
    assert!(e.contains("--features embree"), "{e}");
    assert!(e.contains("libembree-dev"), "{e}");
}

#[cfg(feature = "embree")]
mod with_embree {
    use super::*;
    use crate::intersect::brute::tests::random_rays;
    use crate::intersect::bvh::tests::{rejects_candidates_and_bad_rays, run};
    use crate::intersect::embree::tracer::Embree;
    use crate::intersect::embree::{Mode, Quality};
    use crsh_core::pipeline::compare_hits;
    use crsh_core::{AccuracyCounts, Hit, HitMode, Intersector, Query, Stats, UNKNOWN_TRI};

    /// Brute force (the registry's defaults) on `scene`.
    fn brute(scene: &Arc<crsh_scene::Scene>) -> Box<dyn Intersector<Cpu>> {
        let ctx = StageContext::new(&Cpu, scene, FrameSize::new(8, 8).unwrap());
        Registry::<Cpu>::builtin()
            .build_intersector(&ctx, &StageSpec::new("brute"))
            .unwrap()
    }

    /// Whether `ray` runs in the plane of some triangle of `scene` (within 1e-3): where
    /// Embree's ray-triangle test and Möller-Trumbore's disagree (Möller-Trumbore's
    /// determinant is 0 there and it reports no hit; Embree's edge test can report one).
    fn grazes(scene: &crsh_scene::Scene, ray: &crsh_core::Ray) -> bool {
        (0..scene.triangle_count()).any(|t| {
            let [a, b, c] = scene.triangle(t);
            let n = (b - a).cross(c - a).normalize_or_zero();
            n != crsh_core::glam::Vec3::ZERO
                && n.dot(ray.dir).abs() < 1e-3
                && n.dot(ray.origin - a).abs() < 1e-3
        })
    }

    /// Every mode, coherent flag and quality against brute force on a random soup (with
    /// degenerate and duplicated triangles, rays from surfaces and along triangle planes):
    /// every ray agrees (hit or miss, and the nearest triangle unless the `t` tie) except
    /// rays running in a triangle's plane, where the two tests differ by design; closest
    /// `t` agree to 1e-5 relative and barycentrics to 1e-3 (Embree normalises them in
    /// another order; thin triangles amplify it). Packets and single rays give the same hits.
    #[test]
    fn every_mode_agrees_with_brute_force() {
        let scene = Arc::new(soup(11, 300));
        let rays = random_rays(&scene, 5, 2000);
        let brute = brute(&scene);
        let (closest, _) = run(&*brute, &rays, HitMode::Closest);
        let (any, _) = run(&*brute, &rays, HitMode::Any);
        let mut single: Option<(Vec<Hit>, Vec<Hit>)> = None;
        let mut grazing = 0;
        for quality in [Quality::Low, Quality::Medium, Quality::High] {
            for mode in [Mode::Single, Mode::Packet4, Mode::Packet8, Mode::Packet16] {
                for coherent in [false, true] {
                    let x = Embree::new(&scene, mode, coherent, quality).unwrap();
                    let what = format!("{mode:?} coherent {coherent} {quality:?}");
                    let (got, stats) = run(&x, &rays, HitMode::Closest);
                    assert!(stats.tests.uncounted, "{what}: tests reported as counted");
                    let (got_any, _) = run(&x, &rays, HitMode::Any);
                    for (i, ray) in rays.iter().enumerate() {
                        let (g, w) = (&got[i], &closest[i]);
                        let differs = g.is_hit() != w.is_hit()
                            || (g.is_hit() && g.nearest_differs(w))
                            || got_any[i].is_hit() != any[i].is_hit();
                        if differs {
                            assert!(grazes(&scene, ray), "{what} ray {i} {ray:?}: {g:?} {w:?}");
                            grazing += 1;
                        } else if g.is_hit() {
                            assert!((g.t - w.t).abs() <= 1e-5 * w.t.abs().max(1.0), "{what}");
                            if g.tri == w.tri {
                                assert!(
                                    (g.u - w.u).abs() < 1e-3 && (g.v - w.v).abs() < 1e-3,
                                    "{what} ray {i}: {g:?} {w:?}"
                                );
                            }
                        }
                    }
                    assert!(got_any.iter().all(|h| !h.is_hit() || h.tri == UNKNOWN_TRI));
                    // Within one build, every query mode finds the same hits.
                    match &single {
                        None => single = Some((got, got_any)),
                        Some((c, a)) => {
                            let mut acc = AccuracyCounts::default();
                            compare_hits(&got, c, HitMode::Closest, &mut acc);
                            compare_hits(&got_any, a, HitMode::Any, &mut acc);
                            assert_eq!(acc.agreeing, acc.rays, "{what} vs single rays");
                        }
                    }
                }
            }
            single = None;
        }
        // The soup's grazing rays are a few in a thousand, and Embree hits some of them.
        assert!(
            grazing > 0 && grazing < 24 * 20,
            "{grazing} grazing mismatches"
        );
    }

    /// Stored hits merge as for every intersector: a closer stored hit stays, an any-hit ray
    /// already hit is not traced again, an empty interval stays a miss; a partial last packet
    /// is traced.
    #[test]
    fn merges_into_stored_hits() {
        let scene = Arc::new(soup(11, 300));
        let mut rays = random_rays(&scene, 7, 37);
        rays[3].t_min = rays[3].t_max;
        for mode in [Mode::Single, Mode::Packet16] {
            let x = Embree::new(&scene, mode, false, Quality::High).unwrap();
            let (fresh, _) = run(&x, &rays, HitMode::Closest);
            assert!(!fresh[3].is_hit(), "{mode:?}: empty interval");
            // 37 rays: the last packet has 5 lanes, traced like the others.
            let (want, _) = run(&*brute(&scene), &rays, HitMode::Closest);
            let mut acc = AccuracyCounts::default();
            compare_hits(&fresh, &want, HitMode::Closest, &mut acc);
            assert_eq!(acc.agreeing, 37, "{mode:?}: {acc:?}");
            assert!(
                want[32..].iter().any(|h| h.is_hit()),
                "the last packet hits something"
            );
            let closer = Hit {
                t: 1e-9,
                tri: 0,
                u: 0.0,
                v: 0.0,
            };
            let mut hits = vec![closer; rays.len()];
            x.intersect(
                &Cpu,
                &rays,
                Query::Scene,
                HitMode::Closest,
                &mut hits,
                &mut Stats::default(),
            )
            .unwrap();
            assert!(
                hits.iter().all(|h| *h == closer),
                "{mode:?}: a closer hit stays"
            );
            let mut hits = vec![closer; rays.len()];
            x.intersect(
                &Cpu,
                &rays,
                Query::Scene,
                HitMode::Any,
                &mut hits,
                &mut Stats::default(),
            )
            .unwrap();
            assert!(hits.iter().all(|h| *h == closer), "{mode:?}: any hit kept");
        }
    }

    /// The hits do not depend on the thread count.
    #[test]
    fn hits_do_not_depend_on_threads() {
        let scene = Arc::new(soup(13, 200));
        let rays = random_rays(&scene, 9, 3000);
        for mode in [Mode::Single, Mode::Packet8] {
            let runs: Vec<Vec<Hit>> = [1, 2, 3]
                .iter()
                .map(|&n| {
                    let pool = rayon::ThreadPoolBuilder::new()
                        .num_threads(n)
                        .build()
                        .unwrap();
                    pool.install(|| {
                        let x = Embree::new(&scene, mode, true, Quality::High).unwrap();
                        run(&x, &rays, HitMode::Closest).0
                    })
                })
                .collect();
            assert!(runs.windows(2).all(|w| w[0] == w[1]), "{mode:?}");
        }
    }

    /// Candidate queries, invalid rays and edge-width queries are refused.
    #[test]
    fn refuses_what_it_cannot_answer() {
        let scene = Arc::new(soup(3, 40));
        let x = Embree::new(&scene, Mode::Packet4, false, Quality::Medium).unwrap();
        rejects_candidates_and_bad_rays(&x, &scene);
        let rays = random_rays(&scene, 1, 4);
        let mut hits = vec![Hit::MISS; 4];
        let mode = HitMode::EdgeWidth(crsh_core::edge_width::EdgePairing::default());
        let e = x
            .intersect(
                &Cpu,
                &rays,
                Query::Scene,
                mode,
                &mut hits,
                &mut Stats::default(),
            )
            .unwrap_err();
        assert!(matches!(e, CoreError::Unsupported { .. }), "{e}");
    }
}
