// Evaluates rng.wgsl for a list of keys and normals, for the tests against crsh_core::rng (see
// rng.rs). Prepended: common.wgsl, glam.wgsl, trig.wgsl, rng.wgsl.

const PI: f32 = 3.14159265358979;

// crate::kernels::rng::RngQuery (48 bytes).
struct Query {
    key: vec4<u32>,
    normal: vec4<f32>,
    geo_normal: vec4<f32>,
}

// crate::kernels::rng::RngAnswer (64 bytes).
struct Answer {
    words: vec4<u32>,
    uniforms: vec4<f32>,
    cosine: vec4<f32>,
    front: vec4<f32>,
}

struct Params {
    n: u32,
    _a: u32,
    _b: u32,
    _c: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> queries: array<Query>;
@group(0) @binding(2) var<storage, read_write> answers: array<Answer>;

@compute @workgroup_size(WG)
fn probe(@builtin(global_invocation_id) gid: vec3<u32>,
         @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= p.n) {
        return;
    }
    let q = queries[i];
    let w = pcg4d(q.key);
    let u = rng_uniforms2(q.key.x, q.key.y, q.key.z, q.key.w);
    var a: Answer;
    a.words = w;
    a.uniforms = vec4<f32>(u, rng_unit(w.z), rng_unit(w.w));
    a.cosine = vec4<f32>(cosine_direction(q.normal.xyz, u), 0.0);
    a.front = vec4<f32>(front_cosine_direction(q.normal.xyz, q.geo_normal.xyz, u), 0.0);
    answers[i] = a;
}
