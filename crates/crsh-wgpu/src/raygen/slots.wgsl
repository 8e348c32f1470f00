// The two passes every ray generator runs over its slots (see slots.rs), and the bindings
// they share. Appended after the generator's kernel, which declares its parameter block `p`
// (binding 0; fields `count`, `per_surface`, `out_first`, `out_count` among them) and
//   slot_of(j) -> vec3<u32>: (surface, slot within the surface, global slot index) of the
//                            chunk's slot j;
//   make(surface, k) -> Made: the ray of slot k of that surface, if it makes one.
// The generator's kernel is composed with kernels/origin_offset.wgsl, whose table this file
// binds (7-9).

@group(0) @binding(1) var<storage, read> surfaces: array<Surface>;
// Binding 2: the scene's lights (declared by the generators that use them).
@group(0) @binding(3) var<storage, read> materials: array<Material>;
// count: 1 per kept slot; emit: the exclusive scan of those flags (output positions).
@group(0) @binding(4) var<storage, read_write> slots: array<u32>;
@group(0) @binding(5) var<storage, read_write> rays_out: array<Ray>;
// [0] bad material (0xffffffff - pixel), [1] the generator's own, [2] rays an origin offset
// ended (count).
@group(0) @binding(6) var<storage, read_write> report: array<atomic<u32>>;
// The hemisphere set (crate::raygen::offsets): parameters, records then normals, polygon index.
@group(0) @binding(7) var<uniform> hemi: HemiParams;
@group(0) @binding(8) var<storage, read> hemi_table: array<vec4<f32>>;
@group(0) @binding(9) var<storage, read> hemi_index: array<u32>;

struct Made {
    ok: bool,
    ray: Ray,
}

@compute @workgroup_size(WG)
fn count(@builtin(global_invocation_id) gid: vec3<u32>,
         @builtin(num_workgroups) nwg: vec3<u32>) {
    let j = linear_id(gid, nwg);
    if (j >= p.count * p.per_surface) {
        return;
    }
    let sl = slot_of(j);
    let made = make(sl.x, sl.y);
    slots[sl.z] = select(0u, 1u, made.ok);
    if (made.ok && offset_ended(made.ray.t_min, made.ray.t_max)) {
        atomicAdd(&report[2], 1u);
    }
}

@compute @workgroup_size(WG)
fn emit(@builtin(global_invocation_id) gid: vec3<u32>,
        @builtin(num_workgroups) nwg: vec3<u32>) {
    let j = linear_id(gid, nwg);
    if (j >= p.count * p.per_surface) {
        return;
    }
    let sl = slot_of(j);
    let at = slots[sl.z];
    if (at < p.out_first || at - p.out_first >= p.out_count) {
        return;
    }
    let made = make(sl.x, sl.y);
    if (made.ok) {
        rays_out[at - p.out_first] = made.ray;
    }
}
