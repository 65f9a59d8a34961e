// Binning, step 1: every (triangle, tile row) item learns its triangle's depth rank:
// item_rank[row_offsets[j] + r] = j for r < rows(j). One loop over the rows of one
// triangle per invocation (at most the image's tile rows), so items need no search.
#import frame
#import dispatch

@group(0) @binding(0) var<uniform> params: FrameParams;
@group(0) @binding(1) var<storage, read> pixel_rects: array<vec4<i32>>; // [M]
@group(0) @binding(2) var<storage, read> tri_from_rank: array<u32>;   // [M] depth order
@group(0) @binding(3) var<storage, read> row_offsets: array<u32>;     // [M] by rank, scanned
@group(0) @binding(4) var<storage, read_write> item_rank: array<u32>; // [R]

const THREADS: u32 = 256u;   // one item per invocation

@compute @workgroup_size(THREADS)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let j = linear_group(wid, nwg) * THREADS + li;
    if (j >= params.num_triangles) {
        return;
    }
    let rect = pixel_rects[tri_from_rank[j]];
    if (rect.x > rect.z || rect.y > rect.w) {
        return;
    }
    let rows = u32(rect.w / i32(TILE) - rect.y / i32(TILE) + 1);
    let first = row_offsets[j];
    for (var r = 0u; r < rows; r++) {
        item_rank[first + r] = j;
    }
}
