// SSIM stage 3: per pixel, the row blur of the derivative maps (a, b, c) of ssim_loss
// (the blur is symmetric, so its transpose is itself).
// One invocation per run of SSIM_SEG pixels of a row (H * ceil(W / SSIM_SEG) invocations); the
// 11 samples under the window slide through registers, so each is loaded once.
#import dispatch
#import ssim


@group(0) @binding(0) var<uniform> sp: SsimParams;
@group(0) @binding(1) var<storage, read> dmaps: array<vec4<f32>>;       // [H, W, 3]
@group(0) @binding(2) var<storage, read_write> grows: array<vec4<f32>>;  // [H, W, 3]

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
    var wa: array<vec4<f32>, 11>;
    var wb: array<vec4<f32>, 11>;
    var wc: array<vec4<f32>, 11>;
    for (var k = 1; k < 2 * RADIUS + 1; k++) {
        let j = c0 + k - RADIUS - 1;
        var a = vec4<f32>(0.0);
        var b = vec4<f32>(0.0);
        var c = vec4<f32>(0.0);
        if (j >= 0 && j < width) {
            let q = 3u * (row_start + u32(j));
            a = dmaps[q];
            b = dmaps[q + 1u];
            c = dmaps[q + 2u];
        }
        wa[k] = a;
        wb[k] = b;
        wc[k] = c;
    }
    for (var p = 0; p < i32(SSIM_SEG); p++) {
        let col = c0 + p;
        if (col >= width) {
            break;
        }
        for (var k = 0; k < 2 * RADIUS; k++) {
            wa[k] = wa[k + 1];
            wb[k] = wb[k + 1];
            wc[k] = wc[k + 1];
        }
        let j = col + RADIUS;
        var an = vec4<f32>(0.0);
        var bn = vec4<f32>(0.0);
        var cn = vec4<f32>(0.0);
        if (j < width) {
            let q = 3u * (row_start + u32(j));
            an = dmaps[q];
            bn = dmaps[q + 1u];
            cn = dmaps[q + 2u];
        }
        wa[2 * RADIUS] = an;
        wb[2 * RADIUS] = bn;
        wc[2 * RADIUS] = cn;
        var sa = vec4<f32>(0.0);
        var sb = vec4<f32>(0.0);
        var sc = vec4<f32>(0.0);
        for (var k = 0; k < 2 * RADIUS + 1; k++) {
            let w = GAUSS[k];
            sa += w * wa[k];
            sb += w * wb[k];
            sc += w * wc[k];
        }
        let pix = row_start + u32(col);
        grows[3u * pix] = sa;
        grows[3u * pix + 1u] = sb;
        grows[3u * pix + 2u] = sc;
    }
}
