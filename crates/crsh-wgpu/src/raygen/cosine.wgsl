// `ao` and `diffuse` ray generation on the device: cosine-weighted rays leaving surfaces, the
// twins of crsh_cpu::raygen::ao and crsh_cpu::raygen::diffuse's diffuse rays (see cosine.rs).
// Prepended: common.wgsl, glam.wgsl, trig.wgsl, rng.wgsl, segment.wgsl, origin_offset.wgsl;
// appended: slots.wgsl (the bindings but the parameters, and the passes).

const PI: f32 = 3.14159265358979;
const KIND_AO: u32 = 4u;
const SAMPLE_SHIFT: u32 = 8u;

struct Params {
    // Surfaces in the batch, and the first surface and count of this dispatch's chunk.
    n: u32,
    first: u32,
    count: u32,
    // Slots per surface (surface-major): `samples` for AO rays and for a batch with a primary
    // vertex, else 1.
    per_surface: u32,
    // RayKind as u32: 4 (Ao) or 5 (Diffuse).
    kind: u32,
    n_materials: u32,
    // AO rays per surface, or diffuse paths started at a primary vertex.
    samples: u32,
    seed: u32,
    // 0 normal, 1 scaled, 2 fixed, 3 wachter, and the policy's distance.
    policy: u32,
    offset: f32,
    min_throughput: f32,
    // AO rays' length (ao_length × the scene's diagonal).
    length: f32,
    // emit: the output range bound at `out`.
    out_first: u32,
    out_count: u32,
    _a: u32,
    _b: u32,
}

@group(0) @binding(0) var<uniform> p: Params;

// The ray of slot `k` of surface `source`, if it makes one: Ao::ray, or the slot loop of
// Diffuse::diffuse_slots with Diffuse::ray.
fn make(source: u32, k: u32) -> Made {
    var m: Made;
    m.ok = false;
    let s = surfaces[source - p.first];
    if (s.tri == NO_HIT) {
        return m;
    }
    var sample = k;
    var throughput: vec3<f32>;
    if (p.kind == KIND_AO) {
        throughput = s.throughput / f32(p.samples);
    } else {
        if (s.material >= p.n_materials) {
            atomicMax(&report[0], 0xffffffffu - s.pixel);
            return m;
        }
        // A primary vertex starts `samples` paths; a deeper one continues its own.
        var paths = p.samples;
        if (s.depth != 0u) {
            if (k != 0u) {
                return m;
            }
            sample = s.flags >> SAMPLE_SHIFT;
            paths = 1u;
        }
        let albedo = max(materials[s.material].diffuse, vec3<f32>(0.0));
        throughput = s.throughput * albedo / f32(paths);
    }
    if (!keeps_throughput(throughput, p.min_throughput)) {
        return m;
    }
    let u = rng_uniforms2(s.pixel, sample, s.depth, p.seed);
    let dir = front_cosine_direction(s.normal, s.geo_normal, u);
    if (g_is_zero(dir)) {
        return m;
    }
    let seg = offset_segment(s.position, s.geo_normal, LEG_ALONG, dir, p.policy, p.offset);
    if (!seg.ok) {
        return m;
    }
    var t_max = seg.t_max;
    if (p.kind == KIND_AO) {
        t_max = max(p.length, seg.t_min);
    }
    // Origin offsets: t_min raised past the hemispheres of the triangle the ray leaves.
    let t = offsets_apply(s.tri, seg.origin, seg.dir, seg.t_min, t_max);
    m.ok = true;
    m.ray = Ray(seg.origin.x, seg.origin.y, seg.origin.z, t.x,
                seg.dir.x, seg.dir.y, seg.dir.z, t.y,
                throughput.x, throughput.y, throughput.z,
                p.kind, s.pixel, sample, s.depth + 1u, source);
    return m;
}

// Slot j of the chunk: (surface first + j / per_surface, slot j % per_surface); its global
// slot index is first · per_surface + j (surface-major).
fn slot_of(j: u32) -> vec3<u32> {
    return vec3<u32>(p.first + j / p.per_surface, j % p.per_surface, p.first * p.per_surface + j);
}

// Whether the batch holds a primary vertex (depth 0), which decides the diffuse slot count
// (run with per_surface = 1): report[1] = 1.
@compute @workgroup_size(WG)
fn probe(@builtin(global_invocation_id) gid: vec3<u32>,
         @builtin(num_workgroups) nwg: vec3<u32>) {
    let j = linear_id(gid, nwg);
    if (j >= p.count) {
        return;
    }
    if (surfaces[j].depth == 0u) {
        atomicOr(&report[1], 1u);
    }
}
