// Segmented sum, down-sweep (common/segment.wgsl), coarsest level first: at every run
// start that is not at a chunk start (every run start on the coarsest level), out[key]
// = (the run's elements within this chunk) + out[key] (the coarser levels' total, or 0).
#import dispatch
#import segment

@group(0) @binding(0) var<uniform> sp: SegParams;
@group(0) @binding(1) var<storage, read> keys_in: array<u32>;          // [n] sorted
@group(0) @binding(2) var<storage, read> index: array<u32>;            // [n] (level 0)
@group(0) @binding(3) var<storage, read> vals_in: array<vec4<f32>>;    // [*, width]
@group(0) @binding(4) var<storage, read_write> out: array<vec4<f32>>;  // [keys, width], zeroed first

const WG: u32 = 256u;   // invocations per workgroup

@compute @workgroup_size(WG)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let i = linear_group(wid, nwg) * WG + li;
    if (i >= sp.n) {
        return;
    }
    let key = keys_in[i];
    if (i > 0u && keys_in[i - 1u] == key) {
        return;   // not a run start
    }
    if (key - sp.key_lo >= sp.key_hi - sp.key_lo) {
        return;   // another page's key
    }
    var end = sp.n;
    if (sp.top == 0u) {
        if (i % CHUNK == 0u) {
            return;   // the whole run is in the coarser level's total
        }
        end = min(sp.n, (i / CHUNK + 1u) * CHUNK);
    }
    let s = seg_run(sp, i, end, key);
    for (var w = 0u; w < sp.width; w++) {
        let o = (key - sp.key_lo) * sp.width + w;
        out[o] = seg_get(s, w) + out[o];
    }
}
