// SSIM stage 4: per pixel, the column blur of ssim_grad_h's rows gives (B a, B b, B c) and
// v_image = 0.8 sign(x - y) / N - 0.2 (B a + 2 x B b + y B c) / N, N = 3 H W.
// One invocation per run of SSIM_SEG pixels of a column (W * ceil(H / SSIM_SEG) invocations,
// neighbouring invocations on neighbouring columns); the 11 samples under the window slide
// through registers (win3_* in ssim.wgsl), so each is loaded once.
#import dispatch
#import ssim


@group(0) @binding(0) var<uniform> sp: SsimParams;
@group(0) @binding(1) var<storage, read> image: array<f32>;          // [H, W, 3]
@group(0) @binding(2) var<storage, read> target_image: array<f32>;   // [H, W, 3]
@group(0) @binding(3) var<storage, read> grows: array<vec4<f32>>;    // [H, W, 3]
@group(0) @binding(4) var<storage, read_write> v_image: array<f32>;  // [H, W, 3]

// The row blurs at row i of column col (0 outside the column).
fn sample(col: u32, i: i32) -> Maps3 {
    if (i < 0 || i >= i32(sp.height)) {
        return Maps3(vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0));
    }
    let q = 3u * (u32(i) * sp.width + col);
    return Maps3(grows[q], grows[q + 1u], grows[q + 2u]);
}

@compute @workgroup_size(SSIM_GROUP)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let id = linear_group(wid, nwg) * SSIM_GROUP + li;
    if (id >= sp.width * ((sp.height + SSIM_SEG - 1u) / SSIM_SEG)) {
        return;
    }
    let col = id % sp.width;
    let r0 = i32((id / sp.width) * SSIM_SEG);
    for (var k = 1; k < 2 * RADIUS + 1; k++) {
        win3_set(k, sample(col, r0 + k - RADIUS - 1));
    }
    for (var p = 0; p < i32(SSIM_SEG); p++) {
        let row = r0 + p;
        if (row >= i32(sp.height)) {
            break;
        }
        let s = win3_push_blur(sample(col, row + RADIUS));
        let p3 = 3u * (u32(row) * sp.width + col);
        let x = vec3<f32>(image[p3], image[p3 + 1u], image[p3 + 2u]);
        let y = vec3<f32>(target_image[p3], target_image[p3 + 1u], target_image[p3 + 2u]);
        let v_ssim = s.a.xyz + 2.0 * x * s.b.xyz + y * s.c.xyz;
        let v = (L1_WEIGHT * sign(x - y) - SSIM_WEIGHT * v_ssim) * sp.inv_n;
        v_image[p3] = v.x;
        v_image[p3 + 1u] = v.y;
        v_image[p3 + 2u] = v.z;
    }
}
