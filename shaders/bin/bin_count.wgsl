// Binning, counting pass: for each (triangle, tile row) item (its rank from bin_items),
// the number of tiles of that row the triangle's alpha >= 1/255 region meets
// (tile_overlaps, shared with bin_emit), and per tile the number of triangles (for the
// blend's pass count).
#import frame
#import dispatch
#import triangle

@group(0) @binding(0) var<uniform> params: FrameParams;
@group(0) @binding(1) var<storage, read> tris: array<Tri2D>;          // [page.count]: triangles page.first..
// The projected triangles may outgrow one binding: then one dispatch per page of them, each
// doing the items of its page's triangles only (tsplus_wgpu.gpu.chunks).
@group(0) @binding(8) var<uniform> page: ItemRange;
@group(0) @binding(2) var<storage, read> pixel_rects: array<vec4<i32>>; // [M]
@group(0) @binding(3) var<storage, read> tri_from_rank: array<u32>;   // [M] depth order
@group(0) @binding(4) var<storage, read> row_offsets: array<u32>;     // [M] by rank
@group(0) @binding(5) var<storage, read> item_rank: array<u32>;       // [R] rank of each item
@group(0) @binding(6) var<storage, read_write> counts: array<u32>;    // [R] by item
@group(0) @binding(7) var<storage, read_write> tile_counts: array<atomic<u32>>;  // [tiles]

const THREADS: u32 = 256u;   // one item per invocation

@compute @workgroup_size(THREADS)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let q = linear_group(wid, nwg) * THREADS + li;
    if (q >= params.num_rows) {
        return;
    }
    let j = item_rank[q];
    let t = tri_from_rank[j];
    if (t - page.first >= page.count) {   // another page's triangle (t < first wraps)
        return;
    }
    let rect = pixel_rects[t];
    let tri = tris[t - page.first];
    let ty = rect.y / i32(TILE) + i32(q - row_offsets[j]);
    var n = 0u;
    for (var tx = rect.x / i32(TILE); tx <= rect.z / i32(TILE); tx++) {
        if (tile_overlaps(tri, rect, tx, ty)) {
            n++;
            atomicAdd(&tile_counts[u32(ty) * params.tiles_x + u32(tx)], 1u);
        }
    }
    counts[q] = n;
}
