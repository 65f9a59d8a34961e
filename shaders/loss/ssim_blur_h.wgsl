// SSIM stage 1 (of ssim_blur_h, ssim_loss, ssim_grad_h, ssim_grad_v, ssim_reduce): per pixel,
// the row blur ('same', zero padding) of x, y, x*x, y*y, x*y for the 3 channels, packed in
// 4 vec4: (x.rgb, y.r), (y.gb, xx.rg), (xx.b, yy.rgb), (xy.rgb, 0).
#import dispatch
#import ssim


@group(0) @binding(0) var<uniform> sp: SsimParams;
@group(0) @binding(1) var<storage, read> image: array<f32>;          // [H, W, 3]
@group(0) @binding(2) var<storage, read> target_image: array<f32>;   // [H, W, 3]
@group(0) @binding(3) var<storage, read_write> rows: array<vec4<f32>>;  // [H, W, 4]

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
    var sx = vec3<f32>(0.0);
    var sy = vec3<f32>(0.0);
    var sxx = vec3<f32>(0.0);
    var syy = vec3<f32>(0.0);
    var sxy = vec3<f32>(0.0);
    for (var j = lo; j <= hi; j++) {
        let w = g[u32(j - i32(col) + RADIUS)];
        let q = 3u * (row_start + u32(j));
        let x = vec3<f32>(image[q], image[q + 1u], image[q + 2u]);
        let y = vec3<f32>(target_image[q], target_image[q + 1u], target_image[q + 2u]);
        sx += w * x;
        sy += w * y;
        sxx += w * (x * x);
        syy += w * (y * y);
        sxy += w * (x * y);
    }
    rows[4u * pix] = vec4<f32>(sx, sy.x);
    rows[4u * pix + 1u] = vec4<f32>(sy.yz, sxx.xy);
    rows[4u * pix + 2u] = vec4<f32>(sxx.z, syy);
    rows[4u * pix + 3u] = vec4<f32>(sxy, 0.0);
}
