// SSIM stage 1 (of ssim_blur_h, ssim_loss, ssim_grad_h, ssim_grad_v, ssim_reduce): per pixel,
// the row blur ('same', zero padding) of x, y, x*x, y*y, x*y for the 3 channels, packed in
// 4 vec4: (x.rgb, y.r), (y.gb, xx.rg), (xx.b, yy.rgb), (xy.rgb, 0).
// One invocation per run of SSIM_SEG pixels of a row (H * ceil(W / SSIM_SEG) invocations); the
// 11 samples of x and y under the window slide through registers, so each is loaded once.
#import dispatch
#import ssim


@group(0) @binding(0) var<uniform> sp: SsimParams;
@group(0) @binding(1) var<storage, read> image: array<f32>;          // [H, W, 3]
@group(0) @binding(2) var<storage, read> target_image: array<f32>;   // [H, W, 3]
@group(0) @binding(3) var<storage, read_write> rows: array<vec4<f32>>;  // [H, W, 4]

@compute @workgroup_size(SSIM_GROUP)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let id = linear_group(wid, nwg) * SSIM_GROUP + li;
    let runs = (sp.width + SSIM_SEG - 1u) / SSIM_SEG;
    if (id >= runs * sp.height) {
        return;
    }
    let row_start = (id / runs) * sp.width;
    let c0 = i32((id % runs) * SSIM_SEG);
    let width = i32(sp.width);
    // slot k holds the sample at column col - RADIUS + k of the output column col (0 outside)
    var wx: array<vec3<f32>, 11>;
    var wy: array<vec3<f32>, 11>;
    for (var k = 1; k < 2 * RADIUS + 1; k++) {
        let j = c0 + k - RADIUS - 1;
        var x = vec3<f32>(0.0);
        var y = vec3<f32>(0.0);
        if (j >= 0 && j < width) {
            let q = 3u * (row_start + u32(j));
            x = vec3<f32>(image[q], image[q + 1u], image[q + 2u]);
            y = vec3<f32>(target_image[q], target_image[q + 1u], target_image[q + 2u]);
        }
        wx[k] = x;
        wy[k] = y;
    }
    for (var p = 0; p < i32(SSIM_SEG); p++) {
        let col = c0 + p;
        if (col >= width) {
            break;
        }
        for (var k = 0; k < 2 * RADIUS; k++) {
            wx[k] = wx[k + 1];
            wy[k] = wy[k + 1];
        }
        let j = col + RADIUS;
        var xn = vec3<f32>(0.0);
        var yn = vec3<f32>(0.0);
        if (j < width) {
            let q = 3u * (row_start + u32(j));
            xn = vec3<f32>(image[q], image[q + 1u], image[q + 2u]);
            yn = vec3<f32>(target_image[q], target_image[q + 1u], target_image[q + 2u]);
        }
        wx[2 * RADIUS] = xn;
        wy[2 * RADIUS] = yn;
        var sx = vec3<f32>(0.0);
        var sy = vec3<f32>(0.0);
        var sxx = vec3<f32>(0.0);
        var syy = vec3<f32>(0.0);
        var sxy = vec3<f32>(0.0);
        for (var k = 0; k < 2 * RADIUS + 1; k++) {
            let w = GAUSS[k];
            let x = wx[k];
            let y = wy[k];
            sx += w * x;
            sy += w * y;
            sxx += w * (x * x);
            syy += w * (y * y);
            sxy += w * (x * y);
        }
        let pix = row_start + u32(col);
        rows[4u * pix] = vec4<f32>(sx, sy.x);
        rows[4u * pix + 1u] = vec4<f32>(sy.yz, sxx.xy);
        rows[4u * pix + 2u] = vec4<f32>(sxx.z, syy);
        rows[4u * pix + 3u] = vec4<f32>(sxy, 0.0);
    }
}
