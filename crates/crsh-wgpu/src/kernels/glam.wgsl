// glam's Vec3 helpers, written with glam's scalar operations in glam's order (Vec3 is the
// scalar, non-SIMD type), so that a kernel computes what its CPU twin computes up to WGSL's
// rounding of `sqrt` and division. Prepended where needed (after common.wgsl).

fn g_dot(a: vec3<f32>, b: vec3<f32>) -> f32 {
    return (a.x * b.x) + (a.y * b.y) + (a.z * b.z);
}

fn g_cross(a: vec3<f32>, b: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(a.y * b.z - b.y * a.z, a.z * b.x - b.z * a.x, a.x * b.y - b.x * a.y);
}

// f32::is_finite.
fn g_finite(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7f800000u) != 0x7f800000u;
}

// Vec3::is_finite.
fn g_vec_finite(v: vec3<f32>) -> bool {
    return g_finite(v.x) && g_finite(v.y) && g_finite(v.z);
}

// Vec3 == Vec3::ZERO (either sign of zero).
fn g_is_zero(v: vec3<f32>) -> bool {
    return v.x == 0.0 && v.y == 0.0 && v.z == 0.0;
}

fn g_length(v: vec3<f32>) -> f32 {
    return sqrt(g_dot(v, v));
}

// glam's normalize_or_zero: v / |v| when that reciprocal is finite and positive.
fn g_normalize_or_zero(v: vec3<f32>) -> vec3<f32> {
    let rcp = 1.0 / g_length(v);
    if (g_finite(rcp) && rcp > 0.0) {
        return v * rcp;
    }
    return vec3<f32>(0.0);
}
