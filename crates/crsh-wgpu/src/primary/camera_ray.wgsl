// The pixel-centre camera ray of both raster passes: crsh_scene::Camera::direction with glam's
// operations (the twin of crsh_cpu::primary::raycast::camera_ray). Needs glam.wgsl.

struct View {
    right: vec3<f32>,
    // tan(vfov / 2)
    tan_half: f32,
    up: vec3<f32>,
    // width / height
    aspect: f32,
    forward: vec3<f32>,
    width: u32,
    eye: vec3<f32>,
    height: u32,
}

fn camera_dir(v: View, x: u32, y: u32) -> vec3<f32> {
    let sx = f32(x) + 0.5;
    let sy = f32(y) + 0.5;
    let ndc_x = (2.0 * sx / f32(v.width) - 1.0) * v.tan_half * v.aspect;
    let ndc_y = (1.0 - 2.0 * sy / f32(v.height)) * v.tan_half;
    let d = v.forward + v.right * ndc_x + v.up * ndc_y;
    return d * (1.0 / g_length(d));
}

// The plane hit `(t, u, v)` of the pixel-centre ray with a prepared triangle, as
// crsh_cpu::triangle::PreparedTriangle::plane_hit, then kept only with `t` in (0, inf) as the
// CPU rasterizer keeps a fragment; `t` = -1 when there is none.
fn pixel_plane_hit(tri: MtTri, o: vec3<f32>, dir: vec3<f32>) -> vec3<f32> {
    let r = mt_lane(tri, o, dir, ray_dir_len(dir));
    let ok = r.x > 0.5 && f32_finite(r.y) && f32_finite(r.z) && f32_finite(r.w) && r.y > 0.0;
    return select(vec3<f32>(-1.0, 0.0, 0.0), r.yzw, ok);
}
