// Möller-Trumbore on host-prepared triangles: the twin of crsh_cpu::triangle::moller_trumbore
// (`mt_lane`, `inside`, `PreparedTriangle::{intersect, plane_hit}`), the same operations in
// the same order. Included by the kernels that test rays against triangles.

// crsh_cpu::triangle::PreparedTriangle (40 bytes): v0, e1 = b - a, e2 = c - a (zero for a
// degenerate triangle), det_eps = DET_REL_EPS·|e1|·|e2|, all computed on the host.
struct MtTri {
    v0x: f32, v0y: f32, v0z: f32,
    e1x: f32, e1y: f32, e1z: f32,
    e2x: f32, e2y: f32, e2z: f32,
    det_eps: f32,
}

// `(det_ok, t, u, v)` packed as vec4 (x = 1 when the determinant test passed).
fn mt_lane(tri: MtTri, o: vec3<f32>, d: vec3<f32>, d_len: f32) -> vec4<f32> {
    let px = d.y * tri.e2z - d.z * tri.e2y;
    let py = d.z * tri.e2x - d.x * tri.e2z;
    let pz = d.x * tri.e2y - d.y * tri.e2x;
    let det = tri.e1x * px + tri.e1y * py + tri.e1z * pz;
    let inv = 1.0 / det;
    let sx = o.x - tri.v0x;
    let sy = o.y - tri.v0y;
    let sz = o.z - tri.v0z;
    let u = (sx * px + sy * py + sz * pz) * inv;
    let qx = sy * tri.e1z - sz * tri.e1y;
    let qy = sz * tri.e1x - sx * tri.e1z;
    let qz = sx * tri.e1y - sy * tri.e1x;
    let v = (d.x * qx + d.y * qy + d.z * qz) * inv;
    let t = (tri.e2x * qx + tri.e2y * qy + tri.e2z * qz) * inv;
    let ok = select(0.0, 1.0, abs(det) > tri.det_eps * d_len);
    return vec4<f32>(ok, t, u, v);
}

fn ray_dir_len(d: vec3<f32>) -> f32 {
    return sqrt(d.x * d.x + d.y * d.y + d.z * d.z);
}

fn mt_inside(u: f32, v: f32) -> bool {
    return (u >= 0.0) && (v >= 0.0) && (u + v <= 1.0);
}

// `(t, u, v)` of a hit strictly inside `(t_min, t_max)`; t = +inf when there is none.
fn mt_hit(tri: MtTri, o: vec3<f32>, d: vec3<f32>, d_len: f32, t_min: f32, t_max: f32) -> vec3<f32> {
    let r = mt_lane(tri, o, d, d_len);
    let hit = r.x > 0.5 && mt_inside(r.z, r.w) && r.y > t_min && r.y < t_max;
    return select(vec3<f32>(inf(), r.z, r.w), r.yzw, hit);
}

// Hit::closer_than: smaller t, ties to the lower triangle id.
fn closer_than(t: f32, tri: u32, best: Hit) -> bool {
    return t < best.t || (t == best.t && tri < best.tri);
}

// Adds `n` to the 64-bit counter held in counters[at] (low word) and counters[at + 1].
fn add_u64(at: u32, n: u32) {
    if (n == 0u) { return; }
    let old = atomicAdd(&counters[at], n);
    if (old + n < old) {
        atomicAdd(&counters[at + 1u], 1u);
    }
}

fn f32_finite(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7f800000u) != 0x7f800000u;
}

fn f32_nan(x: f32) -> bool {
    let b = bitcast<u32>(x);
    return (b & 0x7f800000u) == 0x7f800000u && (b & 0x007fffffu) != 0u;
}

// crsh_core::Ray::is_valid: finite origin and direction, non-zero direction, no NaN bound.
fn ray_valid(r: Ray) -> bool {
    let o = ray_origin(r);
    let d = ray_dir(r);
    return f32_finite(o.x) && f32_finite(o.y) && f32_finite(o.z)
        && f32_finite(d.x) && f32_finite(d.y) && f32_finite(d.z)
        && dot(d, d) > 0.0 && !f32_nan(r.t_min) && !f32_nan(r.t_max);
}
