// SSIM stage 2: per pixel, the column blur of stage 1's rows gives mu_x, mu_y, E_xx, E_yy, E_xy;
// from them the SSIM map m and its partial derivatives a = dm/dmu_x, b = dm/dE_xx,
// c = dm/dE_xy (3 vec4 per pixel: (a.rgb, 0), (b.rgb, 0), (c.rgb, 0)), and per workgroup the
// sums of |x - y| and of m over its 256 pixels (a fixed-order tree, no atomics).
#import dispatch
#import ssim


@group(0) @binding(0) var<uniform> sp: SsimParams;
@group(0) @binding(1) var<storage, read> image: array<f32>;          // [H, W, 3]
@group(0) @binding(2) var<storage, read> target_image: array<f32>;   // [H, W, 3]
@group(0) @binding(3) var<storage, read> rows: array<vec4<f32>>;     // [H, W, 4]
@group(0) @binding(4) var<storage, read_write> dmaps: array<vec4<f32>>;     // [H, W, 3]
@group(0) @binding(5) var<storage, read_write> partials: array<vec2<f32>>;  // [groups] (sum |x-y|, sum m)

var<workgroup> red: array<vec2<f32>, SSIM_GROUP>;

@compute @workgroup_size(SSIM_GROUP)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let group = linear_group(wid, nwg);
    let pix = group * SSIM_GROUP + li;
    var part = vec2<f32>(0.0);
    if (pix < sp.num_pixels) {
        var g = GAUSS;
        let col = pix % sp.width;
        let row = pix / sp.width;
        let lo = max(i32(row) - RADIUS, 0);
        let hi = min(i32(row) + RADIUS, i32(sp.height) - 1);
        var s0 = vec4<f32>(0.0);
        var s1 = vec4<f32>(0.0);
        var s2 = vec4<f32>(0.0);
        var s3 = vec4<f32>(0.0);
        for (var i = lo; i <= hi; i++) {
            let w = g[u32(i - i32(row) + RADIUS)];
            let q = 4u * (u32(i) * sp.width + col);
            s0 += w * rows[q];
            s1 += w * rows[q + 1u];
            s2 += w * rows[q + 2u];
            s3 += w * rows[q + 3u];
        }
        let mx = s0.xyz;
        let my = vec3<f32>(s0.w, s1.xy);
        let exx = vec3<f32>(s1.zw, s2.x);
        let eyy = s2.yzw;
        let exy = s3.xyz;
        let a1 = 2.0 * mx * my + C1;
        let a2 = 2.0 * (exy - mx * my) + C2;
        let d1 = mx * mx + my * my + C1;
        let d2 = (exx - mx * mx) + (eyy - my * my) + C2;
        let den = d1 * d2;
        let m = a1 * a2 / den;
        let a = 2.0 * my * (a2 - a1) / den - 2.0 * mx * m * (1.0 / d1 - 1.0 / d2);
        let b = -m / d2;
        let c = 2.0 * a1 / den;
        dmaps[3u * pix] = vec4<f32>(a, 0.0);
        dmaps[3u * pix + 1u] = vec4<f32>(b, 0.0);
        dmaps[3u * pix + 2u] = vec4<f32>(c, 0.0);
        let p = 3u * pix;
        let x = vec3<f32>(image[p], image[p + 1u], image[p + 2u]);
        let y = vec3<f32>(target_image[p], target_image[p + 1u], target_image[p + 2u]);
        let ad = abs(x - y);
        part = vec2<f32>(ad.x + ad.y + ad.z, m.x + m.y + m.z);
    }
    red[li] = part;
    workgroupBarrier();
    for (var off = SSIM_GROUP / 2u; off > 0u; off = off / 2u) {
        if (li < off) {
            red[li] = red[li] + red[li + off];
        }
        workgroupBarrier();
    }
    if (li == 0u && group * SSIM_GROUP < sp.num_pixels) {
        partials[group] = red[0];
    }
}
