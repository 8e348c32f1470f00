// Seed 004's screen-tile group of a ray: the twin of
// crsh_cpu::hash::tile::TileGrid::group. Prepended: common.wgsl and the generated constant
// RAY_KIND_SHADOW (crate::hash::tile).
//
// tile = (y / ts)·tiles_x + x / ts for the pixel y·width + x (rows), or the tile coordinates'
// bits interleaved, x / ts in the even bits (Z-order, `morton` != 0); group = tile, or for
// shadow rays light·span + tile (so that a node never mixes two lights), as a u64 in (lo, hi).
// span is the numbers a tile can take (TileGrid::span: tiles in rows, 4^b in Z-order).

// v's low 16 bits spread to the even bits (bit i to bit 2i): crsh_core::quantize::spread2 for
// tile coordinates (below 2^14).
fn spread_bits(x: u32) -> u32 {
    var v = x & 0xffffu;
    v = (v | (v << 8u)) & 0x00ff00ffu;
    v = (v | (v << 4u)) & 0x0f0f0f0fu;
    v = (v | (v << 2u)) & 0x33333333u;
    return (v | (v << 1u)) & 0x55555555u;
}

// a·b as a u64 (lo, hi) from 16-bit halves.
fn mul_wide(a: u32, b: u32) -> vec2<u32> {
    let a_lo = a & 0xffffu;
    let a_hi = a >> 16u;
    let b_lo = b & 0xffffu;
    let b_hi = b >> 16u;
    let ll = a_lo * b_lo;
    let lh = a_lo * b_hi;
    let hl = a_hi * b_lo;
    let hh = a_hi * b_hi;
    let mid = (ll >> 16u) + (lh & 0xffffu) + (hl & 0xffffu);
    let lo = (ll & 0xffffu) | (mid << 16u);
    let hi = hh + (lh >> 16u) + (hl >> 16u) + (mid >> 16u);
    return vec2<u32>(lo, hi);
}

// The group of a ray with `pixel`, `light` and `kind` in a frame of `width × height` cut into
// tiles of `ts` pixels (`tiles_x` per row, tile numbers below `span`, numbered in Z-order when
// `morton` != 0): (lo, hi, 1), or (0, 0, 0) when the pixel is outside the frame.
fn tile_group(pixel: u32, light: u32, kind: u32, width: u32, height: u32, ts: u32,
              tiles_x: u32, span: u32, morton: u32) -> vec3<u32> {
    let y = pixel / width;
    let x = pixel % width;
    if (y >= height) {
        return vec3<u32>(0u, 0u, 0u);
    }
    var tile = (y / ts) * tiles_x + x / ts;
    if (morton != 0u) {
        tile = spread_bits(x / ts) | (spread_bits(y / ts) << 1u);
    }
    if (kind != RAY_KIND_SHADOW) {
        return vec3<u32>(tile, 0u, 1u);
    }
    let m = mul_wide(light, span);
    let lo = m.x + tile;
    var hi = m.y;
    if (lo < m.x) {
        hi += 1u;
    }
    return vec3<u32>(lo, hi, 1u);
}
