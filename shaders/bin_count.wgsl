// Binning, counting pass: for each triangle in depth order, the number of 16x16
// tiles its alpha >= 1/255 region meets (tile_overlaps, shared with bin_emit).
#import frame
#import dispatch
#import triangle

@group(0) @binding(0) var<uniform> params: FrameParams;
@group(0) @binding(1) var<storage, read> tris: array<Tri2D>;          // [M]
@group(0) @binding(2) var<storage, read> pixel_rects: array<vec4<i32>>; // [M]
@group(0) @binding(3) var<storage, read> tri_from_rank: array<u32>;   // [M] depth order
@group(0) @binding(4) var<storage, read_write> counts: array<u32>;    // [M] by rank

@compute @workgroup_size(256)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let j = linear_group(wid, nwg) * 256u + li;
    if (j >= params.num_triangles) {
        return;
    }
    let t = tri_from_rank[j];
    let rect = pixel_rects[t];
    var n = 0u;
    if (rect.x <= rect.z && rect.y <= rect.w) {
        let tri = tris[t];
        for (var ty = rect.y / i32(TILE); ty <= rect.w / i32(TILE); ty++) {
            for (var tx = rect.x / i32(TILE); tx <= rect.z / i32(TILE); tx++) {
                if (tile_overlaps(tri, rect, tx, ty)) {
                    n++;
                }
            }
        }
    }
    counts[j] = n;
}
