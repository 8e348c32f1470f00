//! The stability suite's guarantees (issue 5), over the default suite of
//! `crsh_scene::stress::cases` and every pipeline × `intersect.test` × `raygen.offset` the
//! catalogue offers.

use std::collections::BTreeMap;
use std::sync::OnceLock;

use crsh_core::Registry;
use crsh_cpu::stress::{
    intersect_tests, offset_policies, run_suite, suite_presets, variants, StressRow,
};
use crsh_cpu::Cpu;
use crsh_scene::stress::cases;

/// The whole default table, computed once for all the tests of this file.
fn table() -> &'static [StressRow] {
    static ROWS: OnceLock<Vec<StressRow>> = OnceLock::new();
    ROWS.get_or_init(|| {
        let registry = Registry::<Cpu>::builtin();
        let pipelines = suite_presets(&registry);
        let vs = variants(
            &pipelines,
            &intersect_tests(&registry),
            &offset_policies(&registry),
        );
        let t0 = std::time::Instant::now();
        let rows = run_suite(&registry, &cases(), &vs, &mut |_, _, _| {}).expect("suite runs");
        eprintln!(
            "suite: {} rows in {:.1} s",
            rows.len(),
            t0.elapsed().as_secs_f64()
        );
        rows
    })
}

fn label(r: &StressRow) -> String {
    format!(
        "{} {} test={} offset={}",
        r.case,
        r.variant.pipeline,
        r.variant.test.as_deref().unwrap_or("default"),
        r.variant.offset.as_deref().unwrap_or("default")
    )
}

#[test]
fn nothing_panics_and_only_expected_errors() {
    let all = cases();
    for r in table() {
        assert!(!r.outcome.panicked, "{}: {:?}", label(r), r.outcome.error);
        let case = all.iter().find(|c| c.name == r.case).unwrap();
        if let Some(e) = &r.outcome.error {
            assert!(case.error_allowed(), "{}: unexpected error {e}", label(r));
        }
        if case.scene.is_err() {
            assert!(r
                .outcome
                .error
                .as_deref()
                .unwrap_or("")
                .contains("scene rejected"));
        }
    }
}

#[test]
fn exact_pipelines_agree_with_brute_force() {
    // Same intersect.test and offset: bvh, kdtree, crsh, rah and the dual presets find exactly
    // the hits brute does, so every count column is equal.
    let mut brute = BTreeMap::new();
    for r in table().iter().filter(|r| r.variant.pipeline == "brute") {
        brute.insert(
            (
                r.case.clone(),
                r.variant.test.clone(),
                r.variant.offset.clone(),
            ),
            r,
        );
    }
    let mut compared = 0;
    for r in table().iter().filter(|r| r.variant.pipeline != "brute") {
        let b = brute[&(
            r.case.clone(),
            r.variant.test.clone(),
            r.variant.offset.clone(),
        )];
        let (x, y) = (&r.outcome, &b.outcome);
        // The one known difference (see `crsh_cpu::intersect::bvh`'s module doc): the BVH
        // culls by geometry, so a spurious self-hit whose computed `t` puts it outside its
        // triangle's box (rounding noise of a ray leaving the surface with a tiny `t_min`, or
        // the projected test's cancelling `t` far from the origin) can be culled: bvh may report
        // fewer self-intersections than brute force, and must agree on everything else.
        // kdtree likewise, for another reason: an any-hit (shadow) ray's triangle is
        // unspecified; the kd-tree visits leaves front to back and stops at the first hit, so
        // a shadow ray from the light can report a real occluder where brute force reports the
        // receiving triangle itself, grazed near `t_max` (stadium/teapot, `fixed`: 0 against 1).
        // `dual_inline`, `dual_screen` and `dual_screen_bvh` too: their traversal tests pairs
        // as it finds them, nearer object nodes first, and a shadow ray stops at the first hit
        // (the same case, 0 against 1). Which of a shadow ray's hits comes first depends on the
        // order the traversal meets the triangles in, so these may also report the receiving
        // triangle where brute force met a real occluder first (`dual_screen`, projected,
        // fixed: 2 against 1); a hit stays a hit, so every other count is equal. Only the BVH's
        // culling is one-sided.
        let any_hit_order = ["kdtree", "dual_inline", "dual_screen", "dual_screen_bvh"];
        let pipeline = r.variant.pipeline.as_str();
        if (pipeline == "bvh" || any_hit_order.contains(&pipeline))
            && x.self_intersections != y.self_intersections
        {
            eprintln!(
                "known: {}: {} self-intersections, brute force {}",
                label(r),
                x.self_intersections,
                y.self_intersections
            );
            if pipeline == "bvh" {
                assert!(x.self_intersections < y.self_intersections, "{}", label(r));
            }
            assert_eq!(
                (
                    x.rays,
                    x.false_misses,
                    x.false_hits,
                    x.wrong_nearest,
                    x.escapes
                ),
                (
                    y.rays,
                    y.false_misses,
                    y.false_hits,
                    y.wrong_nearest,
                    y.escapes
                ),
                "{} differs from brute",
                label(r)
            );
            compared += 1;
            continue;
        }
        assert_eq!(
            (
                x.rays,
                x.false_misses,
                x.false_hits,
                x.wrong_nearest,
                x.self_intersections,
                x.escapes
            ),
            (
                y.rays,
                y.false_misses,
                y.false_hits,
                y.wrong_nearest,
                y.self_intersections,
                y.escapes
            ),
            "{} differs from brute",
            label(r)
        );
        compared += 1;
    }
    assert!(compared >= 3 * brute.len());
}

#[test]
fn invalid_rays_and_misses_never_hit() {
    for r in table().iter().filter(|r| r.family == "invalid") {
        let o = &r.outcome;
        assert_eq!(o.failures(), 0, "{}: {o:?}", label(r));
    }
    // The valid cases of the family really ran.
    for name in ["invalid/one-triangle", "invalid/all-miss"] {
        assert!(table()
            .iter()
            .any(|r| r.case == name && r.outcome.rays > 0 && r.outcome.error.is_none()));
    }
}

#[test]
fn degenerate_triangles_are_never_hit() {
    for r in table().iter().filter(|r| r.case == "degenerate/zero-area") {
        let o = &r.outcome;
        assert!(o.error.is_none() && o.rays > 800);
        assert_eq!(
            (o.false_misses, o.wrong_nearest, o.false_hits),
            (0, 0, 0),
            "{}",
            label(r)
        );
    }
}

#[test]
fn default_offset_has_no_acne_on_a_plane_lit_at_1_to_89_degrees() {
    // The default policy (origin moved by 1e-5 of the scene diagonal along the geometric
    // normal, and t_min) keeps a tilted plane acne-free at 1°-89° with the light near the
    // scene, at scales 1e-4..1e4 and moved by up to 1e3. It does not when the plane is moved
    // by 1e5 or 1e7 (the offset falls below the coordinates' ulp) or when the light is 1000
    // plane sizes away (long shadow rays): those rows are reported, and are what the other
    // offset policies are for.
    let default_offset = offset_policies(&Registry::<Cpu>::builtin())
        .first()
        .cloned();
    let rows: Vec<_> = table()
        .iter()
        .filter(|r| {
            (r.case.starts_with("acne/plane-")
                || r.case.starts_with("scale/plane-")
                || r.case == "far/plane-1e3")
                && r.variant.offset == default_offset
        })
        .collect();
    assert!(
        rows.len()
            >= 8 * suite_presets(&Registry::<Cpu>::builtin()).len()
                * intersect_tests(&Registry::<Cpu>::builtin()).len().max(1)
    );
    for r in rows {
        let o = &r.outcome;
        assert!(o.rays > 1000, "{}: {o:?}", label(r));
        assert_eq!(o.self_intersections, 0, "{}", label(r));
    }
    // And the far-away plane does show acne, so the case can catch a policy that fails.
    assert!(table().iter().any(|r| r.case == "far/plane-1e7"
        && r.variant.offset == default_offset
        && r.outcome.self_intersections > 0));
}

#[test]
fn frames_with_a_reference_agree_under_the_default_offset() {
    // Curved mirror and stadium: the pipelines' hits match the f64 reference on the same rays
    // except for a handful of near-ties (at most 0.5% of the rays).
    for r in table()
        .iter()
        .filter(|r| matches!(r.family.as_str(), "bundles" | "stadium"))
    {
        let o = &r.outcome;
        assert!(o.error.is_none() && o.rays > 0, "{}", label(r));
        assert!(o.rate(o.failures()) <= 0.005, "{}: {o:?}", label(r));
    }
}

#[test]
fn watertight_test_closes_every_mesh() {
    // Checks only once the catalogue offers `intersect.test=watertight` (another branch).
    if !intersect_tests(&Registry::<Cpu>::builtin())
        .iter()
        .any(|t| t == "watertight")
    {
        eprintln!("SKIP: this build has no intersect.test=watertight");
        return;
    }
    for r in table().iter().filter(|r| {
        r.variant.test.as_deref() == Some("watertight")
            && (r.family == "closed"
                || r.case == "edges/fan"
                || r.case.starts_with("degenerate/s")
                || r.case == "degenerate/needles")
    }) {
        assert_eq!(r.outcome.escapes, 0, "{}", label(r));
    }
}

#[test]
fn wachter_offset_has_no_self_intersections_at_any_translation() {
    // Checks only once the catalogue offers `raygen.offset=wachter` (another branch).
    if !offset_policies(&Registry::<Cpu>::builtin())
        .iter()
        .any(|t| t == "wachter")
    {
        eprintln!("SKIP: this build has no raygen.offset=wachter");
        return;
    }
    for r in table().iter().filter(|r| {
        r.variant.offset.as_deref() == Some("wachter")
            && matches!(r.family.as_str(), "far" | "scale" | "acne")
    }) {
        assert_eq!(r.outcome.self_intersections, 0, "{}", label(r));
    }
}

#[test]
fn the_expectations_hold_for_the_f64_reference() {
    // The cases' own answers are right: the f64 reference intersector meets every `Nearest`
    // and `Miss` expectation, and lets at most 1% of the `MustHit` rays escape (the f64
    // Möller-Trumbore test is not watertight either: measured, 3 of the 2936 rays aimed at the
    // icosphere's vertices and edges, none elsewhere), so what the table counts against the f32
    // pipelines is theirs, not the case's. Needles and grazing rays the f32 test drops are hit.
    use crsh_core::{FrameSize, Hit, Query, StageContext, Stats};
    use crsh_scene::stress::{Expect, Probe};
    let registry = Registry::<Cpu>::builtin();
    for case in cases() {
        let (Ok(scene), Probe::Rays { kind, rays, expect }) = (&case.scene, &case.probe) else {
            continue;
        };
        if expect.contains(&Expect::Invalid) {
            continue;
        }
        let ctx = StageContext::new(&Cpu, scene, FrameSize::new(64, 64).unwrap());
        let reference = registry
            .build_intersector(&ctx, &crsh_core::StageSpec::new("brute64"))
            .expect("brute64");
        let mut hits = vec![Hit::MISS; rays.len()];
        reference
            .intersect(
                &Cpu,
                rays,
                Query::Scene,
                kind.hit_mode(),
                &mut hits,
                &mut Stats::default(),
            )
            .unwrap();
        let (mut escapes, mut must) = (0, 0);
        for (i, (h, e)) in hits.iter().zip(expect).enumerate() {
            match *e {
                Expect::MustHit => {
                    must += 1;
                    escapes += usize::from(!h.is_hit());
                }
                Expect::Miss => assert!(!h.is_hit(), "{} ray {i}: {h:?}", case.name),
                Expect::Nearest { tri, t } => {
                    assert!(h.is_hit(), "{} ray {i} missed", case.name);
                    assert!(
                        h.tri == tri || (h.t - t).abs() <= 1e-6 * t.abs(),
                        "{} ray {i}: {h:?}",
                        case.name
                    );
                }
                Expect::Reference | Expect::Invalid => {}
            }
        }
        eprintln!("{}: brute64 escapes {escapes} of {must}", case.name);
        assert!(
            escapes * 100 <= must,
            "{}: brute64 lets {escapes} of {must} escape",
            case.name
        );
    }
}
