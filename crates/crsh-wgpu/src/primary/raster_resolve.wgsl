// The resolve pass of `raster`: every pixel's triangle id becomes its G-buffer record, the
// twin of crsh_cpu::primary::raster's resolve (pixel-centre camera ray, the Möller-Trumbore
// plane solve, surface_from_hit). Prepended: common.wgsl, mt.wgsl, glam.wgsl, surface.wgsl,
// camera_ray.wgsl.

struct Params {
    view: View,
    // u32 per row of the copied id texture (256-byte aligned rows).
    row_stride: u32,
    // First pixel of this chunk and pixels in it.
    first: u32,
    count: u32,
    n_tris: u32,
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

@compute @workgroup_size(WG)
fn resolve(@builtin(global_invocation_id) gid: vec3<u32>,
           @builtin(num_workgroups) nwg: vec3<u32>) {
    let j = linear_id(gid, nwg);
    if (j >= p.count) {
        return;
    }
    let pixel = p.first + j;
    let x = pixel % p.view.width;
    let y = pixel / p.view.width;
    let dir = camera_dir(p.view, x, y);
    let tri = ids[y * p.row_stride + x];
    var hit = Hit(inf(), NO_HIT, 0.0, 0.0);
    if (tri < p.n_tris) {
        let h = pixel_plane_hit(prepared[tri], p.view.eye, dir);
        if (h.x >= 0.0) {
            hit = Hit(h.x, tri, h.y, h.z);
        }
    }
    surfaces[j] = surface_from_hit(dir, hit, pixel, vec3<f32>(1.0), 0u, p.n_tris);
}
