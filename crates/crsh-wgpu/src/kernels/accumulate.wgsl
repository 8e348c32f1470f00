// Ordered accumulation of per-record contributions into an image (see accumulate.rs).
// Prepended: common.wgsl.

struct Params {
    // Records, image pixels, and the report slot that receives the most runs of one pixel.
    n: u32,
    n_pixels: u32,
    report_slot: u32,
    _a: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read_write> contrib: array<Contribution>;
// Per pixel: runs seen (count_heads), then the lowest run head not yet applied (elect / apply).
@group(0) @binding(2) var<storage, read_write> heads: array<atomic<u32>>;
@group(0) @binding(3) var<storage, read_write> image: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> report: array<atomic<u32>>;

// Set on a run head once its run is in the image.
const ACC_DONE: u32 = 0x80000000u;

// The pixel of record i if it starts a run (a maximal sequence of consecutive records of one
// pixel), else NO_HIT.
fn run_pixel(i: u32) -> u32 {
    let px = contrib[i].pixel;
    if (px >= p.n_pixels || (i > 0u && contrib[i - 1u].pixel == px)) {
        return NO_HIT;
    }
    return px;
}

// Counts the runs of every pixel: the rounds `elect` / `apply` need.
@compute @workgroup_size(WG)
fn count_heads(@builtin(global_invocation_id) gid: vec3<u32>,
               @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= p.n) {
        return;
    }
    let px = run_pixel(i);
    if (px != NO_HIT) {
        let seen = atomicAdd(&heads[px], 1u) + 1u;
        atomicMax(&report[p.report_slot], seen);
    }
}

// Resets `heads` to "no run elected".
@compute @workgroup_size(WG)
fn reset_heads(@builtin(global_invocation_id) gid: vec3<u32>,
               @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i < p.n_pixels) {
        atomicStore(&heads[i], NO_HIT);
    }
}

// One round: every run not yet applied elects itself for its pixel (the lowest head wins) ...
@compute @workgroup_size(WG)
fn elect(@builtin(global_invocation_id) gid: vec3<u32>,
         @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= p.n) {
        return;
    }
    let px = run_pixel(i);
    if (px != NO_HIT && (contrib[i].flags & ACC_DONE) == 0u) {
        atomicMin(&heads[px], i);
    }
}

// ... and each winner adds its run to the pixel record by record: every pixel sums its records
// in record order, as the CPU does, whatever the scheduling.
@compute @workgroup_size(WG)
fn apply(@builtin(global_invocation_id) gid: vec3<u32>,
         @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg);
    if (i >= p.n) {
        return;
    }
    let px = run_pixel(i);
    if (px == NO_HIT || (contrib[i].flags & ACC_DONE) != 0u || atomicLoad(&heads[px]) != i) {
        return;
    }
    var v = image[px];
    for (var k = i; k < p.n; k++) {
        let c = contrib[k];
        if (c.pixel != px) {
            break;
        }
        if ((c.flags & ACC_ADD) != 0u) {
            v = vec4<f32>(v.x + c.r, v.y + c.g, v.z + c.b, v.w);
        }
        if ((c.flags & ACC_ALPHA) != 0u) {
            v.w = 1.0;
        }
    }
    image[px] = v;
    contrib[i].flags |= ACC_DONE;
    atomicStore(&heads[px], NO_HIT);
}
