// The five build passes of seed 002 §3.2 on the device, the twin of
// crsh_cpu::intersect::grid (count_pass, write_pairs_pass, sort_pass's gather, ranges_pass;
// the scan and the radix sort are the project's own kernels). See grid.rs.

struct BuildParams {
    n: u32,
    total: u32,
    n_cells: u32,
    margin: f32,
    dims: vec4<u32>,
}

@group(0) @binding(0) var<uniform> p: BuildParams;
// count: GpuTriangle (v0, v1, v2 as vec4).
@group(0) @binding(1) var<storage, read> verts: array<vec4<f32>>;
// count: 1 where the triangle is binned.
@group(0) @binding(2) var<storage, read> hittable: array<u32>;
// Cell planes: dims.x + 1 for x, then y, then z.
@group(0) @binding(3) var<storage, read> planes: array<f32>;
// write_pairs*: the scan (n + 1); gather: the order.
@group(0) @binding(4) var<storage, read> in0: array<u32>;
// write_pairs: the cell boxes (6 per primitive); write_pairs_listed: the listed cells in
// primitive order; gather: pair primitives; ranges: sorted cells.
@group(0) @binding(5) var<storage, read> in1: array<u32>;
@group(0) @binding(6) var<storage, read_write> out0: array<u32>;
@group(0) @binding(7) var<storage, read_write> out1: array<u32>;
@group(0) @binding(8) var<storage, read_write> out2: array<u32>;

fn plane_base(a: u32) -> u32 {
    if (a == 0u) { return 0u; }
    if (a == 1u) { return p.dims.x + 1u; }
    return p.dims.x + p.dims.y + 2u;
}

// GridGeometry::axis_cell: interior planes at or below x.
fn axis_cell(a: u32, x: f32) -> u32 {
    let base = plane_base(a);
    var lo = 1u;
    var hi = p.dims[a];
    while (lo < hi) {
        let mid = lo + (hi - lo) / 2u;
        if (planes[base + mid] <= x) { lo = mid + 1u; } else { hi = mid; }
    }
    return lo - 1u;
}

// Pass 1 (§3.2.1): cells of each triangle's widened box; out0 = counts, out1 = boxes.
@compute @workgroup_size(WG)
fn count(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let t = linear_id(gid, nwg);
    if (t >= p.n) { return; }
    var lo = vec3<u32>(1u);
    var hi = vec3<u32>(0u);
    var c = 0u;
    if (hittable[t] != 0u) {
        let a = verts[3u * t].xyz;
        let b = verts[3u * t + 1u].xyz;
        let d = verts[3u * t + 2u].xyz;
        let bmin = min(min(a, b), d);
        let bmax = max(max(a, b), d);
        for (var k = 0u; k < 3u; k++) {
            lo[k] = axis_cell(k, bmin[k] - p.margin);
            hi[k] = axis_cell(k, bmax[k] + p.margin);
        }
        c = (hi.x + 1u - lo.x) * (hi.y + 1u - lo.y) * (hi.z + 1u - lo.z);
    }
    out0[t] = c;
    for (var k = 0u; k < 3u; k++) {
        out1[6u * t + k] = lo[k];
        out1[6u * t + 3u + k] = hi[k];
    }
}

// slot_primitive: the last p with scan[p] <= slot.
fn slot_primitive(slot: u32) -> u32 {
    var lo = 0u;
    var hi = p.n + 1u;
    while (lo < hi) {
        let mid = lo + (hi - lo) / 2u;
        if (in0[mid] <= slot) { lo = mid + 1u; } else { hi = mid; }
    }
    return lo - 1u;
}

// Pass 3 (§3.2.3), one invocation per output slot: out0 = u64 keys (cell, 0), out1 = prims.
@compute @workgroup_size(WG)
fn write_pairs(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let s = linear_id(gid, nwg);
    if (s >= p.total) { return; }
    let q = slot_primitive(s);
    let n = s - in0[q];
    let lx = in1[6u * q];
    let ly = in1[6u * q + 1u];
    let lz = in1[6u * q + 2u];
    let wx = in1[6u * q + 3u] + 1u - lx;
    let wy = in1[6u * q + 4u] + 1u - ly;
    let x = lx + n % wx;
    let y = ly + (n / wx) % wy;
    let z = lz + n / (wx * wy);
    out0[2u * s] = x + p.dims.x * (y + p.dims.y * z);
    out0[2u * s + 1u] = 0u;
    out1[s] = q;
}

// Pass 3 on explicit overlap lists (seed 002 fig. 5): the n-th listed cell of the primitive.
@compute @workgroup_size(WG)
fn write_pairs_listed(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let s = linear_id(gid, nwg);
    if (s >= p.total) { return; }
    let q = slot_primitive(s);
    out0[2u * s] = in1[in0[q] + (s - in0[q])];
    out0[2u * s + 1u] = 0u;
    out1[s] = q;
}

// Pass 4's gather after the radix order: in0 = order, in1 = pair prims, out0 = keys (read),
// out1 = sorted cells, out2 = sorted prims.
@compute @workgroup_size(WG)
fn gather(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= p.total) { return; }
    let j = in0[i];
    out1[i] = out0[2u * j];
    out2[i] = in1[j];
}

// Pass 5 (§3.2.5), one invocation per cell: (start, count) by binary search; (0, 0) if empty.
@compute @workgroup_size(WG)
fn ranges(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let c = linear_id(gid, nwg);
    if (c >= p.n_cells) { return; }
    var lo = 0u;
    var hi = p.total;
    while (lo < hi) {
        let mid = lo + (hi - lo) / 2u;
        if (in1[mid] < c) { lo = mid + 1u; } else { hi = mid; }
    }
    let start = lo;
    hi = p.total;
    while (lo < hi) {
        let mid = lo + (hi - lo) / 2u;
        if (in1[mid] <= c) { lo = mid + 1u; } else { hi = mid; }
    }
    if (lo > start) {
        out0[2u * c] = start;
        out0[2u * c + 1u] = lo - start;
    } else {
        out0[2u * c] = 0u;
        out0[2u * c + 1u] = 0u;
    }
}
