// The render pass of `raster`: every triangle drawn with the camera of the CPU rasterizer,
// writing the triangle id (a visibility buffer). The depth tested is the CPU rasterizer's own:
// the distance `t` along the pixel-centre camera ray to the triangle's plane (the solve of
// the resolve pass), times a power of two, so exact, written as the fragment depth. `Less`
// keeps the nearer fragment, and among equal depths the first drawn, i.e. the lower triangle
// id (primitives are processed in order): `Hit::closer_than`, on any backend, whatever its
// clip-space depth range. Prepended: common.wgsl, mt.wgsl, glam.wgsl, camera_ray.wgsl.

struct Camera {
    view: View,
    // Near plane distance: clip z = near, clip w = view depth, so clipping keeps w >= near.
    near: f32,
    // 1 / (tan(vfov / 2) · aspect)
    sx: f32,
    // 1 / tan(vfov / 2)
    sy: f32,
    // A power of two below 1 / (every visible t): depth = t · depth_scale, exact and in (0, 1).
    depth_scale: f32,
}

@group(0) @binding(0) var<uniform> cam: Camera;
@group(0) @binding(1) var<storage, read> scene_tris: array<Triangle>;
@group(0) @binding(2) var<storage, read> scene_info: array<TriangleInfo>;
@group(0) @binding(3) var<storage, read> prepared: array<MtTri>;
// Unused here (mt.wgsl's counter helper names it).
@group(0) @binding(4) var<storage, read_write> counters: array<atomic<u32>>;

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
    let rel = p - cam.view.eye;
    let x = dot(rel, cam.view.right);
    let y = dot(rel, cam.view.up);
    let z = dot(rel, cam.view.forward);
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

struct FsOut {
    @location(0) tri: u32,
    @builtin(frag_depth) depth: f32,
}

@fragment
fn fs(in: VsOut) -> FsOut {
    // Without multisampling the fragment position is the pixel centre.
    let x = u32(in.clip.x);
    let y = u32(in.clip.y);
    let h = pixel_plane_hit(prepared[in.tri], cam.view.eye, camera_dir(cam.view, x, y));
    if (h.x < 0.0) {
        discard;
    }
    var out: FsOut;
    out.tri = in.tri;
    out.depth = min(h.x * cam.depth_scale, 1.0);
    return out;
}
