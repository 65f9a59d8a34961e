// Binning, writing pass: each (triangle, tile row) item writes its (tile, triangle)
// pairs at its offset from the exclusive prefix sum of bin_count's counts. Items are in
// depth-rank order, so pairs come out ordered by rank, then tile.
#import frame
#import dispatch
#import triangle

@group(0) @binding(0) var<uniform> params: FrameParams;
@group(0) @binding(1) var<storage, read> tris: array<Tri2D>;          // [page.count]: triangles page.first..
// The projected triangles may outgrow one binding: then one dispatch per page of them, each
// doing the items of its page's triangles only (tsplus_wgpu.gpu.chunks).
@group(0) @binding(9) var<uniform> page: ItemRange;
@group(0) @binding(2) var<storage, read> pixel_rects: array<vec4<i32>>; // [M]
@group(0) @binding(3) var<storage, read> tri_from_rank: array<u32>;   // [M]
@group(0) @binding(4) var<storage, read> row_offsets: array<u32>;     // [M] by rank
@group(0) @binding(5) var<storage, read> item_rank: array<u32>;       // [R] rank of each item
@group(0) @binding(6) var<storage, read> offsets: array<u32>;         // [R] by item
@group(0) @binding(7) var<storage, read_write> pair_tiles: array<u32>; // [P]
@group(0) @binding(8) var<storage, read_write> pair_tris: array<u32>;  // [P]

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
    var o = offsets[q];
    for (var tx = rect.x / i32(TILE); tx <= rect.z / i32(TILE); tx++) {
        if (tile_overlaps(tri, rect, tx, ty)) {
            if (o < params.num_pairs) {
                pair_tiles[o] = u32(ty) * params.tiles_x + u32(tx);
                pair_tris[o] = t;
            }
            o++;
        }
    }
}
