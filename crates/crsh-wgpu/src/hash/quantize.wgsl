// Quantization and key packing shared by the hashes: the twins of crsh_core::quantize
// (UniformCells::cell, scaled_direction, square, octahedral_cells, FieldOrder::combine /
// interleave), bit for bit: only +, -, *, comparisons, floor, min/max and bit operations, every
// product either exact or feeding only a comparison or a floor (so FMA contraction cannot change
// a result), inputs screened by their bits (NaN, infinities, subnormals) before any arithmetic.
// No division, sqrt, acos or atan2 (not correctly rounded in WGSL). Keys as vec2<u32> (x = low
// word). Prepended after common.wgsl.

fn shl64(v: vec2<u32>, s: u32) -> vec2<u32> {
    if (s == 0u) { return v; }
    if (s >= 64u) { return vec2<u32>(0u); }
    if (s >= 32u) { return vec2<u32>(0u, v.x << (s - 32u)); }
    return vec2<u32>(v.x << s, (v.y << s) | (v.x >> (32u - s)));
}

fn mask_width(v: u32, w: u32) -> u32 {
    if (w >= 32u) { return v; }
    return v & ((1u << w) - 1u);
}

// quantize::combine: concatenated (first field highest) or interleaved MSB-first.
fn combine(vals: array<u32, 5>, widths: array<u32, 5>, count: u32, interleave: bool) -> vec2<u32> {
    var out = vec2<u32>(0u);
    if (!interleave) {
        for (var f = 0u; f < count; f++) {
            out = shl64(out, widths[f]) | vec2<u32>(mask_width(vals[f], widths[f]), 0u);
        }
        return out;
    }
    var max_w = 0u;
    for (var f = 0u; f < count; f++) { max_w = max(max_w, widths[f]); }
    for (var level = 0u; level < max_w; level++) {
        for (var f = 0u; f < count; f++) {
            if (level < widths[f]) {
                let bit = (vals[f] >> (widths[f] - 1u - level)) & 1u;
                out = shl64(out, 1u) | vec2<u32>(bit, 0u);
            }
        }
    }
    return out;
}

// 2^bits as an f32 (exact).
fn pow2f(bits: u32) -> f32 {
    return bitcast<f32>((127u + bits) << 23u);
}

// quantize::UniformCells::cell: floor((clamp(x, lo, hi) - lo) * scale), clamped to
// 0 ..= 2^bits - 1 (scale = 2^bits / (hi - lo) rounded to f32 on the host; 0 when degenerate).
fn uniform_cell(x: f32, lo: f32, hi: f32, scale: f32, bits: u32) -> u32 {
    let b = bitcast<u32>(x);
    let e = b & 0x7f800000u;
    var v = 0.0;
    if (e == 0x7f800000u) {
        if ((b & 0x007fffffu) != 0u) { return 0u; }
        v = select(hi, lo, (b >> 31u) == 1u);
    } else if (e != 0u) {
        v = min(max(x, lo), hi);
    }
    let f = floor((v - lo) * scale);
    if (f >= pow2f(bits)) {
        if (bits >= 32u) { return 0xffffffffu; }
        return (1u << bits) - 1u;
    }
    return u32(f);
}

// quantize::scaled_direction: d scaled by a power of two (exponent arithmetic) so that its
// largest component is in [1, 2), components 2^32 times smaller than it (or subnormal) set to
// 0; w = 0 for a zero, subnormal-only or non-finite direction, else 1.
fn scaled_direction(d: vec3<f32>) -> vec4<f32> {
    let b = vec3<u32>(bitcast<u32>(d.x), bitcast<u32>(d.y), bitcast<u32>(d.z));
    let e = (b >> vec3<u32>(23u)) & vec3<u32>(0xffu);
    let top = max(e.x, max(e.y, e.z));
    if (top == 0u || top == 0xffu) {
        return vec4<f32>(0.0);
    }
    var out = vec4<f32>(0.0, 0.0, 0.0, 1.0);
    for (var i = 0u; i < 3u; i++) {
        if (e[i] != 0u && e[i] + 32u >= top) {
            out[i] = bitcast<f32>((b[i] & 0x807fffffu) | ((e[i] + 127u - top) << 23u));
        }
    }
    return out;
}

// quantize::product: a * b as the sum of the exact products of the 12-bit halves.
fn product_exact(a: f32, b: f32) -> f32 {
    let ah = bitcast<f32>(bitcast<u32>(a) & 0xfffff000u);
    let bh = bitcast<f32>(bitcast<u32>(b) & 0xfffff000u);
    let al = a - ah;
    let bl = b - bh;
    return ah * bh + ((ah * bl + al * bh) + al * bl);
}

// quantize::square.
fn square_exact(x: f32) -> f32 {
    return product_exact(x, x);
}

// quantize::octa_cell: the last k in 0 ..= 2^bits - 1 with num >= b_k * l1,
// b_k = -1 + k * 2^(1 - bits) (exact: k * 2^(1 - bits) is a power-of-two scaling).
fn octa_cell(num: f32, l1: f32, bits: u32) -> u32 {
    if (bits == 0u) { return 0u; }
    let step = bitcast<f32>((128u - bits) << 23u);
    var lo = 0u;
    var hi = (1u << bits) - 1u;
    while (lo < hi) {
        let mid = lo + (hi - lo + 1u) / 2u;
        let b = f32(mid) * step - 1.0;
        if (num >= b * l1) { lo = mid; } else { hi = mid - 1u; }
    }
    return lo;
}

// quantize::octahedral_cells: the octahedral square's cells without dividing by |x|+|y|+|z|.
fn octahedral_cells(d: vec3<f32>, ub: u32, vb: u32) -> vec2<u32> {
    var s = scaled_direction(d);
    if (s.w == 0.0) {
        s = vec4<f32>(0.0, 0.0, 1.0, 1.0);
    }
    let a = abs(s.xyz);
    let l1 = (a.x + a.y) + a.z;
    var nu = s.x;
    var nv = s.y;
    if (s.z < 0.0) {
        nu = (a.x + a.z) * select(-1.0, 1.0, s.x >= 0.0);
        nv = (a.y + a.z) * select(-1.0, 1.0, s.y >= 0.0);
    }
    return vec2<u32>(octa_cell(nu, l1, ub), octa_cell(nv, l1, vb));
}
