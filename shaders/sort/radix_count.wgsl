// Radix sort pass, step 1: per-block digit histogram, written digit-major
// (counts[digit * num_blocks + block]) so that an exclusive scan gives every
// (digit, block) its first output slot in stable order.
#import dispatch
#import radix

@group(0) @binding(0) var<uniform> sp: SortParams;
@group(0) @binding(1) var<storage, read> keys: array<vec4<u32>>;  // [ceil(n / 4)], read 4 at a time
@group(0) @binding(2) var<storage, read_write> counts: array<u32>;  // [RADIX * num_blocks]

var<workgroup> hist: array<atomic<u32>, RADIX>;

@compute @workgroup_size(SORT_THREADS)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let block = linear_group(wid, nwg);
    if (li < RADIX) {
        atomicStore(&hist[li], 0u);
    }
    workgroupBarrier();
    let base = block * SORT_BLOCK + li * SORT_ITEMS;
    var local: array<u32, RADIX>;
    for (var i = 0u; i < SORT_ITEMS; i += 4u) {
        if (base + i < sp.n) {
            let k4 = keys[(base + i) / 4u];
            for (var c = 0u; c < 4u; c++) {
                if (base + i + c < sp.n) {
                    local[(k4[c] >> sp.shift) & (RADIX - 1u)] += 1u;
                }
            }
        }
    }
    for (var d = 0u; d < RADIX; d++) {
        if (local[d] != 0u) {
            atomicAdd(&hist[d], local[d]);
        }
    }
    workgroupBarrier();
    if (li < RADIX && block < sp.num_blocks) {
        counts[li * sp.num_blocks + block] = atomicLoad(&hist[li]);
    }
}
