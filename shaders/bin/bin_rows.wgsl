// Binning, step 0: for each triangle in depth order, the number of tile rows its pixel
// box spans (0 when culled); scanned into the row_offsets of (triangle, row) items.
#import frame
#import dispatch

@group(0) @binding(0) var<uniform> params: FrameParams;
@group(0) @binding(1) var<storage, read> pixel_rects: array<vec4<i32>>; // [M]
@group(0) @binding(2) var<storage, read> tri_from_rank: array<u32>;   // [M] depth order
@group(0) @binding(3) var<storage, read_write> rows: array<u32>;      // [M] by rank

const THREADS: u32 = 256u;   // one item per invocation

@compute @workgroup_size(THREADS)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let j = linear_group(wid, nwg) * THREADS + li;
    if (j >= params.num_triangles) {
        return;
    }
    let rect = pixel_rects[tri_from_rank[j]];
    var n = 0u;
    if (rect.x <= rect.z && rect.y <= rect.w) {
        n = u32(rect.w / i32(TILE) - rect.y / i32(TILE) + 1);
    }
    rows[j] = n;
}
