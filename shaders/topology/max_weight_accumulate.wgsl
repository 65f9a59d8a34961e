// Per triangle: the running maximum of the forward pass's max blending weight over the views
// rendered since the last reset (topology strategy). Weights are >= 0, so the maximum of
// their f32 bit patterns as u32 is the maximum of the floats.
#import dispatch

struct AccParams {
    num_triangles: u32,
    reset: u32,            // 1: acc = weights (first view after a reset)
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<uniform> ap: AccParams;
@group(0) @binding(1) var<storage, read> weights: array<u32>;    // [M] f32 bits
@group(0) @binding(2) var<storage, read_write> acc: array<u32>;  // [M] f32 bits

@compute @workgroup_size(256)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let i = linear_group(wid, nwg) * 256u + li;
    if (i >= ap.num_triangles) {
        return;
    }
    let w = weights[i];
    if (ap.reset == 1u) {
        acc[i] = w;
    } else {
        acc[i] = max(acc[i], w);
    }
}
