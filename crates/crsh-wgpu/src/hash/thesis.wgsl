// `thesis` hashing on the device: the twin of crsh_cpu::hash::thesis (thesis_shadow,
// thesis_bounce), bit for bit (seed 000 §3.2.3, figs 3.8-3.9). Prepended: common.wgsl,
// quantize.wgsl, spherical.wgsl.

struct Params {
    n: u32,
    n_lights: u32,
    // 1: interleave, 0: concat.
    interleave: u32,
    light_bits: u32,
    shadow_theta_bits: u32,
    shadow_phi_bits: u32,
    origin_bits: u32,
    bounce_theta_bits: u32,
    bounce_phi_bits: u32,
    first: u32,
    // Offsets of the boundary tables in dir_tables (quantize::theta_table / phi_table).
    shadow_theta_base: u32,
    shadow_phi_base: u32,
    bounce_theta_base: u32,
    bounce_phi_base: u32,
    _a: u32,
    _b: u32,
    // The origin cells per axis (quantize::UniformCells).
    lo: vec3<f32>,
    _c: f32,
    hi: vec3<f32>,
    _d: f32,
    scale: vec3<f32>,
    _e: f32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> rays: array<Ray>;
@group(0) @binding(2) var<storage, read> lights: array<Light>;
@group(0) @binding(3) var<storage, read_write> keys: array<vec2<u32>>;
// [bad ray report (0xffffffff - index)]
@group(0) @binding(4) var<storage, read_write> report: array<atomic<u32>>;
// The four boundary tables, concatenated.
@group(0) @binding(5) var<storage, read> dir_tables: array<f32>;

@compute @workgroup_size(WG)
fn hash(@builtin(global_invocation_id) gid: vec3<u32>,
        @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= p.n) {
        return;
    }
    let r = rays[i];
    var key = vec2<u32>(0u);
    if (r.kind == 1u) {
        // Shadow: light index, then the direction from the light to the point.
        if (r.light >= p.n_lights) {
            atomicMax(&report[0], 0xffffffffu - (p.first + i));
            return;
        }
        let lp = lights[r.light].position;
        let o = ray_origin(r);
        let d = ray_dir(r);
        // thesis_shadow::light_to_point_direction: every product by product_exact.
        let end = vec3<f32>(o.x + product_exact(d.x, r.t_max), o.y + product_exact(d.y, r.t_max),
                            o.z + product_exact(d.z, r.t_max));
        if (!all(abs(end) < vec3<f32>(inf()))) {
            atomicMax(&report[0], 0xffffffffu - (p.first + i));
            return;
        }
        let to_o = o - lp;
        let to_e = end - lp;
        let do2 = (square_exact(to_o.x) + square_exact(to_o.y)) + square_exact(to_o.z);
        let de2 = (square_exact(to_e.x) + square_exact(to_e.y)) + square_exact(to_e.z);
        var dir = d;
        if (!(do2 <= de2)) {
            dir = -d;
        }
        let c = spherical_cells(dir, p.shadow_theta_bits, p.shadow_phi_bits, p.shadow_theta_base,
                                p.shadow_phi_base);
        let dkey = combine(array<u32, 5>(c.x, c.y, 0u, 0u, 0u),
                           array<u32, 5>(p.shadow_theta_bits, p.shadow_phi_bits, 0u, 0u, 0u), 2u,
                           p.interleave != 0u);
        var light = r.light;
        if (p.light_bits < 32u) {
            light = min(light, (1u << p.light_bits) - 1u);
        }
        key = shl64(vec2<u32>(light, 0u), p.shadow_theta_bits + p.shadow_phi_bits) | dkey;
    } else if (r.kind <= 3u) {
        let o = ray_origin(r);
        let ob = p.origin_bits;
        let cx = uniform_cell(o.x, p.lo.x, p.hi.x, p.scale.x, ob);
        let cy = uniform_cell(o.y, p.lo.y, p.hi.y, p.scale.y, ob);
        let cz = uniform_cell(o.z, p.lo.z, p.hi.z, p.scale.z, ob);
        let okey = combine(array<u32, 5>(cx, cy, cz, 0u, 0u), array<u32, 5>(ob, ob, ob, 0u, 0u), 3u,
                           p.interleave != 0u);
        let c = spherical_cells(ray_dir(r), p.bounce_theta_bits, p.bounce_phi_bits,
                                p.bounce_theta_base, p.bounce_phi_base);
        let dkey = combine(array<u32, 5>(c.x, c.y, 0u, 0u, 0u),
                           array<u32, 5>(p.bounce_theta_bits, p.bounce_phi_bits, 0u, 0u, 0u), 2u,
                           p.interleave != 0u);
        key = shl64(okey, p.bounce_theta_bits + p.bounce_phi_bits) | dkey;
    } else {
        atomicMax(&report[0], 0xffffffffu - (p.first + i));
        return;
    }
    keys[i] = key;
}
