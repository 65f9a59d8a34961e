// Per triangle: the sum of its (triangle, tile) statistics over its tiles, in a fixed
// order (tiles of its pixel box, row by row). Within a tile the pairs are sorted by
// depth rank, so the triangle's pair is found by binary search on the rank.
#import frame
#import dispatch
#import grad_stats

@group(0) @binding(0) var<uniform> params: FrameParams;
@group(0) @binding(1) var<storage, read> pixel_rects: array<vec4<i32>>;  // [M]
@group(0) @binding(2) var<storage, read> ranges: array<vec2<u32>>;       // [tiles]
@group(0) @binding(3) var<storage, read> pair_tris: array<u32>;          // [P]
@group(0) @binding(4) var<storage, read> rank_from_tri: array<u32>;      // [M]
@group(0) @binding(5) var<storage, read> partials: array<f32>;           // [P, NSTAT]
@group(0) @binding(6) var<storage, read_write> tri_stats: array<f32>;    // [M, NSTAT]

@compute @workgroup_size(256)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let t = linear_group(wid, nwg) * 256u + li;
    if (t >= params.num_triangles) {
        return;
    }
    var acc: array<f32, 20>;
    let rect = pixel_rects[t];
    if (rect.x <= rect.z && rect.y <= rect.w) {
        let r = rank_from_tri[t];
        for (var ty = rect.y / i32(TILE); ty <= rect.w / i32(TILE); ty++) {
            for (var tx = rect.x / i32(TILE); tx <= rect.z / i32(TILE); tx++) {
                let rg = ranges[u32(ty) * params.tiles_x + u32(tx)];
                var lo = rg.x;
                var hi = rg.y;
                while (lo < hi) {
                    let mid = lo + (hi - lo) / 2u;
                    if (rank_from_tri[pair_tris[mid]] < r) {
                        lo = mid + 1u;
                    } else {
                        hi = mid;
                    }
                }
                if (lo < rg.y && pair_tris[lo] == t) {
                    for (var q = 0u; q < NSTAT; q++) {
                        acc[q] += partials[lo * NSTAT + q];
                    }
                }
            }
        }
    }
    for (var q = 0u; q < NSTAT; q++) {
        tri_stats[t * NSTAT + q] = acc[q];
    }
}
