// crsh_cpu::surface::surface_from_hit, written with glam's operations in glam's order.
// Prepended: glam.wgsl. The including kernel declares `scene_tris: array<Triangle>`,
// `scene_normals: array<Triangle>` and `scene_info: array<TriangleInfo>` (GpuScene's
// `triangles`, `normals` and `info`).

fn background_surface(pixel: u32, incident: vec3<f32>, throughput: vec3<f32>, depth: u32) -> Surface {
    return Surface(vec3<f32>(0.0), NO_HIT, vec3<f32>(0.0), 0u, incident, pixel, throughput, depth,
                   vec3<f32>(0.0), 0u);
}

// The surface record of a hit (or a background record for a miss / an unknown triangle).
fn surface_from_hit(ray_dir: vec3<f32>, hit: Hit, pixel: u32, throughput: vec3<f32>, depth: u32,
                    n_tris: u32) -> Surface {
    let incident = g_normalize_or_zero(ray_dir);
    if (hit.tri == NO_HIT || hit.tri >= n_tris) {
        return background_surface(pixel, incident, throughput, depth);
    }
    let t = scene_tris[hit.tri];
    let a = t.v0.xyz;
    let b = t.v1.xyz;
    let c = t.v2.xyz;
    let u = hit.u;
    let v = hit.v;
    let w = 1.0 - u - v;
    let position = a * w + b * u + c * v;
    let face = g_cross(b - a, c - a);
    let front = g_dot(ray_dir, face) < 0.0;
    var geo = g_normalize_or_zero(face);
    if (!front) {
        geo = -geo;
    }
    let nn = scene_normals[hit.tri];
    let interpolated = nn.v0.xyz * w + nn.v1.xyz * u + nn.v2.xyz * v;
    var normal = g_normalize_or_zero(interpolated);
    if (g_is_zero(normal)) {
        normal = geo;
    } else if (g_dot(normal, geo) < 0.0) {
        normal = -normal;
    }
    return Surface(position, hit.tri, normal, scene_info[hit.tri].material, incident, pixel,
                   throughput, depth, geo, select(0u, 1u, front));
}
