// SSIM stage 3: per pixel, the row blur of the derivative maps (a, b, c) of ssim_loss
// (the blur is symmetric, so its transpose is itself).
// One invocation per run of SSIM_SEG pixels of a row (H * ceil(W / SSIM_SEG) invocations); the
// 11 samples under the window slide through registers (win3_* in ssim.wgsl), so each is loaded once.
#import dispatch
#import ssim


@group(0) @binding(0) var<uniform> sp: SsimParams;
@group(0) @binding(1) var<storage, read> dmaps: array<vec4<f32>>;       // [H, W, 3]
@group(0) @binding(2) var<storage, read_write> grows: array<vec4<f32>>;  // [H, W, 3]

// The maps at column j of the row starting at pixel row_start (0 outside the row).
fn sample(row_start: u32, j: i32) -> Maps3 {
    if (j < 0 || j >= i32(sp.width)) {
        return Maps3(vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0));
    }
    let q = 3u * (row_start + u32(j));
    return Maps3(dmaps[q], dmaps[q + 1u], dmaps[q + 2u]);
}

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
    for (var k = 1; k < 2 * RADIUS + 1; k++) {
        win3_set(k, sample(row_start, c0 + k - RADIUS - 1));
    }
    for (var p = 0; p < i32(SSIM_SEG); p++) {
        let col = c0 + p;
        if (col >= i32(sp.width)) {
            break;
        }
        let s = win3_push_blur(sample(row_start, col + RADIUS));
        let pix = row_start + u32(col);
        grows[3u * pix] = s.a;
        grows[3u * pix + 1u] = s.b;
        grows[3u * pix + 2u] = s.c;
    }
}
