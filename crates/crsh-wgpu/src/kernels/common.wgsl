// Records shared by every crsh kernel; `Kernel::new` prepends this file to each kernel's source.
// Each struct mirrors a `#[repr(C)]` Rust type byte for byte (tests in kernel.rs and scene.rs
// check the sizes); vec3 fields are spelled as scalars where WGSL's vec3 alignment (16) would
// differ from the Rust layout.

// Workgroup size of 1D kernels. Dispatches wider than the adapter's per-dimension limit fold
// into a 2D grid; `linear_id` recovers the flat invocation index.
const WG: u32 = 256u;
const NO_HIT: u32 = 0xffffffffu;
// +infinity (WGSL constants cannot be infinite; Hit::MISS.t and unbounded t_max are).
fn inf() -> f32 { return bitcast<f32>(0x7f800000u); }

// Flat invocation index of a (possibly 2D) dispatch of WG-wide workgroups.
fn linear_id(gid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return gid.x + gid.y * nwg.x * WG;
}

// crsh_core::Ray (64 bytes).
struct Ray {
    ox: f32, oy: f32, oz: f32,
    t_min: f32,
    dx: f32, dy: f32, dz: f32,
    t_max: f32,
    tr: f32, tg: f32, tb: f32,
    kind: u32,
    pixel: u32,
    light: u32,
    depth: u32,
    source: u32,
}

fn ray_origin(r: Ray) -> vec3<f32> { return vec3<f32>(r.ox, r.oy, r.oz); }
fn ray_dir(r: Ray) -> vec3<f32> { return vec3<f32>(r.dx, r.dy, r.dz); }
fn ray_throughput(r: Ray) -> vec3<f32> { return vec3<f32>(r.tr, r.tg, r.tb); }

// crsh_core::Hit (16 bytes).
struct Hit {
    t: f32,
    tri: u32,
    u: f32,
    v: f32,
}

// crsh_core::Surface (80 bytes): vec3 + u32 rows, so vec3<f32> at 16-byte alignment matches.
struct Surface {
    position: vec3<f32>,
    tri: u32,
    normal: vec3<f32>,
    material: u32,
    incident: vec3<f32>,
    pixel: u32,
    throughput: vec3<f32>,
    depth: u32,
    geo_normal: vec3<f32>,
    flags: u32,
}

// crsh_core::SphereCone (32 bytes): the sphere bounding the origins (centre, radius) and the
// cone bounding the directions (unit axis, half-angle in radians).
struct SphereCone {
    center: vec3<f32>,
    radius: f32,
    axis: vec3<f32>,
    half_angle: f32,
}

// crsh_core::Candidate (8 bytes).
struct Candidate {
    node: u32,
    tri: u32,
}

// crate::scene::GpuTriangle (48 bytes): the three vertices, w = 0.
struct Triangle {
    v0: vec4<f32>,
    v1: vec4<f32>,
    v2: vec4<f32>,
}

// crate::scene::GpuTriangleInfo (16 bytes).
struct TriangleInfo {
    mesh: u32,
    material: u32,
    // 1 when crsh_scene::Scene::is_degenerate says so.
    degenerate: u32,
    _pad: u32,
}

// crate::scene::GpuMesh (48 bytes).
struct Mesh {
    sphere: vec4<f32>,
    aabb_min: vec4<f32>,
    aabb_max: vec4<f32>,
    // (first_tri, tri_count) in the first two lanes of a vec4<u32> would misalign; they live
    // in aabb_min.w / aabb_max.w as bit patterns: use mesh_first_tri / mesh_tri_count.
}

fn mesh_first_tri(m: Mesh) -> u32 { return bitcast<u32>(m.aabb_min.w); }
fn mesh_tri_count(m: Mesh) -> u32 { return bitcast<u32>(m.aabb_max.w); }

// crate::scene::GpuMaterial (64 bytes).
struct Material {
    diffuse: vec3<f32>,
    shininess: f32,
    specular: vec3<f32>,
    reflectivity: f32,
    emission: vec3<f32>,
    transparency: f32,
    ior: f32,
    _pad0: f32,
    _pad1: f32,
    _pad2: f32,
}

// crate::scene::GpuLight (48 bytes).
struct Light {
    position: vec3<f32>,
    intensity: f32,
    color: vec3<f32>,
    _pad0: f32,
    attenuation: vec3<f32>,
    _pad1: f32,
}

// crate::kernels::accumulate::Contribution (32 bytes): what one record adds to its pixel in
// the ordered accumulation (kernels/accumulate.wgsl). `pixel` out of the image: nothing.
struct Contribution {
    r: f32,
    g: f32,
    b: f32,
    pixel: u32,
    // ACC_ADD: add (r, g, b); ACC_ALPHA: set alpha to 1.
    flags: u32,
    _a: u32,
    _b: u32,
    _c: u32,
}

const ACC_ADD: u32 = 1u;
const ACC_ALPHA: u32 = 2u;
