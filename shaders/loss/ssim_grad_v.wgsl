// SSIM stage 4: per pixel, the column blur of ssim_grad_h's rows gives (B a, B b, B c) and
// v_image = 0.8 sign(x - y) / N - 0.2 (B a + 2 x B b + y B c) / N, N = 3 H W.
// One invocation per run of SSIM_SEG pixels of a column (W * ceil(H / SSIM_SEG) invocations,
// neighbouring invocations on neighbouring columns); the 11 samples under the window slide
// through registers, so each is loaded once.
#import dispatch
#import ssim


@group(0) @binding(0) var<uniform> sp: SsimParams;
@group(0) @binding(1) var<storage, read> image: array<f32>;          // [H, W, 3]
@group(0) @binding(2) var<storage, read> target_image: array<f32>;   // [H, W, 3]
@group(0) @binding(3) var<storage, read> grows: array<vec4<f32>>;    // [H, W, 3]
@group(0) @binding(4) var<storage, read_write> v_image: array<f32>;  // [H, W, 3]

@compute @workgroup_size(SSIM_GROUP)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let id = linear_group(wid, nwg) * SSIM_GROUP + li;
    if (id >= sp.width * ((sp.height + SSIM_SEG - 1u) / SSIM_SEG)) {
        return;
    }
    let col = id % sp.width;
    let r0 = i32((id / sp.width) * SSIM_SEG);
    let height = i32(sp.height);
    // slot k holds the sample at row row - RADIUS + k of the output row row (0 outside)
    var wa: array<vec4<f32>, 11>;
    var wb: array<vec4<f32>, 11>;
    var wc: array<vec4<f32>, 11>;
    for (var k = 1; k < 2 * RADIUS + 1; k++) {
        let i = r0 + k - RADIUS - 1;
        var a = vec4<f32>(0.0);
        var b = vec4<f32>(0.0);
        var c = vec4<f32>(0.0);
        if (i >= 0 && i < height) {
            let q = 3u * (u32(i) * sp.width + col);
            a = grows[q];
            b = grows[q + 1u];
            c = grows[q + 2u];
        }
        wa[k] = a;
        wb[k] = b;
        wc[k] = c;
    }
    for (var p = 0; p < i32(SSIM_SEG); p++) {
        let row = r0 + p;
        if (row >= height) {
            break;
        }
        for (var k = 0; k < 2 * RADIUS; k++) {
            wa[k] = wa[k + 1];
            wb[k] = wb[k + 1];
            wc[k] = wc[k + 1];
        }
        let i = row + RADIUS;
        var an = vec4<f32>(0.0);
        var bn = vec4<f32>(0.0);
        var cn = vec4<f32>(0.0);
        if (i < height) {
            let q = 3u * (u32(i) * sp.width + col);
            an = grows[q];
            bn = grows[q + 1u];
            cn = grows[q + 2u];
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
        let p3 = 3u * (u32(row) * sp.width + col);
        let x = vec3<f32>(image[p3], image[p3 + 1u], image[p3 + 2u]);
        let y = vec3<f32>(target_image[p3], target_image[p3 + 1u], target_image[p3 + 2u]);
        let v_ssim = sa.xyz + 2.0 * x * sb.xyz + y * sc.xyz;
        let v = (L1_WEIGHT * sign(x - y) - SSIM_WEIGHT * v_ssim) * sp.inv_n;
        v_image[p3] = v.x;
        v_image[p3 + 1u] = v.y;
        v_image[p3 + 2u] = v.z;
    }
}
