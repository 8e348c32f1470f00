// `morton` hashing on the device: the twin of crsh_cpu::hash::morton_octa, bit for bit (see
// morton_octa.rs). Prepended: common.wgsl, quantize.wgsl.

struct Params {
    n: u32,
    origin_bits: u32,
    u_bits: u32,
    v_bits: u32,
    // The origin cells per axis (quantize::UniformCells).
    lo: vec3<f32>,
    _a: f32,
    hi: vec3<f32>,
    _b: f32,
    scale: vec3<f32>,
    _c: f32,
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
    let o = ray_origin(r);
    let ob = p.origin_bits;
    let e = octahedral_cells(ray_dir(r), p.u_bits, p.v_bits);
    let vals = array<u32, 5>(
        uniform_cell(o.x, p.lo.x, p.hi.x, p.scale.x, ob),
        uniform_cell(o.y, p.lo.y, p.hi.y, p.scale.y, ob),
        uniform_cell(o.z, p.lo.z, p.hi.z, p.scale.z, ob),
        e.x,
        e.y);
    keys[i] = combine(vals, array<u32, 5>(ob, ob, ob, p.u_bits, p.v_bits), 5u, true);
}
