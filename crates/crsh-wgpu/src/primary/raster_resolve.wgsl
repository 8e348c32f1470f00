// The resolve pass of `raster`: every pixel's triangle id becomes its G-buffer record, the
// twin of crsh_cpu::primary::raster's resolve (pixel-centre camera ray, the Möller-Trumbore
// plane solve, surface_from_hit). Prepended: common.wgsl, mt.wgsl, glam.wgsl, surface.wgsl.

struct Params {
    width: u32,
    height: u32,
    // u32 per row of the copied id texture (256-byte aligned rows).
    row_stride: u32,
    // First pixel of this chunk and pixels in it.
    first: u32,
    count: u32,
    n_tris: u32,
    tan_half: f32,
    aspect: f32,
    right: vec3<f32>,
    _a: f32,
    up: vec3<f32>,
    _b: f32,
    forward: vec3<f32>,
    _c: f32,
    eye: vec3<f32>,
    _d: f32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> ids: array<u32>;
@group(0) @binding(2) var<storage, read> prepared: array<MtTri>;
@group(0) @binding(3) var<storage, read> scene_tris: array<Triangle>;
@group(0) @binding(4) var<storage, read> scene_normals: array<Triangle>;
@group(0) @binding(5) var<storage, read> scene_info: array<TriangleInfo>;
@group(0) @binding(6) var<storage, read_write> surfaces: array<Surface>;
// Unused here (mt.wgsl's counter helper names it).
@group(0) @binding(7) var<storage, read_write> counters: array<atomic<u32>>;

// crsh_scene::Camera::direction at the pixel centre, with glam's operations.
fn camera_dir(x: u32, y: u32) -> vec3<f32> {
    let sx = f32(x) + 0.5;
    let sy = f32(y) + 0.5;
    let ndc_x = (2.0 * sx / f32(p.width) - 1.0) * p.tan_half * p.aspect;
    let ndc_y = (1.0 - 2.0 * sy / f32(p.height)) * p.tan_half;
    let d = p.forward + p.right * ndc_x + p.up * ndc_y;
    return d * (1.0 / g_length(d));
}

@compute @workgroup_size(WG)
fn resolve(@builtin(global_invocation_id) gid: vec3<u32>,
           @builtin(num_workgroups) nwg: vec3<u32>) {
    let j = linear_id(gid, nwg);
    if (j >= p.count) {
        return;
    }
    let pixel = p.first + j;
    let x = pixel % p.width;
    let y = pixel / p.width;
    let dir = camera_dir(x, y);
    let tri = ids[y * p.row_stride + x];
    var hit = Hit(inf(), NO_HIT, 0.0, 0.0);
    if (tri < p.n_tris) {
        let r = mt_lane(prepared[tri], p.eye, dir, ray_dir_len(dir));
        let ok = r.x > 0.5 && f32_finite(r.y) && f32_finite(r.z) && f32_finite(r.w)
            && r.y > 0.0;
        if (ok) {
            hit = Hit(r.y, tri, r.z, r.w);
        }
    }
    surfaces[j] = surface_from_hit(dir, hit, pixel, vec3<f32>(1.0), 0u, p.n_tris);
}
