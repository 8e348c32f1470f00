// `compress` on the device: compression / decompression around the chunk radix sort, the
// twin of crsh_cpu::sort::compress (see compress.rs). Prepended: common.wgsl.

struct Params {
    // Keys (rays), and chunks.
    n: u32,
    chunks: u32,
    _a: u32,
    _b: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> keys: array<vec2<u32>>;
// Head flags, scanned in place into chunk indices.
@group(0) @binding(2) var<storage, read_write> heads: array<u32>;
@group(0) @binding(3) var<storage, read_write> base: array<u32>;
@group(0) @binding(4) var<storage, read_write> chunk_keys: array<vec2<u32>>;
@group(0) @binding(5) var<storage, read_write> size: array<u32>;
@group(0) @binding(6) var<storage, read> sorted: array<u32>;
// The skeleton (sorted chunk sizes), scanned in place into output positions.
@group(0) @binding(7) var<storage, read_write> skeleton: array<u32>;
@group(0) @binding(8) var<storage, read_write> order: array<u32>;

fn is_head(i: u32) -> bool {
    return i == 0u || any(keys[i] != keys[i - 1u]);
}

// §3.2.4: 1 where a run of equal keys starts.
@compute @workgroup_size(WG)
fn flag_heads(@builtin(global_invocation_id) gid: vec3<u32>,
              @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i < p.n) {
        heads[i] = select(0u, 1u, is_head(i));
    }
}

// Each head writes its chunk (the scanned flags number them): first ray and key.
@compute @workgroup_size(WG)
fn write_chunks(@builtin(global_invocation_id) gid: vec3<u32>,
                @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i < p.n && is_head(i)) {
        let c = heads[i];
        base[c] = i;
        chunk_keys[c] = keys[i];
    }
}

@compute @workgroup_size(WG)
fn chunk_sizes(@builtin(global_invocation_id) gid: vec3<u32>,
               @builtin(num_workgroups) nwg: vec3<u32>) {
    let c = linear_id(gid, nwg);
    if (c >= p.chunks) {
        return;
    }
    var next = p.n;
    if (c + 1u < p.chunks) {
        next = base[c + 1u];
    }
    size[c] = next - base[c];
}

// §3.2.6: the skeleton, the sorted chunks' sizes.
@compute @workgroup_size(WG)
fn skeleton_sizes(@builtin(global_invocation_id) gid: vec3<u32>,
                  @builtin(num_workgroups) nwg: vec3<u32>) {
    let j = linear_id(gid, nwg);
    if (j < p.chunks) {
        skeleton[j] = size[sorted[j]];
    }
}

// Output position q belongs to the last sorted chunk whose position is <= q (sizes are >= 1).
@compute @workgroup_size(WG)
fn expand(@builtin(global_invocation_id) gid: vec3<u32>,
          @builtin(num_workgroups) nwg: vec3<u32>) {
    let q = linear_id(gid, nwg);
    if (q >= p.n) {
        return;
    }
    var lo = 0u;
    var hi = p.chunks;
    while (lo < hi) {
        let mid = lo + (hi - lo) / 2u;
        if (skeleton[mid] <= q) { lo = mid + 1u; } else { hi = mid; }
    }
    let j = lo - 1u;
    order[q] = base[sorted[j]] + (q - skeleton[j]);
}
