// `phong` (and `diffuse`'s Lambertian model) on the device: the twin of crsh_cpu::shade::phong
// (see phong.rs). Prepended: common.wgsl, glam.wgsl, surface.wgsl.

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
    // 1: Model::Lambert (diffuse / π, no specular, no ambient, every material opaque), and
    // `resolve` keeps a diffuse ray's sample index in the vertex (the `diffuse` shader).
    lambert: u32,
    _a: u32,
    _b: u32,
    _c: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> surfaces: array<Surface>;
@group(0) @binding(2) var<storage, read> shadow_rays: array<Ray>;
@group(0) @binding(3) var<storage, read> shadow_hits: array<Hit>;
@group(0) @binding(4) var<storage, read> materials: array<Material>;
@group(0) @binding(5) var<storage, read> lights: array<Light>;
// surfaces × lights visibility flags; then per record its contribution (kernels/accumulate).
@group(0) @binding(6) var<storage, read_write> visible: array<u32>;
@group(0) @binding(7) var<storage, read_write> contrib: array<Contribution>;
// [0] bad record (0xffffffff - index), [1] rounds of the accumulation, [2] bad shadow ray.
@group(0) @binding(8) var<storage, read_write> report: array<atomic<u32>>;
@group(0) @binding(9) var<storage, read> scene_tris: array<Triangle>;
@group(0) @binding(10) var<storage, read> scene_normals: array<Triangle>;
@group(0) @binding(11) var<storage, read> scene_info: array<TriangleInfo>;
@group(0) @binding(12) var<storage, read_write> resolved: array<Surface>;
// resolve: the rays and their hits.
@group(0) @binding(13) var<storage, read> rays: array<Ray>;
@group(0) @binding(14) var<storage, read> hits: array<Hit>;

const FRAC_1_PI: f32 = 0.3183098861837907;
const KIND_DIFFUSE: u32 = 5u;
const SAMPLE_SHIFT: u32 = 8u;

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

// eq. 3.19a-i for one light, with the material's `diffuse` and `specular` colours.
fn light_term(s: Surface, diffuse: vec3<f32>, specular: vec3<f32>, shininess: f32,
              l: Light) -> vec3<f32> {
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
        fs = clamp(powf(max(g_dot(h, s.normal), 0.0), shininess), 0.0, 1.0);
    }
    let radiance = l.color * l.intensity;
    return (diffuse * fd + specular * fs) * radiance * att;
}

// The sum of light_term over the lights visible from record i.
fn direct(i: u32, s: Surface, diffuse: vec3<f32>, specular: vec3<f32>, shininess: f32,
          start: vec3<f32>) -> vec3<f32> {
    var color = start;
    for (var li = 0u; li < p.n_lights; li++) {
        if (visible[i * p.n_lights + li] != 0u) {
            color += light_term(s, diffuse, specular, shininess, lights[li]);
        }
    }
    return color;
}

// Per record: its contribution to its pixel.
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
        contrib[i].pixel = NO_HIT;
        return;
    }
    var c = s.throughput * p.background;
    if (s.tri != NO_HIT) {
        let m = materials[s.material];
        let emitted = m.emission * s.throughput;
        let local_weight = max(1.0 - m.reflectivity - m.transparency, 0.0);
        if (p.lambert != 0u) {
            let color = direct(i, s, m.diffuse * FRAC_1_PI, vec3<f32>(0.0), m.shininess,
                               vec3<f32>(0.0));
            c = emitted + color * s.throughput;
        } else if (local_weight <= 0.0) {
            c = emitted;
        } else {
            let color = direct(i, s, m.diffuse, m.specular, m.shininess, m.diffuse * p.ambient);
            c = emitted + color * local_weight * s.throughput;
        }
    }
    contrib[i] = Contribution(c.x, c.y, c.z, s.pixel, ACC_ADD | ACC_ALPHA, 0u, 0u, 0u);
}

// The next path vertex of every reflection / refraction (or diffuse) ray.
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
    var s = surface_from_hit(ray_dir(r), h, r.pixel, ray_throughput(r), r.depth, p.n_tris);
    if (p.lambert != 0u && r.kind == KIND_DIFFUSE) {
        s.flags |= r.light << SAMPLE_SHIFT;
    }
    resolved[i] = s;
}
