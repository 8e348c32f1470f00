// `whitted` ray generation on the device: the twin of crsh_cpu::raygen::whitted (see
// whitted.rs). Prepended: common.wgsl.

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
    _a: u32,
    _b: u32,
    _c: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> surfaces: array<Surface>;
@group(0) @binding(2) var<storage, read> lights: array<Light>;
@group(0) @binding(3) var<storage, read> materials: array<Material>;
// count: 1 per kept slot; emit: the exclusive scan of those flags (output positions).
@group(0) @binding(4) var<storage, read_write> slots: array<u32>;
@group(0) @binding(5) var<storage, read_write> rays_out: array<Ray>;
// [bad material report (0xffffffff - pixel), ...]
@group(0) @binding(6) var<storage, read_write> report: array<atomic<u32>>;

const WACHTER_ORIGIN: f32 = 0.03125;
const WACHTER_FLOAT_SCALE: f32 = 1.52587890625e-05;
const WACHTER_INT_SCALE: f32 = 256.0;
const WACHTER_T_ULPS: f32 = 32.0;
const FRONT_FACE: u32 = 1u;

fn len3(v: vec3<f32>) -> f32 {
    return sqrt(v.x * v.x + v.y * v.y + v.z * v.z);
}

// glam's Vec3::normalize_or_zero: v / |v| when that reciprocal is finite and positive.
fn normalize_or_zero(v: vec3<f32>) -> vec3<f32> {
    let rcp = 1.0 / len3(v);
    if (f32_is_finite(rcp) && rcp > 0.0) {
        return v * rcp;
    }
    return vec3<f32>(0.0);
}

fn f32_is_finite(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7f800000u) != 0x7f800000u;
}

fn vec_is_finite(v: vec3<f32>) -> bool {
    return f32_is_finite(v.x) && f32_is_finite(v.y) && f32_is_finite(v.z);
}

fn dot3(a: vec3<f32>, b: vec3<f32>) -> f32 {
    return a.x * b.x + a.y * b.y + a.z * b.z;
}

// f32::max / min as Rust has them for finite input.
fn ulp(x: f32) -> f32 {
    return bitcast<f32>(bitcast<u32>(x) + 1u) - x;
}

fn wachter_component(p: f32, n: f32) -> f32 {
    if (abs(p) < WACHTER_ORIGIN) {
        return p + WACHTER_FLOAT_SCALE * n;
    }
    let ulps = i32(WACHTER_INT_SCALE * n);
    let bits = bitcast<i32>(p);
    var moved: i32;
    if (p < 0.0) {
        moved = bits - ulps;
    } else {
        moved = bits + ulps;
    }
    return bitcast<f32>(moved);
}

// Wächter & Binder's offset_ray (Ray Tracing Gems ch. 6).
fn offset_ray(p: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(wachter_component(p.x, n.x), wachter_component(p.y, n.y), wachter_component(p.z, n.z));
}

struct Segment {
    ok: bool,
    origin: vec3<f32>,
    dir: vec3<f32>,
    t_min: f32,
    t_max: f32,
}

// crsh_cpu::raygen::whitted::offset_segment. leg: 0 Along(v), 1 To(v), 2 From(v).
fn offset_segment(pos: vec3<f32>, geo_normal: vec3<f32>, leg: u32, v: vec3<f32>) -> Segment {
    var leaving = v;
    if (leg != 0u) {
        leaving = v - pos;
    }
    var n = geo_normal;
    if (dot3(leaving, geo_normal) < 0.0) {
        n = -geo_normal;
    }
    var start = pos;
    var near = p.offset;
    var far = p.offset;
    let wachter = p.policy == 3u;
    if (p.policy == 0u) {
        start = pos + n * p.offset;
    } else if (wachter) {
        start = offset_ray(pos, n);
        near = 0.0;
    }
    var origin = start;
    var seg = v;
    if (leg == 1u) {
        seg = v - start;
    } else if (leg == 2u) {
        origin = v;
        seg = start - v;
    }
    let dir = normalize_or_zero(seg);
    var res: Segment;
    res.ok = false;
    if ((dir.x == 0.0 && dir.y == 0.0 && dir.z == 0.0) || !vec_is_finite(dir)) {
        return res;
    }
    res.ok = true;
    res.origin = origin;
    res.dir = dir;
    if (leg == 0u) {
        res.t_min = near;
        res.t_max = inf();
        return res;
    }
    if (wachter) {
        var towards_surface = -dir;
        if (leg == 2u) {
            towards_surface = dir;
        }
        far = len3(offset_ray(v, towards_surface) - v);
    }
    let l = len3(seg);
    if (wachter && leg == 2u) {
        near = WACHTER_T_ULPS * ulp(l);
    }
    if (leg == 2u) {
        res.t_min = far;
        res.t_max = max(l - near, far);
    } else {
        res.t_min = near;
        res.t_max = max(l - far, near);
    }
    return res;
}

fn reflect3(i: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    return i - 2.0 * n * dot3(n, i);
}

fn refraction_direction(i: vec3<f32>, n: vec3<f32>, ior: f32, front: bool) -> vec3<f32> {
    var ri = ior;
    if (front) {
        ri = 1.0 / ior;
    }
    let cos_i = dot3(i, n);
    let k = 1.0 - ri * ri * (1.0 - cos_i * cos_i);
    if (k < 0.0) {
        return normalize_or_zero(reflect3(i, n));
    }
    return normalize_or_zero(i * ri - n * (ri * cos_i + sqrt(k)));
}

fn keeps(t: vec3<f32>) -> bool {
    return max(t.x, max(t.y, t.z)) >= p.min_throughput && vec_is_finite(t);
}

struct Made {
    ok: bool,
    ray: Ray,
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
        if (p.cull_backfacing != 0u && dot3(to_light, s.geo_normal) <= 0.0) {
            return m;
        }
        throughput = s.throughput * max(1.0 - mat.reflectivity - mat.transparency, 0.0);
        if (!keeps(throughput)) {
            return m;
        }
        var leg = 1u;
        if (p.shadow_from_light != 0u) {
            leg = 2u;
        }
        seg = offset_segment(s.position, s.geo_normal, leg, l);
    } else {
        var dir: vec3<f32>;
        var weight: f32;
        if (p.kind == 2u && mat.reflectivity > 0.0) {
            weight = mat.reflectivity;
            dir = normalize_or_zero(reflect3(s.incident, s.normal));
        } else if (p.kind == 3u && mat.transparency > 0.0) {
            weight = mat.transparency;
            dir = refraction_direction(s.incident, s.normal, mat.ior, (s.flags & FRONT_FACE) != 0u);
        } else {
            return m;
        }
        throughput = s.throughput * weight;
        if (!keeps(throughput)) {
            return m;
        }
        seg = offset_segment(s.position, s.geo_normal, 0u, dir);
    }
    if (!seg.ok) {
        return m;
    }
    m.ok = true;
    var lid = 0xffffffffu;
    if (p.kind == 1u) {
        lid = light;
    }
    m.ray = Ray(seg.origin.x, seg.origin.y, seg.origin.z, seg.t_min,
                seg.dir.x, seg.dir.y, seg.dir.z, seg.t_max,
                throughput.x, throughput.y, throughput.z,
                p.kind, s.pixel, lid, s.depth + 1u, source);
    return m;
}

// Slot j of the chunk: (light j / count, surface first + j % count); its global slot index is
// light·n + surface (light-major, surface order).
fn slot_of(j: u32) -> vec2<u32> {
    return vec2<u32>(p.first + j % p.count, j / p.count);
}

@compute @workgroup_size(WG)
fn count(@builtin(global_invocation_id) gid: vec3<u32>,
         @builtin(num_workgroups) nwg: vec3<u32>) {
    let j = linear_id(gid, nwg);
    if (j >= p.count * p.per_surface) {
        return;
    }
    let sl = slot_of(j);
    let made = make(sl.x, sl.y);
    slots[sl.y * p.n + sl.x] = select(0u, 1u, made.ok);
}

@compute @workgroup_size(WG)
fn emit(@builtin(global_invocation_id) gid: vec3<u32>,
        @builtin(num_workgroups) nwg: vec3<u32>) {
    let j = linear_id(gid, nwg);
    if (j >= p.count * p.per_surface) {
        return;
    }
    let sl = slot_of(j);
    let at = slots[sl.y * p.n + sl.x];
    if (at < p.out_first || at - p.out_first >= p.out_count) {
        return;
    }
    let made = make(sl.x, sl.y);
    if (made.ok) {
        rays_out[at - p.out_first] = made.ray;
    }
}
