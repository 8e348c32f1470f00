// Rays leaving a surface: the self-intersection policies of
// crsh_cpu::raygen::whitted::offset_segment (Wächter & Binder's offset_ray included, with
// `bitcast`), and the throughput threshold, shared by the ray generators whitted, ao and
// diffuse. Prepended: glam.wgsl.

const WACHTER_ORIGIN: f32 = 0.03125;
const WACHTER_FLOAT_SCALE: f32 = 1.52587890625e-05;
const WACHTER_INT_SCALE: f32 = 256.0;
const WACHTER_T_ULPS: f32 = 32.0;

// The `policy` codes (crate::raygen::slots::policy_code).
const POLICY_NORMAL: u32 = 0u;
const POLICY_WACHTER: u32 = 3u;

// The `leg` codes: Leg::Along(v), Leg::To(v), Leg::From(v).
const LEG_ALONG: u32 = 0u;
const LEG_TO: u32 = 1u;
const LEG_FROM: u32 = 2u;

// The unit in the last place of the finite x >= 0.
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

// crsh_cpu::raygen::whitted::offset_segment for the policy `policy` with its distance `off`
// (normal / scaled: epsilon × diagonal; fixed: fixed_epsilon; wachter: unused).
fn offset_segment(pos: vec3<f32>, geo_normal: vec3<f32>, leg: u32, v: vec3<f32>, policy: u32,
                  off: f32) -> Segment {
    var leaving = v;
    if (leg != LEG_ALONG) {
        leaving = v - pos;
    }
    var n = geo_normal;
    if (g_dot(leaving, geo_normal) < 0.0) {
        n = -geo_normal;
    }
    var start = pos;
    var near = off;
    var far = off;
    let wachter = policy == POLICY_WACHTER;
    if (policy == POLICY_NORMAL) {
        start = pos + n * off;
    } else if (wachter) {
        start = offset_ray(pos, n);
        near = 0.0;
    }
    var origin = start;
    var seg = v;
    if (leg == LEG_TO) {
        seg = v - start;
    } else if (leg == LEG_FROM) {
        origin = v;
        seg = start - v;
    }
    let dir = g_normalize_or_zero(seg);
    var res: Segment;
    res.ok = false;
    if (g_is_zero(dir) || !g_vec_finite(dir)) {
        return res;
    }
    res.ok = true;
    res.origin = origin;
    res.dir = dir;
    if (leg == LEG_ALONG) {
        res.t_min = near;
        res.t_max = inf();
        return res;
    }
    if (wachter) {
        var towards_surface = -dir;
        if (leg == LEG_FROM) {
            towards_surface = dir;
        }
        far = g_length(offset_ray(v, towards_surface) - v);
    }
    let l = g_length(seg);
    if (wachter && leg == LEG_FROM) {
        near = WACHTER_T_ULPS * ulp(l);
    }
    if (leg == LEG_FROM) {
        res.t_min = far;
        res.t_max = max(l - near, far);
    } else {
        res.t_min = near;
        res.t_max = max(l - far, near);
    }
    return res;
}

// Whether a ray of this throughput is spawned: its largest component reaches `min_throughput`
// and all are finite.
fn keeps_throughput(t: vec3<f32>, min_throughput: f32) -> bool {
    return max(t.x, max(t.y, t.z)) >= min_throughput && g_vec_finite(t);
}
