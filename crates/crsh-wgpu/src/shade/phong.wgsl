// `phong` on the device: the twin of crsh_cpu::shade::phong (see phong.rs).
// Prepended: common.wgsl, glam.wgsl, surface.wgsl.

struct Params {
    // Records (surfaces, or rays for `resolve`), lights, pixels, materials, triangles.
    n: u32,
    n_lights: u32,
    n_pixels: u32,
    n_materials: u32,
    n_tris: u32,
    // Shadow rays (visibility pass).
    n_shadow: u32,
    ambient: f32,
    background: f32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> surfaces: array<Surface>;
@group(0) @binding(2) var<storage, read> shadow_rays: array<Ray>;
@group(0) @binding(3) var<storage, read> shadow_hits: array<Hit>;
@group(0) @binding(4) var<storage, read> materials: array<Material>;
@group(0) @binding(5) var<storage, read> lights: array<Light>;
// surfaces × lights visibility flags; then per record its contribution (xyz, w = 1).
@group(0) @binding(6) var<storage, read_write> visible: array<u32>;
@group(0) @binding(7) var<storage, read_write> contrib: array<vec4<f32>>;
// Per pixel: records seen (count pass), the lowest unapplied record (elect / apply).
@group(0) @binding(8) var<storage, read_write> per_pixel: array<atomic<u32>>;
@group(0) @binding(9) var<storage, read_write> image: array<vec4<f32>>;
// [0] bad record (0xffffffff - index), [1] most records on one pixel, [2] bad shadow ray.
@group(0) @binding(10) var<storage, read_write> report: array<atomic<u32>>;
@group(0) @binding(11) var<storage, read> scene_tris: array<Triangle>;
@group(0) @binding(12) var<storage, read> scene_normals: array<Triangle>;
@group(0) @binding(13) var<storage, read> scene_info: array<TriangleInfo>;
@group(0) @binding(14) var<storage, read_write> resolved: array<Surface>;
// resolve: the rays and their hits.
@group(0) @binding(15) var<storage, read> rays: array<Ray>;
@group(0) @binding(16) var<storage, read> hits: array<Hit>;

// An unoccluded shadow ray makes its light visible from its source surface.
@compute @workgroup_size(WG)
fn visibility(@builtin(global_invocation_id) gid: vec3<u32>,
              @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= p.n_shadow) {
        return;
    }
    let r = shadow_rays[i];
    if (r.source >= p.n || r.light >= p.n_lights) {
        atomicMax(&report[2], 0xffffffffu - i);
        return;
    }
    if (shadow_hits[i].tri == NO_HIT) {
        visible[r.source * p.n_lights + r.light] = 1u;
    }
}

// Rust's f32::powf for the specular term's x >= 0.
fn powf(x: f32, y: f32) -> f32 {
    if (y == 0.0) {
        return 1.0;
    }
    if (x == 0.0) {
        return select(inf(), 0.0, y > 0.0);
    }
    return pow(x, y);
}

fn attenuation(c: vec3<f32>, d: f32) -> f32 {
    let a = 1.0 / (c.x + d * c.y + d * d * c.z);
    return select(0.0, a, g_finite(a));
}

// eq. 3.19a-i for one light.
fn light_term(s: Surface, m: Material, l: Light) -> vec3<f32> {
    let to_light = l.position - s.position;
    let dist = g_length(to_light);
    if (dist <= 0.0 || !g_finite(dist)) {
        return vec3<f32>(0.0);
    }
    let ldir = to_light / dist;
    if (g_dot(ldir, s.geo_normal) <= 0.0) {
        return vec3<f32>(0.0);
    }
    let att = attenuation(l.attenuation, dist);
    let fd = clamp(g_dot(ldir, s.normal), 0.0, 1.0);
    var fs = 0.0;
    if (fd > 0.0) {
        let h = g_normalize_or_zero(ldir - s.incident);
        fs = clamp(powf(max(g_dot(h, s.normal), 0.0), m.shininess), 0.0, 1.0);
    }
    let radiance = l.color * l.intensity;
    return (m.diffuse * fd + m.specular * fs) * radiance * att;
}

// Per record: its contribution, and a count of the records of its pixel.
@compute @workgroup_size(WG)
fn contribution(@builtin(global_invocation_id) gid: vec3<u32>,
                @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= p.n) {
        return;
    }
    let s = surfaces[i];
    if (s.pixel >= p.n_pixels || (s.tri != NO_HIT && s.material >= p.n_materials)) {
        atomicMax(&report[0], 0xffffffffu - i);
        return;
    }
    let seen = atomicAdd(&per_pixel[s.pixel], 1u) + 1u;
    atomicMax(&report[1], seen);
    var c = s.throughput * p.background;
    if (s.tri != NO_HIT) {
        let m = materials[s.material];
        let emitted = m.emission * s.throughput;
        let local_weight = max(1.0 - m.reflectivity - m.transparency, 0.0);
        if (local_weight <= 0.0) {
            c = emitted;
        } else {
            var color = m.diffuse * p.ambient;
            for (var li = 0u; li < p.n_lights; li++) {
                if (visible[i * p.n_lights + li] != 0u) {
                    color += light_term(s, m, lights[li]);
                }
            }
            c = emitted + color * local_weight * s.throughput;
        }
    }
    contrib[i] = vec4<f32>(c, 1.0);
}

// Resets per_pixel to "no record elected".
@compute @workgroup_size(WG)
fn reset_heads(@builtin(global_invocation_id) gid: vec3<u32>,
               @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i < p.n_pixels) {
        atomicStore(&per_pixel[i], 0xffffffffu);
    }
}

// One round of the ordered accumulation: every record not yet added elects itself for its
// pixel (the lowest index wins) ...
@compute @workgroup_size(WG)
fn elect(@builtin(global_invocation_id) gid: vec3<u32>,
         @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= p.n || contrib[i].w == 0.0) {
        return;
    }
    atomicMin(&per_pixel[surfaces[i].pixel], i);
}

// ... and the winners add their contribution: so each pixel sums its records in record order,
// as the CPU does, whatever the scheduling.
@compute @workgroup_size(WG)
fn apply(@builtin(global_invocation_id) gid: vec3<u32>,
         @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= p.n || contrib[i].w == 0.0) {
        return;
    }
    let px = surfaces[i].pixel;
    if (atomicLoad(&per_pixel[px]) != i) {
        return;
    }
    let c = contrib[i];
    var v = image[px];
    v = vec4<f32>(v.x + c.x, v.y + c.y, v.z + c.z, 1.0);
    image[px] = v;
    contrib[i] = vec4<f32>(0.0);
    atomicStore(&per_pixel[px], 0xffffffffu);
}

// The next path vertex of every reflection / refraction ray.
@compute @workgroup_size(WG)
fn resolve(@builtin(global_invocation_id) gid: vec3<u32>,
           @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= p.n) {
        return;
    }
    let r = rays[i];
    let h = hits[i];
    if (h.tri != NO_HIT && h.tri >= p.n_tris) {
        atomicMax(&report[0], 0xffffffffu - i);
    }
    resolved[i] = surface_from_hit(ray_dir(r), h, r.pixel, ray_throughput(r), r.depth, p.n_tris);
}
