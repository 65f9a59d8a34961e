// SSIM stage 3: per pixel, the row blur of the derivative maps (a, b, c) of ssim_loss
// (the blur is symmetric, so its transpose is itself).
#import dispatch
#import ssim


@group(0) @binding(0) var<uniform> sp: SsimParams;
@group(0) @binding(1) var<storage, read> dmaps: array<vec4<f32>>;       // [H, W, 3]
@group(0) @binding(2) var<storage, read_write> grows: array<vec4<f32>>;  // [H, W, 3]

@compute @workgroup_size(SSIM_GROUP)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let pix = linear_group(wid, nwg) * SSIM_GROUP + li;
    if (pix >= sp.num_pixels) {
        return;
    }
    var g = GAUSS;
    let col = pix % sp.width;
    let row_start = pix - col;
    let lo = max(i32(col) - RADIUS, 0);
    let hi = min(i32(col) + RADIUS, i32(sp.width) - 1);
    var sa = vec4<f32>(0.0);
    var sb = vec4<f32>(0.0);
    var sc = vec4<f32>(0.0);
    for (var j = lo; j <= hi; j++) {
        let w = g[u32(j - i32(col) + RADIUS)];
        let q = 3u * (row_start + u32(j));
        sa += w * dmaps[q];
        sb += w * dmaps[q + 1u];
        sc += w * dmaps[q + 2u];
    }
    grows[3u * pix] = sa;
    grows[3u * pix + 1u] = sb;
    grows[3u * pix + 2u] = sc;
}
