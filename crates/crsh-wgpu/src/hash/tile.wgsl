// `tile` hashing on the device: the twin of crsh_cpu::hash::tile::TileHasher (see tile.rs). Prepended:
// common.wgsl, RAY_KIND_SHADOW, tile_group.wgsl.

struct Params {
    // Rays in this chunk.
    n: u32,
    width: u32,
    height: u32,
    tile_size: u32,
    tiles_x: u32,
    // TileGrid::span: the numbers a tile can take.
    span: u32,
    // The scene's light count (min(lights, 2^32 - 1)).
    lights: u32,
    // The all-ones key of key_bits (lo, hi): the key of a ray outside the frame or of a shadow
    // ray naming a light the scene lacks (the CPU twin's errors).
    none_lo: u32,
    none_hi: u32,
    // 1: tiles in Z-order (TileOrder::Morton), 0: in rows.
    morton: u32,
    _b: u32,
    _c: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> rays: array<Ray>;
@group(0) @binding(2) var<storage, read_write> keys: array<vec2<u32>>;

@compute @workgroup_size(WG)
fn hash(@builtin(global_invocation_id) gid: vec3<u32>,
        @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= p.n) {
        return;
    }
    let r = rays[i];
    let g = tile_group(r.pixel, r.light, r.kind, p.width, p.height, p.tile_size, p.tiles_x,
                       p.span, p.morton);
    if (g.z == 0u || (r.kind == RAY_KIND_SHADOW && r.light >= p.lights)) {
        keys[i] = vec2<u32>(p.none_lo, p.none_hi);
    } else {
        keys[i] = g.xy;
    }
}
