//! The whole pipeline on the wgpu backend against the CPU: for every preset the GPU runs
//! ([`GPU_PRESETS`]) on the built-in scenes and the shared Cornell boxes, the GPU frame traces the same rays
//! as the CPU frame, agrees with the CPU's exact answer on them (hit agreement ≥ 0.9999, the
//! reference running on the host), and its image matches the CPU image (PSNR ≥ 45 dB); stage
//! times come with device timestamps; the output is the same run after run.
//!
//! Without an adapter every test prints `SKIP:` and passes, unless `CRSH_REQUIRE_GPU=1`.

use std::path::Path;
use std::sync::Arc;

use crsh::{BackendKind, Registries, RenderRequest, Renderer};
use crsh_core::metrics::{psnr_rgba8, to_rgba8};
use crsh_core::{PipelineConfig, Stats, STAGE_TIMINGS};
use crsh_scene::Scene;
use crsh_wgpu::Wgpu;

/// The presets whose every stage has a WGSL implementation: all of them.
const GPU_PRESETS: [&str; 8] = [
    "brute",
    "bvh",
    "crsh",
    "rah",
    "grid",
    "tile_cone",
    "kdtree",
    "dual",
];

const W: u32 = 48;
const H: u32 = 36;

fn opts(max_depth: u32) -> RenderRequest {
    RenderRequest::new()
        .with_width(W)
        .with_height(H)
        .with_max_depth(max_depth)
}

fn registries() -> &'static Registries {
    static R: std::sync::OnceLock<Registries> = std::sync::OnceLock::new();
    R.get_or_init(Registries::builtin)
}

fn config(name: &str, sets: &[&str]) -> PipelineConfig {
    let mut cfg = registries().preset(name).expect("preset exists");
    for s in sets {
        cfg.set(s).unwrap();
    }
    cfg
}

fn builtin(name: &str) -> Arc<Scene> {
    Arc::new(crsh_scene::builtin::build(name).unwrap())
}

fn load(path: &Path) -> Arc<Scene> {
    Arc::new(crsh_scene::load_path(path).unwrap_or_else(|e| panic!("{e}")))
}

/// A GPU frame (with the CPU `reference` on the host) and its image on the host.
fn gpu_frame(
    b: &Wgpu,
    scene: &Arc<Scene>,
    cfg: &PipelineConfig,
    o: &RenderRequest,
    reference: &str,
) -> (Vec<[f32; 4]>, Stats) {
    let renderer = Renderer::on_wgpu(registries(), Arc::clone(scene), b).unwrap();
    let r = renderer
        .render(cfg, &o.clone().with_reference(reference), &mut |_| {})
        .unwrap_or_else(|e| panic!("{} with {} on wgpu: {e}", scene.name, cfg.name));
    assert_eq!(r.backend, BackendKind::Wgpu);
    // The device's primaries are the CPU rasterizer's but where a pixel centre lies within
    // rounding of an edge.
    let acc = r.accuracy.expect("a reference was given");
    let primary = acc.primary_agreement.expect("primaries compared");
    assert!(
        primary >= 0.999 && acc.primary_pixels == u64::from(o.width * o.height.unwrap_or(0)),
        "{} with {}: primary agreement {primary} over {} pixels",
        scene.name,
        cfg.name,
        acc.primary_pixels
    );
    (r.image, r.stats)
}

fn cpu_frame(
    scene: &Arc<Scene>,
    cfg: &PipelineConfig,
    o: &RenderRequest,
) -> (Vec<[f32; 4]>, Stats) {
    let r = Renderer::new(registries(), Arc::clone(scene))
        .render(cfg, o, &mut |_| {})
        .unwrap_or_else(|e| panic!("{} with {} on cpu: {e}", scene.name, cfg.name));
    (r.image, r.stats)
}

/// Stage variants checked beyond the presets: (preset, settings). The last is the CPU-only
/// `dual_screen` preset's keys (4-pixel tiles in Z-order) under the `dual` preset, which runs
/// on both backends.
const GPU_VARIANTS: [(&str, &[&str]); 4] = [
    ("crsh", &["traverse.kind=dual"]),
    ("crsh", &["traverse.kind=dual", "traverse.objects=grid"]),
    ("crsh", &["traverse.kind=dual", "traverse.objects=meshes"]),
    (
        "dual",
        &["hash.kind=tile", "hash.tile_size=4", "hash.order=morton"],
    ),
];

/// Every preset on `scene`, and the variants of [`GPU_VARIANTS`]: GPU vs CPU rays, agreement
/// and image.
fn check_presets_agree(b: &Wgpu, scene: &Arc<Scene>, depth: u32) {
    let o = opts(depth);
    let presets = GPU_PRESETS.iter().map(|&p| (p, &[][..]));
    for (name, sets) in presets.chain(GPU_VARIANTS) {
        let cfg = config(name, sets);
        let name = format!("{name} {sets:?}");
        let (gpu_image, gpu) = gpu_frame(b, scene, &cfg, &o, "brute");
        let (cpu_image, cpu) = cpu_frame(scene, &cfg, &o);
        let acc = gpu.accuracy.clone().expect("reference given");
        assert!(acc.rays > 0, "{} {name}: nothing compared", scene.name);
        assert!(
            acc.hit_agreement() >= 0.9999,
            "{} {name}: GPU hits vs the CPU brute force: {acc:?}",
            scene.name
        );
        // The rays spawned differ only where a primary or secondary hit differs.
        for kind in crsh_core::RayKind::ALL {
            let (g, c) = (gpu.rays.get(kind) as f64, cpu.rays.get(kind) as f64);
            assert!(
                (g - c).abs() <= 0.002 * c.max(1.0) + 2.0,
                "{} {name}: {kind:?} rays gpu {g} cpu {c}",
                scene.name
            );
        }
        let psnr = psnr_rgba8(&to_rgba8(&gpu_image), &to_rgba8(&cpu_image));
        assert!(
            psnr >= 45.0,
            "{} {name}: GPU image vs CPU image PSNR {psnr:.2} dB",
            scene.name
        );
        for key in gpu.device_timings_ms.keys() {
            assert!(
                STAGE_TIMINGS.contains(&key.as_str()),
                "unknown device key {key}"
            );
        }
    }
}

#[test]
fn every_preset_agrees_with_the_cpu_on_the_builtin_scenes() {
    let Some(b) = crsh_wgpu::testing::shared_backend(
        "every_preset_agrees_with_the_cpu_on_the_builtin_scenes",
    ) else {
        return;
    };
    for name in ["cornell-mirrors", "office-boxes"] {
        check_presets_agree(&b, &builtin(name), 2);
    }
}

#[test]
fn every_preset_agrees_with_the_cpu_on_the_shared_cornell_boxes() {
    let Some(b) = crsh_wgpu::testing::shared_backend(
        "every_preset_agrees_with_the_cpu_on_the_shared_cornell_boxes",
    ) else {
        return;
    };
    let manifests = crsh_tests::shared_scenes_in("cornell", "toml");
    if manifests.is_empty() {
        println!("SKIP: no shared Cornell manifests (set CRSH_SCENES)");
        return;
    }
    for path in manifests {
        check_presets_agree(&b, &load(&path), 1);
    }
}

/// Every preset runs on the GPU; a variant without a WGSL implementation (the f64 reference,
/// ray-cast primaries, the watertight test, inline final tests) is refused with a message naming the stage, before any
/// device work.
#[test]
fn variants_the_gpu_lacks_are_clear_errors() {
    for name in registries().preset_names() {
        if registries().wgpu.preset(&name).is_none() {
            // A CPU-only preset (`grid` until its WGSL twin lands) is refused naming the CPU.
            let e = registries()
                .resolve(&config(&name, &[]), BackendKind::Wgpu)
                .unwrap_err();
            assert!(e.to_string().contains("--backend cpu"), "{name}: {e}");
            continue;
        }
        assert!(
            GPU_PRESETS.contains(&name.as_str()),
            "{name} is not checked on the GPU"
        );
        registries()
            .resolve(&config(&name, &[]), BackendKind::Wgpu)
            .unwrap();
    }
    for (preset, set) in [
        ("bvh", "intersect.kind=brute64"),
        ("crsh", "intersect.test=watertight"),
        ("bvh", "primary.kind=raycast"),
        ("dual", "traverse.final_tests=inline"),
    ] {
        let e = registries()
            .resolve(&config(preset, &[set]), BackendKind::Wgpu)
            .unwrap_err();
        assert!(
            matches!(e, crsh_core::CoreError::Unsupported { .. }),
            "{set}: {e}"
        );
        assert!(e.to_string().contains("wgpu backend"), "{set}: {e}");
    }
}

#[test]
fn gpu_frames_are_deterministic_and_timed() {
    let Some(b) = crsh_wgpu::testing::shared_backend("gpu_frames_are_deterministic_and_timed")
    else {
        return;
    };
    let scene = builtin("cornell-mirrors");
    let bits = |im: &[[f32; 4]]| im.iter().flatten().map(|v| v.to_bits()).collect::<Vec<_>>();
    // `dual` too: its rounds, sorts and merges, and its object-depth rows.
    for sets in [&[][..], &["traverse.kind=dual"][..]] {
        let cfg = config("crsh", sets);
        let (a, sa) = gpu_frame(&b, &scene, &cfg, &opts(2), "brute");
        let (c, sc) = gpu_frame(&b, &scene, &cfg, &opts(2), "brute");
        assert!(bits(&a) == bits(&c), "{sets:?}: two GPU frames differ");
        assert_eq!(sa.tests, sc.tests, "{sets:?}");
        assert_eq!(sa.rays, sc.rays, "{sets:?}");
        assert_eq!(sa.levels, sc.levels, "{sets:?}");
        assert_eq!(sa.object_levels, sc.object_levels, "{sets:?}");
        assert_eq!(sets.is_empty(), sa.object_levels.is_empty(), "{sets:?}");
    }
    let cfg = config("crsh", &[]);
    let (_, sa) = gpu_frame(&b, &scene, &cfg, &opts(2), "brute");
    let keys = [
        "primary",
        "ray_creation",
        "trimming",
        "hashing",
        "compression",
        "sorting",
        "decompression",
        "hierarchy_creation",
        "traversal",
        "final_tests",
        "shading",
    ];
    for key in keys {
        assert!(
            sa.timings_ms.contains_key(key),
            "no wall time for {key}: {:?}",
            sa.timings_ms
        );
    }
    if b.context().has_timestamp_query() {
        for key in keys {
            assert!(
                sa.device_timings_ms.contains_key(key),
                "no device time for {key}: {:?}",
                sa.device_timings_ms
            );
        }
    }
}

/// The frames of the built-in animated scene on the GPU: every pipeline's hits agree with the
/// CPU's brute force on every frame (the scene is uploaded and the pipeline rebuilt per frame;
/// `bvh` with `intersect.update = refit` refits the host tree and uploads it, `dual` with
/// `traverse.update = refit` its object hierarchy).
#[test]
fn gpu_frames_of_the_animated_scene_agree_with_brute_force_on_every_frame() {
    let Some(b) = crsh_wgpu::testing::shared_backend(
        "gpu_frames_of_the_animated_scene_agree_with_brute_force_on_every_frame",
    ) else {
        return;
    };
    let (anim, _) = crsh_scene::load_animated("cornell-mirrors-animated").unwrap();
    for (name, sets) in [
        ("brute", &[][..]),
        ("bvh", &[][..]),
        ("bvh", &["intersect.update=refit"][..]),
        ("bvh", &["intersect.kind=grid"][..]),
        ("crsh", &[][..]),
        ("crsh", &["traverse.kind=dual"][..]),
        ("crsh", &["traverse.kind=dual", "traverse.update=refit"][..]),
        ("rah", &[][..]),
    ] {
        let cfg = config(name, sets);
        let request = crsh::FramesRequest::new(opts(1).with_reference("brute"), 3);
        let mut images = Vec::new();
        crsh::render_frames(
            registries(),
            &anim,
            Some(&b),
            &cfg,
            &request,
            &mut |_, _| {},
            &mut |f| {
                let acc = f.render.accuracy.as_ref().expect("every frame checked");
                assert!(
                    acc.hit_agreement >= 0.9999,
                    "{name} {sets:?} frame {}: {acc:?}",
                    f.frame
                );
                assert_eq!(f.render.backend, BackendKind::Wgpu);
                assert!(f.update.upload_ms > 0.0);
                let intersect = f.update.stages.iter().find(|s| s.slot == "intersect");
                assert_eq!(
                    intersect.map(|s| s.refit),
                    Some(sets.contains(&"intersect.update=refit") && f.frame > 0),
                    "{name} {sets:?} frame {}",
                    f.frame
                );
                let traverse = f.update.stages.iter().find(|s| s.slot == "traverse");
                assert_eq!(
                    traverse.map(|s| s.refit),
                    traverse.map(|_| sets.contains(&"traverse.update=refit") && f.frame > 0),
                    "{name} {sets:?} frame {}",
                    f.frame
                );
                images.push(f.render.image);
                Ok(())
            },
        )
        .unwrap_or_else(|e| panic!("{name} {sets:?} on wgpu: {e}"));
        assert_eq!(images.len(), 3);
        assert_ne!(images[0], images[2], "{name}: nothing moved");
    }
}
