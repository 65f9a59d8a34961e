// Segmented sum, up-sweep (common/segment.wgsl): per chunk of CHUNK elements, the sum of
// its leading run and that run's key, as one element of the next level.
#import dispatch
#import segment

@group(0) @binding(0) var<uniform> sp: SegParams;
@group(0) @binding(1) var<storage, read> keys_in: array<u32>;          // [n] sorted
@group(0) @binding(2) var<storage, read> index: array<u32>;            // [n] (level 0)
@group(0) @binding(3) var<storage, read> vals_in: array<vec4<f32>>;    // [*, width]
@group(0) @binding(4) var<storage, read_write> keys_out: array<u32>;   // [ceil(n / CHUNK)]
@group(0) @binding(5) var<storage, read_write> vals_out: array<vec4<f32>>;  // [ceil(n / CHUNK), width]

const WG: u32 = 256u;   // invocations per workgroup

@compute @workgroup_size(WG)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let c = linear_group(wid, nwg) * WG + li;
    let first = c * CHUNK;
    if (first >= sp.n) {
        return;
    }
    let key = keys_in[first];
    let s = seg_run(sp, first, min(first + CHUNK, sp.n), key);
    keys_out[c] = key;
    for (var w = 0u; w < sp.width; w++) {
        vals_out[c * sp.width + w] = seg_get(s, w);
    }
}
