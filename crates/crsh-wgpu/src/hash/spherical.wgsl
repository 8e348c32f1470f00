// Spherical direction cells: the twins of crsh_core::quantize::{theta_cell, phi_cell,
// spherical_cells}, bit for bit, by binary search over the host's boundary tables
// (quantize::theta_table / phi_table, concatenated in `dir_tables`, which the including shader
// declares). Prepended after quantize.wgsl.

// The last theta boundary k the scaled direction s passes (table at `base`, 2^bits entries).
fn theta_cell(s: vec3<f32>, bits: u32, base: u32) -> u32 {
    if (bits == 0u) { return 0u; }
    let rho2 = square_exact(s.x) + square_exact(s.y);
    let z2 = square_exact(s.z);
    let half = 1u << (bits - 1u);
    var lo = 0u;
    var hi = (1u << bits) - 1u;
    while (lo < hi) {
        let mid = lo + (hi - lo + 1u) / 2u;
        var ok = s.z <= 0.0;
        if (mid < half) {
            ok = ok || rho2 >= dir_tables[base + mid] * z2;
        } else if (mid > half) {
            ok = s.z < 0.0 && rho2 <= dir_tables[base + mid] * z2;
        }
        if (ok) { lo = mid; } else { hi = mid - 1u; }
    }
    return lo;
}

// quantize::octant: 0-7 from phi = -pi; y = ±0 with x < 0 is phi = pi (octant 7).
fn octant(x: f32, y: f32) -> u32 {
    let ax = abs(x);
    let ay = abs(y);
    if (y >= 0.0) {
        if (x > 0.0) { return select(5u, 4u, ay < ax); }
        return select(7u, 6u, ay > ax);
    }
    if (x < 0.0) { return select(1u, 0u, ay < ax); }
    return select(3u, 2u, ay > ax);
}

// The last phi boundary k the scaled direction (x, y) passes (table at `base`).
fn phi_cell(x0: f32, y0: f32, bits: u32, base: u32) -> u32 {
    if (bits == 0u) { return 0u; }
    var x = x0;
    var y = y0;
    if (x == 0.0 && y == 0.0) {
        x = 1.0;
        y = 0.0;
    }
    let o = octant(x, y);
    var n = abs(x);
    var m = abs(y);
    if (o == 0u || o == 3u || o == 4u || o == 7u) {
        n = abs(y);
        m = abs(x);
    }
    var lo = 0u;
    var hi = (1u << bits) - 1u;
    while (lo < hi) {
        let mid = lo + (hi - lo + 1u) / 2u;
        let mo = (mid << 3u) >> bits;
        var ok = o > mo;
        if (mo == o) {
            let t = dir_tables[base + mid] * m;
            ok = select(n <= t, n >= t, o % 2u == 0u);
        }
        if (ok) { lo = mid; } else { hi = mid - 1u; }
    }
    return lo;
}

// quantize::spherical_cells: (theta cell, phi cell) of direction d.
fn spherical_cells(d: vec3<f32>, tb: u32, pb: u32, theta_base: u32, phi_base: u32) -> vec2<u32> {
    let s = scaled_direction(d);
    if (s.w == 0.0) {
        return vec2<u32>(0u, phi_cell(1.0, 0.0, pb, phi_base));
    }
    return vec2<u32>(theta_cell(s.xyz, tb, theta_base), phi_cell(s.x, s.y, pb, phi_base));
}
