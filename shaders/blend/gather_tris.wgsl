// The projected triangles of a window of pairs, in pair order: out[p] = tris[pair_tris[lo + p]]
// for p < count (host: tsplus_wgpu.kernels.blend.GatherTris; twin:
// tsplus_wgpu.reference.blend.gather_tris). Used where the projected triangles outgrow one
// storage binding: the rasterizers then read a window's records at p - lo instead of at the
// triangle's index. The records themselves are bound a page at a time ([page_lo, page_hi)):
// one dispatch per page, each copying the pairs whose triangle is in it.
#import frame
#import dispatch
#import triangle

struct GatherParams {
    lo: u32,        // the window's first pair
    count: u32,     // its pairs
    page_lo: u32,   // the triangles bound as tris
    page_hi: u32,
}

@group(0) @binding(0) var<uniform> gp: GatherParams;
@group(0) @binding(1) var<storage, read> pair_tris: array<u32>;        // [P] sorted
@group(0) @binding(2) var<storage, read> tris: array<Tri2D>;           // [page_hi - page_lo]
@group(0) @binding(3) var<storage, read_write> out: array<Tri2D>;      // [count]

const THREADS: u32 = 256u;   // one pair per invocation

@compute @workgroup_size(THREADS)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let p = linear_group(wid, nwg) * THREADS + li;
    if (p >= gp.count) {
        return;
    }
    let t = pair_tris[gp.lo + p];
    if (t >= gp.page_lo && t < gp.page_hi) {
        out[p] = tris[t - gp.page_lo];
    }
}
