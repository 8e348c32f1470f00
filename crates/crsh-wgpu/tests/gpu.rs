//! Device tests: adapter discovery, the `Wgpu` backend's buffer operations, and the scan kernel
//! against its CPU twin.
//!
//! Without an adapter these tests print `SKIP: no wgpu adapter (...)` and pass, unless
//! `CRSH_REQUIRE_GPU=1` (CI), where a missing adapter fails them.

use std::sync::Arc;

use crsh_core::{Backend, Hit, NO_HIT};
use crsh_wgpu::kernels::scan::SCAN_BLOCK;
use crsh_wgpu::{
    enumerate_adapters, exclusive_scan, exclusive_scan_cpu, exclusive_scan_in_place, GpuBuffer,
    GpuContext, GpuError, ScanKernel, Wgpu,
};

/// The shared device for all tests of this binary, or `None` (after printing `SKIP:`) when
/// this machine has no adapter. Panics when `CRSH_REQUIRE_GPU=1` and there is none.
fn gpu(test: &str) -> Option<Arc<GpuContext>> {
    crsh_wgpu::testing::shared_context(test)
}

fn backend(test: &str) -> Option<Wgpu> {
    gpu(test).map(Wgpu::from_context)
}

/// A tiny deterministic generator (64-bit LCG, Knuth's MMIX constants; high 32 bits out).
struct Lcg(u64);

impl Lcg {
    fn next(&mut self) -> u32 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 32) as u32
    }
    fn vec(&mut self, n: usize) -> Vec<u32> {
        (0..n).map(|_| self.next()).collect()
    }
}

// ---------------------------------------------------------------- discovery

#[test]
fn discovery_lists_the_context_adapter() {
    let Some(ctx) = gpu("discovery_lists_the_context_adapter") else {
        return;
    };
    let adapters = enumerate_adapters();
    assert!(
        !adapters.is_empty(),
        "a device opened but no adapter is listed"
    );
    assert!(
        adapters.iter().any(|a| a == ctx.info()),
        "context adapter {:?} missing from {adapters:?}",
        ctx.info()
    );
    for a in &adapters {
        assert!(!a.name.is_empty());
        assert!(
            ["vulkan", "gl", "metal", "dx12", "webgpu", "noop"].contains(&a.backend.as_str()),
            "{a:?}"
        );
        let json = serde_json::to_value(a).expect("AdapterInfo serialises");
        for key in ["name", "backend", "device_type", "driver", "driver_info"] {
            assert!(json.get(key).is_some(), "{key} missing in {json}");
        }
    }
    println!("adapters: {adapters:#?}");
}

#[test]
fn discovery_lists_lavapipe_when_installed() {
    let icd_dirs = ["/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d"];
    let lavapipe_installed = icd_dirs.iter().any(|d| {
        std::fs::read_dir(d)
            .map(|entries| {
                entries
                    .flatten()
                    .any(|e| e.file_name().to_string_lossy().starts_with("lvp_icd"))
            })
            .unwrap_or(false)
    });
    let vulkan_allowed = crsh_wgpu::adapter::backends_from_env().contains(wgpu::Backends::VULKAN);
    if !lavapipe_installed || !vulkan_allowed {
        println!(
            "SKIP: lavapipe ICD installed: {lavapipe_installed}, Vulkan allowed by WGPU_BACKEND: \
             {vulkan_allowed}"
        );
        return;
    }
    let adapters = enumerate_adapters();
    assert!(
        adapters
            .iter()
            .any(|a| a.backend == "vulkan" && a.is_software() && a.name.contains("llvmpipe")),
        "lavapipe ICD is installed but not listed: {adapters:?}"
    );
}

#[test]
fn context_reports_limits_and_features() {
    let Some(ctx) = gpu("context_reports_limits_and_features") else {
        return;
    };
    let adapter_limits = ctx.adapter().limits();
    // The device got the adapter's own limits, not WebGPU's defaults.
    assert_eq!(
        ctx.max_storage_binding_bytes(),
        adapter_limits.max_storage_buffer_binding_size
    );
    assert_eq!(ctx.max_buffer_bytes(), adapter_limits.max_buffer_size);
    assert_eq!(
        ctx.max_workgroups_per_dimension(),
        adapter_limits.max_compute_workgroups_per_dimension
    );
    assert!(ctx.max_storage_binding_bytes() >= 128 << 20);
    let has = ctx
        .adapter()
        .features()
        .contains(wgpu::Features::TIMESTAMP_QUERY);
    assert_eq!(ctx.has_timestamp_query(), has);
    if has {
        assert!(ctx.timestamp_period_ns() > 0.0);
    }
}

// ---------------------------------------------------------------- backend buffers

#[test]
fn upload_download_round_trips() {
    let Some(b) = backend("upload_download_round_trips") else {
        return;
    };
    assert_eq!(b.name(), "wgpu");
    let data = Lcg(1).vec(1001);
    let buf = b.upload(&data).unwrap();
    assert_eq!(b.len(&buf), 1001);
    assert_eq!(b.download(&buf).unwrap(), data);

    let hits: Vec<Hit> = (0..37)
        .map(|i| Hit {
            t: i as f32 * 0.5,
            tri: if i % 3 == 0 { NO_HIT } else { i },
            u: 0.25,
            v: -1.0,
        })
        .collect();
    let buf = b.upload(&hits).unwrap();
    assert_eq!(b.download(&buf).unwrap(), hits);

    // Element sizes that are not multiples of 4 are padded on the device.
    let bytes: Vec<u8> = (0..13u8).collect();
    let buf = b.upload(&bytes).unwrap();
    assert_eq!(b.len(&buf), 13);
    assert_eq!(b.download(&buf).unwrap(), bytes);
    let triples: Vec<[u16; 3]> = (0..5u16).map(|i| [i, i + 1, u16::MAX - i]).collect();
    assert_eq!(b.download(&b.upload(&triples).unwrap()).unwrap(), triples);
    b.sync().unwrap();
}

#[test]
fn empty_buffers_work() {
    let Some(b) = backend("empty_buffers_work") else {
        return;
    };
    let empty = b.upload::<u32>(&[]).unwrap();
    assert_eq!(b.len(&empty), 0);
    assert!(empty.is_empty());
    // Still a valid, bindable allocation.
    assert!(empty.buffer().size() >= crsh_wgpu::backend::MIN_BUFFER_BYTES);
    assert_eq!(b.download(&empty).unwrap(), Vec::<u32>::new());
    let filled = b.filled(0, 7u32).unwrap();
    assert_eq!(b.len(&filled), 0);
    assert_eq!(b.download(&filled).unwrap(), Vec::<u32>::new());
    let none = b.concat::<Hit>(Vec::new()).unwrap();
    assert_eq!(b.len(&none), 0);
    let all_empty = b
        .concat(vec![
            b.upload::<Hit>(&[]).unwrap(),
            b.upload::<Hit>(&[]).unwrap(),
        ])
        .unwrap();
    assert_eq!(b.download(&all_empty).unwrap(), Vec::<Hit>::new());
}

#[test]
fn filled_replicates_value() {
    let Some(b) = backend("filled_replicates_value") else {
        return;
    };
    // Zero (device zero-init), one chunk, and several chunks with a partial last copy.
    for (len, value) in [(100usize, 0u32), (100, 0xdead_beef), (70_001, 0x0102_0304)] {
        let buf = b.filled(len, value).unwrap();
        assert_eq!(b.len(&buf), len);
        let got = b.download(&buf).unwrap();
        assert_eq!(got.len(), len);
        assert!(
            got.iter().all(|&v| v == value),
            "len {len} value {value:#x}"
        );
    }
    let miss = b.filled(5000, Hit::MISS).unwrap();
    assert_eq!(b.download(&miss).unwrap(), vec![Hit::MISS; 5000]);
    // Unaligned element size takes the host path.
    let odd = b.filled(70_001, [1u8, 2, 3]).unwrap();
    assert_eq!(b.download(&odd).unwrap(), vec![[1u8, 2, 3]; 70_001]);
}

#[test]
fn concat_keeps_order_and_skips_empty_parts() {
    let Some(b) = backend("concat_keeps_order_and_skips_empty_parts") else {
        return;
    };
    let mut rng = Lcg(7);
    let parts: Vec<Vec<u32>> = [0usize, 3, 0, 1024, 1, 0, 4097]
        .iter()
        .map(|&n| rng.vec(n))
        .collect();
    let bufs = parts.iter().map(|p| b.upload(p).unwrap()).collect();
    let joined = b.concat(bufs).unwrap();
    assert_eq!(b.download(&joined).unwrap(), parts.concat());

    let single = b.concat(vec![b.upload(&parts[3]).unwrap()]).unwrap();
    assert_eq!(b.download(&single).unwrap(), parts[3]);

    // Unaligned element size (host path).
    let a: Vec<u8> = vec![1, 2, 3];
    let c: Vec<u8> = vec![4, 5];
    let joined = b
        .concat(vec![b.upload(&a).unwrap(), b.upload(&c).unwrap()])
        .unwrap();
    assert_eq!(b.download(&joined).unwrap(), vec![1, 2, 3, 4, 5]);
}

#[test]
fn concurrent_round_trips_from_many_threads() {
    let Some(b) = backend("concurrent_round_trips_from_many_threads") else {
        return;
    };
    // Downloads on several threads poll the same device: each must still get its own data
    // (a map callback may be delivered by another thread's poll).
    std::thread::scope(|s| {
        for t in 0..8u64 {
            let b = b.clone();
            s.spawn(move || {
                let mut rng = Lcg(100 + t);
                for round in 0..25 {
                    let data = rng.vec(1 + (round * 97 + t as usize * 13) % 3000);
                    let buf = b.upload(&data).unwrap();
                    assert_eq!(b.download(&buf).unwrap(), data, "thread {t} round {round}");
                }
            });
        }
    });
}

#[test]
fn oversized_buffer_is_an_error_not_a_panic() {
    let Some(ctx) = gpu("oversized_buffer_is_an_error_not_a_panic") else {
        return;
    };
    let too_many = (ctx.max_buffer_bytes() / 4 + 1) as usize;
    match GpuBuffer::<u32>::zeroed(&ctx, "too big", too_many) {
        Err(GpuError::TooLarge { limit_name, .. }) => assert_eq!(limit_name, "max_buffer_size"),
        other => panic!("expected TooLarge, got {other:?}"),
    }
    let b = Wgpu::from_context(ctx);
    let err = b.filled(too_many, 1u32).unwrap_err();
    assert!(err.to_string().contains("max_buffer_size"), "{err}");
}

// ---------------------------------------------------------------- scan

fn check_scan(ctx: &GpuContext, input: &[u32], what: &str) {
    let buf = GpuBuffer::from_slice(ctx, "scan test input", input).unwrap();
    let (out, total) = exclusive_scan(ctx, &buf).unwrap();
    let (want, want_total) = exclusive_scan_cpu(input);
    assert_eq!(out.len(), input.len(), "{what}");
    let got = out.to_vec(ctx).unwrap();
    if let Some(i) = (0..input.len()).find(|&i| got[i] != want[i]) {
        panic!(
            "{what}: n = {} first mismatch at {i}: gpu {} cpu {}",
            input.len(),
            got[i],
            want[i]
        );
    }
    assert_eq!(total, want_total, "{what}: total, n = {}", input.len());
    // The input is left unchanged.
    assert_eq!(buf.to_vec(ctx).unwrap(), input, "{what}: input modified");
}

#[test]
fn scan_matches_cpu_twin_on_random_full_range_values() {
    let Some(ctx) = gpu("scan_matches_cpu_twin_on_random_full_range_values") else {
        return;
    };
    // Full-range values: the running sum wraps around 2^32 thousands of times.
    let mut rng = Lcg(0x5eed);
    for n in [
        0usize,
        1,
        255,
        256,
        257,
        1000,
        SCAN_BLOCK,
        SCAN_BLOCK + 1,
        65537,
        1 << 20,
        // Three scan levels: n -> 2049 block sums -> 2 -> 1.
        SCAN_BLOCK * SCAN_BLOCK + 1,
    ] {
        check_scan(&ctx, &rng.vec(n), "full-range");
    }
}

#[test]
fn scan_matches_cpu_twin_on_counts_and_extremes() {
    let Some(ctx) = gpu("scan_matches_cpu_twin_on_counts_and_extremes") else {
        return;
    };
    let mut rng = Lcg(42);
    // Small counts, as in stream compaction (no wrap).
    let counts: Vec<u32> = (0..65537).map(|_| rng.next() % 4).collect();
    check_scan(&ctx, &counts, "counts");
    // All u32::MAX: prefix[i] = -i mod 2^32.
    check_scan(&ctx, &vec![u32::MAX; 3000], "all max");
    check_scan(&ctx, &[u32::MAX], "single max");
    // Values straddling the wrap point.
    let straddle: Vec<u32> = (0..257).map(|i| u32::MAX - (i % 5)).collect();
    check_scan(&ctx, &straddle, "straddle");
    check_scan(&ctx, &vec![0; 1000], "zeros");
}

#[test]
fn scan_in_place_and_2d_dispatch() {
    let Some(ctx) = gpu("scan_in_place_and_2d_dispatch") else {
        return;
    };
    let mut rng = Lcg(99);
    let input = rng.vec(300_001);
    let (want, want_total) = exclusive_scan_cpu(&input);

    let buf = GpuBuffer::from_slice(&ctx, "in place", &input).unwrap();
    let total = exclusive_scan_in_place(&ctx, &buf).unwrap();
    assert_eq!(total, want_total);
    assert_eq!(buf.to_vec(&ctx).unwrap(), want);

    // Narrow rows force a 2D grid with idle workgroups in the last row (147 blocks of 2048 on
    // 5 columns = 30 rows, 3 idle; the second level is one block).
    let narrow = ScanKernel::new(&ctx).unwrap().with_max_groups_x(5);
    let buf = GpuBuffer::from_slice(&ctx, "2d", &input).unwrap();
    let (out, total) = narrow.scan(&ctx, &buf).unwrap();
    assert_eq!(total, want_total);
    assert_eq!(out.to_vec(&ctx).unwrap(), want);

    // One column: every level is a 1 x blocks grid.
    let column = ScanKernel::new(&ctx).unwrap().with_max_groups_x(1);
    let small = &input[..5000];
    let buf = GpuBuffer::from_slice(&ctx, "column", small).unwrap();
    let (out, total) = column.scan(&ctx, &buf).unwrap();
    let (want_small, want_small_total) = exclusive_scan_cpu(small);
    assert_eq!(total, want_small_total);
    assert_eq!(out.to_vec(&ctx).unwrap(), want_small);
}

#[test]
fn scan_rejects_inputs_beyond_the_storage_binding_limit() {
    let Some(ctx) = gpu("scan_rejects_inputs_beyond_the_storage_binding_limit") else {
        return;
    };
    let limit = ctx.max_storage_binding_bytes();
    if limit > 256 << 20 || limit + 4 > ctx.max_buffer_bytes() {
        println!("SKIP: binding limit {limit} B too large to allocate cheaply in a test");
        return;
    }
    let n = (limit / 4 + 1) as usize;
    let buf = GpuBuffer::<u32>::zeroed(&ctx, "over binding limit", n).unwrap();
    match exclusive_scan(&ctx, &buf) {
        Err(GpuError::TooLarge { limit_name, .. }) => {
            assert_eq!(limit_name, "max_storage_buffer_binding_size")
        }
        other => panic!("expected TooLarge, got {:?}", other.map(|(_, t)| t)),
    }
}

// ---------------------------------------------------------------- kernel plumbing, profiler

/// A kernel built on `common.wgsl`: moves every ray's origin along its direction by `t`, over a
/// buffer bound in chunks, inside an open stage; the device timings name that stage.
#[test]
fn common_records_chunked_dispatch_and_stage_timestamps() {
    use crsh_core::Ray;
    use crsh_wgpu::kernel::{chunks, encoder, submit, uniform, Kernel, Slot};
    let Some(b) = backend("common_records_chunked_dispatch_and_stage_timestamps") else {
        return;
    };
    let ctx = b.context();
    const SRC: &str = "
        struct P { n: u32, t: f32, _a: u32, _b: u32 }
        @group(0) @binding(0) var<uniform> p: P;
        @group(0) @binding(1) var<storage, read_write> rays: array<Ray>;
        @compute @workgroup_size(WG)
        fn advance(@builtin(global_invocation_id) gid: vec3<u32>,
                   @builtin(num_workgroups) nwg: vec3<u32>) {
            let i = linear_id(gid, nwg);
            if (i >= p.n) { return; }
            var r = rays[i];
            let o = ray_origin(r) + ray_dir(r) * p.t;
            r.ox = o.x; r.oy = o.y; r.oz = o.z;
            r.source = i;
            rays[i] = r;
        }";
    let kernel = Kernel::new(
        ctx,
        "test advance",
        SRC,
        &["advance"],
        &[Slot::Uniform, Slot::ReadWrite],
    )
    .expect("kernel compiles");
    let mut lcg = Lcg(7);
    let rays: Vec<Ray> = (0..1000)
        .map(|i| Ray {
            origin: glam::Vec3::new(i as f32, 1.0, 2.0),
            dir: glam::Vec3::new((lcg.next() % 7) as f32, 1.0, -1.0),
            t_max: f32::INFINITY,
            ..bytemuck::Zeroable::zeroed()
        })
        .collect();
    let buf = b.upload(&rays).unwrap();
    b.begin_stage("hashing");
    for range in chunks::<Ray>(ctx, buf.len()) {
        #[repr(C)]
        #[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
        struct P {
            n: u32,
            t: f32,
            a: u32,
            b: u32,
        }
        let params = uniform(
            ctx,
            "p",
            &P {
                n: range.len() as u32,
                t: 0.5,
                a: 0,
                b: 0,
            },
        );
        let bg = kernel.bind_group(
            ctx,
            &[params.as_entire_binding(), buf.slice_binding(range.clone())],
        );
        let mut enc = encoder(ctx, "advance");
        {
            let mut pass = ctx.compute_pass(&mut enc, "advance");
            kernel
                .dispatch(ctx, &mut pass, "advance", &bg, range.len() as u32)
                .unwrap();
        }
        submit(ctx, "advance", enc).unwrap();
    }
    b.sync().unwrap();
    let times = b.end_stage().unwrap();
    let got = b.download(&buf).unwrap();
    for (i, (g, r)) in got.iter().zip(&rays).enumerate() {
        assert_eq!(g.origin, r.origin + r.dir * 0.5, "ray {i}");
        assert_eq!(g.source, i as u32);
    }
    if ctx.has_timestamp_query() {
        assert!(!times.is_empty(), "timestamps granted but none read");
        assert!(
            times.iter().all(|(k, ms)| k == "hashing" && *ms >= 0.0),
            "{times:?}"
        );
    } else {
        assert!(times.is_empty());
    }
    // Passes outside any stage are not timed.
    assert!(b.end_stage().unwrap().is_empty());
}

// ---------------------------------------------------------------- host reference

/// The host-side reference gives, through device buffers, exactly the CPU intersector's hits,
/// merged into the hits already there; candidate queries are refused.
#[test]
fn host_intersector_matches_the_cpu_intersector() {
    use crsh_core::{HitMode, Intersector, Query, Ray, StageSpec, Stats};
    use crsh_wgpu::{GpuScene, HostIntersector};
    let Some(b) = backend("host_intersector_matches_the_cpu_intersector") else {
        return;
    };
    let scene = Arc::new(crsh_scene::builtin::build("cornell-mirrors").unwrap());
    let gscene = GpuScene::new(&b, &scene).unwrap();
    let centre = (scene.bounds.min + scene.bounds.max) * 0.5;
    let mut lcg = Lcg(11);
    let mut unit = || lcg.next() as f32 / u32::MAX as f32 * 2.0 - 1.0;
    let rays: Vec<Ray> = (0..500)
        .map(|i| Ray {
            origin: centre,
            dir: glam::Vec3::new(unit(), unit(), unit()),
            t_min: 0.0,
            t_max: if i % 3 == 0 { 0.5 } else { f32::INFINITY },
            source: i,
            ..bytemuck::Zeroable::zeroed()
        })
        .collect();
    // Half the rays start with a hit closer than anything in the scene: merging keeps it.
    let start: Vec<Hit> = (0..rays.len())
        .map(|i| {
            if i % 2 == 0 {
                Hit {
                    t: 1e-4,
                    tri: 0,
                    u: 0.0,
                    v: 0.0,
                }
            } else {
                Hit::MISS
            }
        })
        .collect();
    for mode in [HitMode::Closest, HitMode::Any] {
        let spec = StageSpec::new("brute");
        let cpu = crsh_wgpu::testing::cpu_intersector(&spec, &scene);
        let mut want = start.clone();
        cpu.intersect(
            &crsh_cpu::Cpu,
            &rays,
            Query::Scene,
            mode,
            &mut want,
            &mut Stats::default(),
        )
        .unwrap();
        let host = HostIntersector::new(crsh_wgpu::testing::cpu_intersector(&spec, &gscene.scene));
        assert!(!host.supports_candidates());
        let gpu_rays = b.upload(&rays).unwrap();
        let mut hits = b.upload(&start).unwrap();
        let mut stats = Stats::default();
        host.intersect(&b, &gpu_rays, Query::Scene, mode, &mut hits, &mut stats)
            .unwrap();
        assert_eq!(b.download(&hits).unwrap(), want, "{mode:?}");
        assert!(stats.tests.ray_triangle > 0);
        assert!(want.iter().skip(1).step_by(2).any(|h| h.is_hit()));
    }
}
