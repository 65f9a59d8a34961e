// SSIM stage 2: per pixel, the column blur of stage 1's rows gives mu_x, mu_y, E_xx, E_yy, E_xy;
// from them the SSIM map m and its partial derivatives a = dm/dmu_x, b = dm/dE_xx,
// c = dm/dE_xy (3 vec4 per pixel: (a.rgb, 0), (b.rgb, 0), (c.rgb, 0)), and per workgroup the
// sums of |x - y| and of m over its pixels (each invocation's run in order, then a fixed-order
// tree over the workgroup; no atomics).
// One invocation per run of SSIM_SEG pixels of a column (W * ceil(H / SSIM_SEG) invocations,
// neighbouring invocations on neighbouring columns); the 11 rows under the window slide through
// registers, so each is loaded once.
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
    let id = group * SSIM_GROUP + li;
    let total = sp.width * ((sp.height + SSIM_SEG - 1u) / SSIM_SEG);
    var part = vec2<f32>(0.0);
    if (id < total) {
        let col = id % sp.width;
        let r0 = i32((id / sp.width) * SSIM_SEG);
        let height = i32(sp.height);
        // slot k holds the row blur at row row - RADIUS + k of the output row row (0 outside)
        var w0: array<vec4<f32>, 11>;
        var w1: array<vec4<f32>, 11>;
        var w2: array<vec4<f32>, 11>;
        var w3: array<vec4<f32>, 11>;
        for (var k = 1; k < 2 * RADIUS + 1; k++) {
            let i = r0 + k - RADIUS - 1;
            var v0 = vec4<f32>(0.0);
            var v1 = vec4<f32>(0.0);
            var v2 = vec4<f32>(0.0);
            var v3 = vec4<f32>(0.0);
            if (i >= 0 && i < height) {
                let q = 4u * (u32(i) * sp.width + col);
                v0 = rows[q];
                v1 = rows[q + 1u];
                v2 = rows[q + 2u];
                v3 = rows[q + 3u];
            }
            w0[k] = v0;
            w1[k] = v1;
            w2[k] = v2;
            w3[k] = v3;
        }
        for (var p = 0; p < i32(SSIM_SEG); p++) {
            let row = r0 + p;
            if (row >= height) {
                break;
            }
            for (var k = 0; k < 2 * RADIUS; k++) {
                w0[k] = w0[k + 1];
                w1[k] = w1[k + 1];
                w2[k] = w2[k + 1];
                w3[k] = w3[k + 1];
            }
            let i = row + RADIUS;
            var n0 = vec4<f32>(0.0);
            var n1 = vec4<f32>(0.0);
            var n2 = vec4<f32>(0.0);
            var n3 = vec4<f32>(0.0);
            if (i < height) {
                let q = 4u * (u32(i) * sp.width + col);
                n0 = rows[q];
                n1 = rows[q + 1u];
                n2 = rows[q + 2u];
                n3 = rows[q + 3u];
            }
            w0[2 * RADIUS] = n0;
            w1[2 * RADIUS] = n1;
            w2[2 * RADIUS] = n2;
            w3[2 * RADIUS] = n3;
            var s0 = vec4<f32>(0.0);
            var s1 = vec4<f32>(0.0);
            var s2 = vec4<f32>(0.0);
            var s3 = vec4<f32>(0.0);
            for (var k = 0; k < 2 * RADIUS + 1; k++) {
                let w = GAUSS[k];
                s0 += w * w0[k];
                s1 += w * w1[k];
                s2 += w * w2[k];
                s3 += w * w3[k];
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
            let pix = u32(row) * sp.width + col;
            dmaps[3u * pix] = vec4<f32>(a, 0.0);
            dmaps[3u * pix + 1u] = vec4<f32>(b, 0.0);
            dmaps[3u * pix + 2u] = vec4<f32>(c, 0.0);
            let p3 = 3u * pix;
            let x = vec3<f32>(image[p3], image[p3 + 1u], image[p3 + 2u]);
            let y = vec3<f32>(target_image[p3], target_image[p3 + 1u], target_image[p3 + 2u]);
            let ad = abs(x - y);
            part += vec2<f32>(ad.x + ad.y + ad.z, m.x + m.y + m.z);
        }
    }
    red[li] = part;
    workgroupBarrier();
    for (var off = SSIM_GROUP / 2u; off > 0u; off = off / 2u) {
        if (li < off) {
            red[li] = red[li] + red[li + off];
        }
        workgroupBarrier();
    }
    if (li == 0u && group * SSIM_GROUP < total) {
        partials[group] = red[0];
    }
}
