// The render pass of `raster`: every triangle drawn with the camera of the CPU rasterizer,
// depth-tested (reverse Z, strictly nearer wins, so equal depths keep the lower triangle id,
// primitives being processed in order), writing the triangle id: a visibility buffer.
// Prepended: common.wgsl.

struct Camera {
    eye: vec3<f32>,
    // Near plane distance (reverse Z: depth = near / view depth).
    near: f32,
    right: vec3<f32>,
    // 1 / (tan(vfov / 2) · aspect)
    sx: f32,
    up: vec3<f32>,
    // 1 / tan(vfov / 2)
    sy: f32,
    forward: vec3<f32>,
    _pad: f32,
}

@group(0) @binding(0) var<uniform> cam: Camera;
@group(0) @binding(1) var<storage, read> scene_tris: array<Triangle>;
@group(0) @binding(2) var<storage, read> scene_info: array<TriangleInfo>;

struct VsOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) @interpolate(flat) tri: u32,
}

@vertex
fn vs(@builtin(vertex_index) vi: u32) -> VsOut {
    let tri = vi / 3u;
    let t = scene_tris[tri];
    var p = t.v0.xyz;
    if (vi % 3u == 1u) {
        p = t.v1.xyz;
    } else if (vi % 3u == 2u) {
        p = t.v2.xyz;
    }
    let rel = p - cam.eye;
    let x = dot(rel, cam.right);
    let y = dot(rel, cam.up);
    let z = dot(rel, cam.forward);
    var out: VsOut;
    out.tri = tri;
    if (scene_info[tri].degenerate != 0u) {
        // All three corners at one point: no fragment.
        out.clip = vec4<f32>(2.0, 2.0, 2.0, 1.0);
    } else {
        out.clip = vec4<f32>(x * cam.sx, y * cam.sy, cam.near, z);
    }
    return out;
}

@fragment
fn fs(in: VsOut) -> @location(0) u32 {
    return in.tri;
}
