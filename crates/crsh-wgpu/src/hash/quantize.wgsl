// Quantization and key packing shared by the hashes: the twins of crsh_core::quantize
// (quantize, spherical_cells, octahedral, FieldOrder::combine / interleave) in f32, keys as
// vec2<u32> (x = low word). Prepended after common.wgsl.

const PI: f32 = 3.14159265358979;

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

fn quantize(x: f32, lo: f32, hi: f32, bits: u32) -> u32 {
    if (bits == 0u) { return 0u; }
    let cells = exp2(f32(bits));
    let span = hi - lo;
    if (!(span > 0.0 && span < inf())) { return 0u; }
    let f = floor((x - lo) / span * cells);
    if (!(f >= 0.0)) { return 0u; }
    if (f >= cells) {
        if (bits >= 32u) { return 0xffffffffu; }
        return (1u << bits) - 1u;
    }
    return u32(f);
}

fn spherical_cells(d: vec3<f32>, tb: u32, pb: u32) -> vec2<u32> {
    let l = length(d);
    if (!(l > 0.0 && l < inf())) {
        return vec2<u32>(quantize(0.0, 0.0, PI, tb), quantize(0.0, -PI, PI, pb));
    }
    let n = d / l;
    // θ = acos(n.z) as Kahan's 2·atan2(|n − z|, |n + z|), accurate at both poles.
    let below = vec3<f32>(n.x, n.y, n.z - 1.0);
    let above = vec3<f32>(n.x, n.y, n.z + 1.0);
    let theta = 2.0 * atan2_accurate(length(below), length(above));
    let phi = atan2_accurate(n.y, n.x);
    return vec2<u32>(quantize(theta, 0.0, PI, tb), quantize(phi, -PI, PI, pb));
}

// quantize::octahedral: the octahedral map of a direction into [-1, 1]².
fn octahedral(d: vec3<f32>) -> vec2<f32> {
    let l1 = abs(d.x) + abs(d.y) + abs(d.z);
    if (!(l1 > 0.0 && l1 < inf())) {
        return vec2<f32>(0.0);
    }
    let p = d / l1;
    if (p.z >= 0.0) {
        return p.xy;
    }
    return vec2<f32>((1.0 - abs(p.y)) * select(-1.0, 1.0, p.x >= 0.0),
                     (1.0 - abs(p.x)) * select(-1.0, 1.0, p.y >= 0.0));
}
