// Counter-based random numbers and cosine-weighted directions: the twin of crsh_core::rng (see
// kernels/rng.rs). Prepended: glam.wgsl, trig.wgsl (whose `PI` the including kernel defines).
//
// WGSL's u32 arithmetic wraps like Rust's wrapping_mul / wrapping_add, so `pcg4d` returns the
// CPU's words bit for bit, and `rng_unit` (the top 24 bits times 2^-24) the CPU's floats. The
// directions use `sqrt`, division and sine / cosine (trig.wgsl's accurate ones: WGSL's builtin
// sin / cos may be off by 2^-11), so they agree with the CPU's up to a few 1e-7.

// Jarzynski and Olano's pcg4d (JCGT 2020): crsh_core::rng::pcg4d.
fn pcg4d(key: vec4<u32>) -> vec4<u32> {
    var v = key * 1664525u + 1013904223u;
    v.x += v.y * v.w;
    v.y += v.z * v.x;
    v.z += v.x * v.y;
    v.w += v.y * v.z;
    v = v ^ (v >> vec4<u32>(16u));
    v.x += v.y * v.w;
    v.y += v.z * v.x;
    v.z += v.x * v.y;
    v.w += v.y * v.z;
    return v;
}

// crsh_core::rng::unit: a uniform in [0, 1) from the top 24 bits (exact in f32).
fn rng_unit(w: u32) -> f32 {
    return f32(w >> 8u) * (1.0 / 16777216.0);
}

// RngKey { pixel, sample, bounce, seed }.uniforms2().
fn rng_uniforms2(pixel: u32, sample: u32, bounce: u32, seed: u32) -> vec2<f32> {
    let w = pcg4d(vec4<u32>(pixel, sample, bounce, seed));
    return vec2<f32>(rng_unit(w.x), rng_unit(w.y));
}

// crsh_core::rng::basis (Duff et al. 2017): (t, b) completing the unit n, as columns 0 and 1.
fn rng_basis(n: vec3<f32>) -> mat2x3<f32> {
    // 1.0f32.copysign(n.z): -1 for a negative z, -0.0 included.
    let sign = bitcast<f32>(0x3f800000u | (bitcast<u32>(n.z) & 0x80000000u));
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    return mat2x3<f32>(
        vec3<f32>(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        vec3<f32>(b, sign + n.y * n.y * a, -n.y),
    );
}

// (sin φ, cos φ) for φ = TAU · u in [0, 2π): trig.wgsl's accurate functions on [0, π], and
// through 2π − φ (exact in f32 for φ ≥ π) above.
fn rng_sincos(phi: f32) -> vec2<f32> {
    if (phi <= PI) {
        return vec2<f32>(sin_accurate(phi), cos_accurate(phi));
    }
    let x = 2.0 * PI - phi;
    return vec2<f32>(-sin_accurate(x), cos_accurate(x));
}

// crsh_core::rng::cosine_direction: the cosine-weighted direction about the unit n for u.
fn cosine_direction(n: vec3<f32>, u: vec2<f32>) -> vec3<f32> {
    let r = sqrt(u.x);
    let sc = rng_sincos(2.0 * PI * u.y);
    let tb = rng_basis(n);
    let z = sqrt(max(1.0 - u.x, 0.0));
    return g_normalize_or_zero(tb[0] * (r * sc.y) + tb[1] * (r * sc.x) + n * z);
}

// crsh_core::rng::front_cosine_direction: cosine_direction about the shading normal n,
// mirrored about the geometric plane of n_geo when it points at or below it.
fn front_cosine_direction(n: vec3<f32>, n_geo: vec3<f32>, u: vec2<f32>) -> vec3<f32> {
    let d = cosine_direction(n, u);
    let s = g_dot(d, n_geo);
    if (s > 0.0) {
        return d;
    }
    let m = g_normalize_or_zero(d - (2.0 * s) * n_geo);
    if (g_dot(m, n_geo) > 0.0) {
        return m;
    }
    return n_geo;
}
