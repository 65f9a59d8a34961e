// For the pairs sorted by tile: ranges[tile] = [first, last + 1) (zero when empty;
// the host clears the buffer first).
#import dispatch

struct RangeParams {
    num_pairs: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> rp: RangeParams;
@group(0) @binding(1) var<storage, read> pair_tiles: array<u32>;     // [P] sorted
@group(0) @binding(2) var<storage, read_write> ranges: array<vec2<u32>>;  // [tiles]

const THREADS: u32 = 256u;   // one item per invocation

@compute @workgroup_size(THREADS)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let i = linear_group(wid, nwg) * THREADS + li;
    if (i >= rp.num_pairs) {
        return;
    }
    let tile = pair_tiles[i];
    if (i == 0u || pair_tiles[i - 1u] != tile) {
        ranges[tile].x = i;
    }
    if (i + 1u == rp.num_pairs || pair_tiles[i + 1u] != tile) {
        ranges[tile].y = i + 1u;
    }
}
