// SSIM stage 4: per pixel, the column blur of ssim_grad_h's rows gives (B a, B b, B c) and
// v_image = 0.8 sign(x - y) / N - 0.2 (B a + 2 x B b + y B c) / N, N = 3 H W.
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
    let pix = linear_group(wid, nwg) * SSIM_GROUP + li;
    if (pix >= sp.num_pixels) {
        return;
    }
    var g = GAUSS;
    let col = pix % sp.width;
    let row = pix / sp.width;
    let lo = max(i32(row) - RADIUS, 0);
    let hi = min(i32(row) + RADIUS, i32(sp.height) - 1);
    var sa = vec4<f32>(0.0);
    var sb = vec4<f32>(0.0);
    var sc = vec4<f32>(0.0);
    for (var i = lo; i <= hi; i++) {
        let w = g[u32(i - i32(row) + RADIUS)];
        let q = 3u * (u32(i) * sp.width + col);
        sa += w * grows[q];
        sb += w * grows[q + 1u];
        sc += w * grows[q + 2u];
    }
    let p = 3u * pix;
    let x = vec3<f32>(image[p], image[p + 1u], image[p + 2u]);
    let y = vec3<f32>(target_image[p], target_image[p + 1u], target_image[p + 2u]);
    let v_ssim = sa.xyz + 2.0 * x * sb.xyz + y * sc.xyz;
    let v = (L1_WEIGHT * sign(x - y) - SSIM_WEIGHT * v_ssim) * sp.inv_n;
    v_image[p] = v.x;
    v_image[p + 1u] = v.y;
    v_image[p + 2u] = v.z;
}
