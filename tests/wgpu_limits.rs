//! Every wgpu kernel within WebGPU's default limits: the stages of every preset, and the
//! stage variants beyond them, run on a device opened with `wgpu::Limits::default()`
//! ([`DeviceLimits::WebGpu`]: 8 storage buffers per shader stage, 128 MiB bindings, 256
//! invocations per workgroup) and give the frames the adapter's own limits give, bit for bit;
//! the run compiles every kernel the backend has.
//!
//! Without an adapter every test prints `SKIP:` and passes, unless `CRSH_REQUIRE_GPU=1`.

use std::collections::BTreeSet;
use std::path::Path;
use std::sync::Arc;

use crsh::{Registries, RenderRequest, Renderer};
use crsh_core::PipelineConfig;
use crsh_core::Stats;
use crsh_scene::Scene;
use crsh_wgpu::{DeviceLimits, GpuContext, Wgpu};

/// Presets and settings that together run every kernel of the backend.
const CELLS: &[(&str, &[&str])] = &[
    ("brute", &[]),
    ("bvh", &[]),
    ("grid", &["raygen.offsets=polygon"]),
    ("kdtree", &[]),
    ("crsh", &[]),
    ("crsh", &["hash.kind=morton"]),
    ("rah", &[]),
    ("tile_cone", &[]),
    ("dual", &[]),
    ("dual", &["traverse.objects=grid"]),
    ("dual", &["traverse.objects=meshes"]),
    (
        "dual",
        &["hash.kind=tile", "hash.tile_size=4", "hash.order=morton"],
    ),
    (
        "bvh",
        &[
            "raygen.kind=ao",
            "shade.kind=ao",
            "raygen.samples=2",
            "raygen.offsets=center",
        ],
    ),
    (
        "rah",
        &[
            "raygen.kind=diffuse",
            "shade.kind=diffuse",
            "raygen.samples=2",
        ],
    ),
];

fn registries() -> &'static Registries {
    static R: std::sync::OnceLock<Registries> = std::sync::OnceLock::new();
    R.get_or_init(Registries::builtin)
}

fn config(name: &str, sets: &[&str]) -> PipelineConfig {
    let mut cfg = registries().preset(name).expect("preset exists");
    for s in sets {
        cfg.set(s).unwrap_or_else(|e| panic!("{name} {s}: {e}"));
    }
    cfg
}

fn frame(b: &Wgpu, scene: &Arc<Scene>, cfg: &PipelineConfig) -> (Vec<u32>, Stats) {
    let renderer = Renderer::on_wgpu(registries(), Arc::clone(scene), b).unwrap();
    let request = RenderRequest::new()
        .with_width(40)
        .with_height(30)
        .with_max_depth(2);
    let r = renderer
        .render(cfg, &request, &mut |_| {})
        .unwrap_or_else(|e| {
            panic!(
                "{} on {} ({} limits): {e}",
                cfg.name,
                scene.name,
                b.context().device_limits().name()
            )
        });
    let bits = r.image.iter().flatten().map(|c| c.to_bits()).collect();
    (bits, r.stats)
}

/// The kernel types the backend compiles through `GpuContext::kernel`, read from its source
/// (`kernel(NAME::new)`), so that a kernel added later without a cell here fails the test.
fn kernels_in_source() -> BTreeSet<String> {
    fn walk(dir: &Path, out: &mut BTreeSet<String>) {
        for e in std::fs::read_dir(dir).expect("crsh-wgpu sources") {
            let p = e.expect("dir entry").path();
            if p.is_dir() {
                walk(&p, out);
            } else if p.extension().is_some_and(|x| x == "rs") {
                let text = std::fs::read_to_string(&p).expect("source");
                for (i, _) in text.match_indices("kernel(") {
                    let rest = &text[i + "kernel(".len()..];
                    let Some(end) = rest.find("::new)") else {
                        continue;
                    };
                    let name = rest[..end].rsplit("::").next().unwrap_or("");
                    if !name.is_empty() && name.chars().all(|c| c.is_alphanumeric() || c == '_') {
                        out.insert(name.to_string());
                    }
                }
            }
        }
    }
    let mut out = BTreeSet::new();
    walk(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("crates/crsh-wgpu/src"),
        &mut out,
    );
    out
}

#[test]
fn every_kernel_runs_within_the_webgpu_default_limits() {
    let Some(adapter) =
        crsh_wgpu::testing::shared_backend("every_kernel_runs_within_the_webgpu_default_limits")
    else {
        return;
    };
    let ctx = Arc::new(GpuContext::with_limits(DeviceLimits::WebGpu).expect("a WebGPU device"));
    let limits = ctx.limits();
    let default = wgpu::Limits::default();
    assert_eq!(ctx.device_limits(), DeviceLimits::WebGpu);
    assert!(
        limits.max_storage_buffers_per_shader_stage <= default.max_storage_buffers_per_shader_stage
            && limits.max_storage_buffer_binding_size <= default.max_storage_buffer_binding_size
            && limits.max_compute_invocations_per_workgroup
                <= default.max_compute_invocations_per_workgroup
            && limits.max_compute_workgroup_storage_size
                <= default.max_compute_workgroup_storage_size,
        "WebGPU device limits above the defaults: {limits:?}"
    );
    let webgpu = Wgpu::from_context(Arc::clone(&ctx));
    let scene = Arc::new(crsh_scene::builtin::build("office-boxes").unwrap());
    for (name, sets) in CELLS {
        let cfg = config(name, sets);
        let (want, want_stats) = frame(&adapter, &scene, &cfg);
        let (got, got_stats) = frame(&webgpu, &scene, &cfg);
        assert_eq!(
            got_stats.rays, want_stats.rays,
            "{name} {sets:?}: rays under the WebGPU limits"
        );
        assert!(
            got == want,
            "{name} {sets:?}: the image under the WebGPU limits differs from the adapter's"
        );
    }
    let key = crsh_core::rng::RngKey {
        pixel: 0,
        sample: 0,
        bounce: 0,
        seed: 0,
    };
    let probe = crsh_wgpu::kernels::rng::RngQuery::new(
        key,
        crsh_core::glam::Vec3::Z,
        crsh_core::glam::Vec3::Z,
    );
    crsh_wgpu::kernels::rng::rng_on_device(&ctx, &[probe]).expect("the rng probe");
    let compiled = ctx.compiled_kernels();
    let kernels = kernels_in_source();
    assert!(
        kernels.len() >= 15,
        "kernels found in the source: {kernels:?}"
    );
    for kernel in kernels {
        assert!(
            compiled
                .iter()
                .any(|c| c.rsplit("::").next() == Some(kernel.as_str())),
            "kernel `{kernel}` never ran under the WebGPU limits (compiled: {compiled:?}); add a \
             cell that runs it"
        );
    }
}

/// A kernel whose entry point needs more storage buffers than the device grants is refused
/// with an error that names the limit, before any pipeline is made.
#[test]
fn a_kernel_above_the_limits_is_refused_naming_the_limit() {
    use crsh_wgpu::kernel::{check_binding_limits, entry_bindings, Slot};
    let src = "@group(0) @binding(0) var<storage, read> a: array<u32>;\n\
               @group(0) @binding(1) var<storage, read> b: array<u32>;\n\
               @group(0) @binding(2) var<storage, read_write> c: array<u32>;\n\
               @compute @workgroup_size(1) fn both() { c[0] = a[0] + b[0]; }\n\
               @compute @workgroup_size(1) fn one() { c[0] = a[0]; }";
    let slots = [Slot::Read, Slot::Read, Slot::ReadWrite];
    let used = entry_bindings("test", src, &["both", "one"], slots.len()).unwrap();
    assert_eq!(used, vec![vec![0, 1, 2], vec![0, 2]]);
    let limits = wgpu::Limits {
        max_storage_buffers_per_shader_stage: 2,
        ..wgpu::Limits::default()
    };
    check_binding_limits("one", &slots, &used[1], &limits).unwrap();
    let e = check_binding_limits("kernel `test` entry `both`", &slots, &used[0], &limits)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("max_storage_buffers_per_shader_stage")
            && e.contains("needs 3")
            && e.contains("entry `both`"),
        "{e}"
    );
    assert!(entry_bindings("test", src, &["missing"], 3).is_err());
}
