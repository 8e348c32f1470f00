// `ao` shading on the device: the twin of crsh_cpu::shade::ao (see ao.rs). Prepended:
// common.wgsl. Writes one contribution per record, records being the surfaces followed by the
// AO rays, for kernels/accumulate.

const KIND_AO: u32 = 4u;

struct Params {
    n_surfaces: u32,
    n_rays: u32,
    n_pixels: u32,
    background: f32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> surfaces: array<Surface>;
@group(0) @binding(2) var<storage, read> rays: array<Ray>;
@group(0) @binding(3) var<storage, read> hits: array<Hit>;
@group(0) @binding(4) var<storage, read_write> contrib: array<Contribution>;
// [0] bad surface (0xffffffff - index), [1] rounds of the accumulation, [2] bad ray.
@group(0) @binding(5) var<storage, read_write> report: array<atomic<u32>>;

@compute @workgroup_size(WG)
fn contribution(@builtin(global_invocation_id) gid: vec3<u32>,
                @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= p.n_surfaces + p.n_rays) {
        return;
    }
    if (i < p.n_surfaces) {
        // A surface: the background where it is a miss; alpha 1 either way.
        let s = surfaces[i];
        if (s.pixel >= p.n_pixels) {
            atomicMax(&report[0], 0xffffffffu - i);
            contrib[i].pixel = NO_HIT;
            return;
        }
        let c = s.throughput * p.background;
        let flags = select(ACC_ALPHA, ACC_ALPHA | ACC_ADD, s.tri == NO_HIT);
        contrib[i] = Contribution(c.x, c.y, c.z, s.pixel, flags, 0u, 0u, 0u);
        return;
    }
    // An AO ray: its throughput where it found no occluder.
    let j = i - p.n_surfaces;
    let r = rays[j];
    if (r.kind != KIND_AO || r.source >= p.n_surfaces || r.pixel >= p.n_pixels) {
        atomicMax(&report[2], 0xffffffffu - j);
        contrib[i].pixel = NO_HIT;
        return;
    }
    let flags = select(0u, ACC_ADD, hits[j].tri == NO_HIT);
    contrib[i] = Contribution(r.tr, r.tg, r.tb, r.pixel, flags, 0u, 0u, 0u);
}
