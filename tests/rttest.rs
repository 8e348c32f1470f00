//! Seed 003's kd-tree traversals through the frame driver: camera rays cast by the pipeline's
//! own intersector (`primary.accel = pipeline`) and point-light shadow rays, traced by every
//! `intersect.traversal` of the `kdtree` preset, give brute force's hits and image bit for
//! bit, and report the paper's packet counters (`N`, `I`) per ray kind.

use std::sync::Arc;

use crsh_core::{
    Frame, FrameOptions, FrameSize, PipelineConfig, Registry, StageContext, StageSpec,
};
use crsh_cpu::Cpu;
use crsh_scene::Scene;

const W: u32 = 48;
const H: u32 = 36;

fn registry() -> &'static Registry<Cpu> {
    static REGISTRY: std::sync::OnceLock<Registry<Cpu>> = std::sync::OnceLock::new();
    REGISTRY.get_or_init(Registry::<Cpu>::builtin)
}

fn render(scene: &Arc<Scene>, cfg: &PipelineConfig) -> Frame<Cpu> {
    let ctx = StageContext::new(&Cpu, scene, FrameSize::new(W, H).unwrap());
    let fo = FrameOptions::default().with_max_depth(1);
    registry()
        .render(&ctx, cfg, &fo, Some(&StageSpec::new("brute")), &mut |_| {})
        .unwrap_or_else(|e| panic!("{} with {}: {e}", scene.name, cfg.name))
}

fn cast_by(preset: &str, sets: &[&str]) -> PipelineConfig {
    let mut cfg = registry().preset(preset).unwrap();
    cfg.set("primary.kind=raycast").unwrap();
    cfg.set("primary.accel=pipeline").unwrap();
    for s in sets {
        cfg.set(s).unwrap();
    }
    cfg
}

fn bits(image: &[[f32; 4]]) -> Vec<u32> {
    image.iter().flatten().map(|c| c.to_bits()).collect()
}

#[test]
fn every_traversal_renders_brute_forces_image_and_counts_packets() {
    for name in ["office-boxes", "cornell-mirrors"] {
        let scene = Arc::new(crsh_scene::builtin::build(name).unwrap());
        let want = render(&scene, &cast_by("brute", &[]));
        let mut n = std::collections::BTreeMap::new();
        for traversal in ["single", "packet", "omni", "frustum", "mft", "cone"] {
            let cfg = cast_by("kdtree", &[&format!("intersect.traversal={traversal}")]);
            let got = render(&scene, &cfg);
            let acc = got.stats.accuracy.as_ref().unwrap();
            assert_eq!(acc.hit_agreement(), 1.0, "{name} {traversal}: {acc:?}");
            assert_eq!(bits(&got.image), bits(&want.image), "{name} {traversal}");
            // Camera rays and shadow rays both report the paper's counters.
            let p = &got.stats.packets;
            let primary = p.get("primary").expect("primary packets");
            assert!(p.contains_key("shadow"), "{name} {traversal}: {p:?}");
            let expect_packets = if traversal == "single" {
                u64::from(W * H)
            } else {
                u64::from(W * H / 4)
            };
            assert_eq!(primary.packets, expect_packets, "{name} {traversal}");
            assert!(primary.nodes > 0 && primary.packet_tests > 0);
            n.insert(traversal, primary.nodes_per_packet());
        }
        // Packets share the nodes of their rays; MFT's quadrant masks never add nodes to
        // the single frustum's for closest-hit camera rays (at this size tiles are wide,
        // so frusta visit more nodes per packet than 2×2 packets do: no claim on those).
        assert!(n["packet"] < 4.0 * n["single"], "{name}: {n:?}");
        assert!(n["mft"] <= n["frustum"], "{name}: {n:?}");
    }
}

#[test]
fn bad_traversal_values_are_refused() {
    let scene = Arc::new(crsh_scene::builtin::build("cornell-mirrors").unwrap());
    let ctx = StageContext::new(&Cpu, &scene, FrameSize::new(W, H).unwrap());
    for (set, key) in [
        ("intersect.traversal=octree", "intersect.traversal"),
        ("intersect.tile_size=7", "tile_size"),
        ("intersect.tile_size=1000", "tile_size"),
    ] {
        let mut cfg = registry().preset("kdtree").unwrap();
        cfg.set(set).unwrap();
        let err = registry()
            .render(&ctx, &cfg, &FrameOptions::default(), None, &mut |_| {})
            .err()
            .unwrap_or_else(|| panic!("{set} is accepted"));
        assert!(err.to_string().contains(key), "{set}: {err}");
    }
}

#[test]
fn coherent_kinds_picks_the_rays_that_travel_together() {
    let scene = Arc::new(crsh_scene::builtin::build("office-boxes").unwrap());
    let want = render(&scene, &cast_by("brute", &[]));
    for (kinds, grouped, alone) in [
        ("primary", "primary", "shadow"),
        ("shadow", "shadow", "primary"),
    ] {
        let cfg = cast_by(
            "kdtree",
            &[
                "intersect.traversal=mft",
                &format!("intersect.coherent_kinds={kinds}"),
            ],
        );
        let got = render(&scene, &cfg);
        assert_eq!(bits(&got.image), bits(&want.image), "{kinds}");
        let p = &got.stats.packets;
        assert!(
            p[grouped].groups > 0 && p[grouped].single_rays == 0,
            "{kinds}: {p:?}"
        );
        assert_eq!(p[alone].groups, 0, "{kinds}: {p:?}");
        assert_eq!(p[alone].single_rays, p[alone].packets, "{kinds}: {p:?}");
    }
}
