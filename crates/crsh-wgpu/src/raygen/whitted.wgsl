// `whitted` ray generation on the device: the twin of crsh_cpu::raygen::whitted (see
// whitted.rs). Prepended: common.wgsl, glam.wgsl, segment.wgsl, origin_offset.wgsl;
// appended: slots.wgsl (the bindings but the parameters and lights, and the passes).

struct Params {
    // Surfaces in the batch, and the first surface and count of this dispatch's chunk.
    n: u32,
    first: u32,
    count: u32,
    // Slots per surface: the lights for shadow rays, else 1.
    per_surface: u32,
    // RayKind as u32.
    kind: u32,
    n_materials: u32,
    shadow_from_light: u32,
    cull_backfacing: u32,
    // 0 normal, 1 scaled, 2 fixed, 3 wachter.
    policy: u32,
    // The policy's distance (normal / scaled: epsilon × diagonal; fixed: fixed_epsilon).
    offset: f32,
    min_throughput: f32,
    // emit: the output range bound at `out`.
    out_first: u32,
    out_count: u32,
    // 1: every material opaque and diffuse (Whitted::lambertian, the diffuse generator's
    // shadow rays).
    lambertian: u32,
    _b: u32,
    _c: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(2) var<storage, read> lights: array<Light>;

const FRONT_FACE: u32 = 1u;

fn reflect3(i: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    return i - 2.0 * n * g_dot(n, i);
}

fn refraction_direction(i: vec3<f32>, n: vec3<f32>, ior: f32, front: bool) -> vec3<f32> {
    var ri = ior;
    if (front) {
        ri = 1.0 / ior;
    }
    let cos_i = g_dot(i, n);
    let k = 1.0 - ri * ri * (1.0 - cos_i * cos_i);
    if (k < 0.0) {
        return g_normalize_or_zero(reflect3(i, n));
    }
    return g_normalize_or_zero(i * ri - n * (ri * cos_i + sqrt(k)));
}

// The ray of slot (surface `source`, light `light`), if the surface spawns one.
fn make(source: u32, light: u32) -> Made {
    var m: Made;
    m.ok = false;
    let s = surfaces[source - p.first];
    if (s.tri == NO_HIT) {
        return m;
    }
    if (s.material >= p.n_materials) {
        atomicMax(&report[0], 0xffffffffu - s.pixel);
        return m;
    }
    let mat = materials[s.material];
    var throughput: vec3<f32>;
    var seg: Segment;
    if (p.kind == 1u) {
        let l = lights[light].position;
        let to_light = l - s.position;
        if (p.cull_backfacing != 0u && g_dot(to_light, s.geo_normal) <= 0.0) {
            return m;
        }
        var local_weight = 1.0;
        if (p.lambertian == 0u) {
            local_weight = max(1.0 - mat.reflectivity - mat.transparency, 0.0);
        }
        throughput = s.throughput * local_weight;
        if (!keeps_throughput(throughput, p.min_throughput)) {
            return m;
        }
        var leg = LEG_TO;
        if (p.shadow_from_light != 0u) {
            leg = LEG_FROM;
        }
        seg = offset_segment(s.position, s.geo_normal, leg, l, p.policy, p.offset);
    } else {
        var dir: vec3<f32>;
        var weight: f32;
        if (p.lambertian != 0u) {
            return m;
        } else if (p.kind == 2u && mat.reflectivity > 0.0) {
            weight = mat.reflectivity;
            dir = g_normalize_or_zero(reflect3(s.incident, s.normal));
        } else if (p.kind == 3u && mat.transparency > 0.0) {
            weight = mat.transparency;
            dir = refraction_direction(s.incident, s.normal, mat.ior, (s.flags & FRONT_FACE) != 0u);
        } else {
            return m;
        }
        throughput = s.throughput * weight;
        if (!keeps_throughput(throughput, p.min_throughput)) {
            return m;
        }
        seg = offset_segment(s.position, s.geo_normal, LEG_ALONG, dir, p.policy, p.offset);
    }
    if (!seg.ok) {
        return m;
    }
    // Origin offsets: a shadow ray from the light ends on the surface (t_max cut), every
    // other ray leaves it (t_min raised).
    var t: vec2<f32>;
    if (p.kind == 1u && p.shadow_from_light != 0u) {
        t = offsets_cut_end(s.tri, seg.origin, seg.dir, seg.t_min, seg.t_max);
    } else {
        t = offsets_apply(s.tri, seg.origin, seg.dir, seg.t_min, seg.t_max);
    }
    m.ok = true;
    var lid = 0xffffffffu;
    if (p.kind == 1u) {
        lid = light;
    }
    m.ray = Ray(seg.origin.x, seg.origin.y, seg.origin.z, t.x,
                seg.dir.x, seg.dir.y, seg.dir.z, t.y,
                throughput.x, throughput.y, throughput.z,
                p.kind, s.pixel, lid, s.depth + 1u, source);
    return m;
}

// Slot j of the chunk: (surface first + j % count, light j / count); its global slot index
// is light·n + surface (light-major, surface order).
fn slot_of(j: u32) -> vec3<u32> {
    let surface = p.first + j % p.count;
    let light = j / p.count;
    return vec3<u32>(surface, light, light * p.n + surface);
}
