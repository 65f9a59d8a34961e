// SSIM stage 5: one workgroup sums ssim_loss's per-workgroup partials in a fixed order
// (strided, then a tree) and writes (loss, l1, ssim, 0) with the means over N = 3 H W.
#import ssim

@group(0) @binding(0) var<uniform> sp: SsimParams;
@group(0) @binding(1) var<storage, read> partials: array<vec2<f32>>;   // [ceil(W ceil(H / SSIM_SEG) / 256)]
@group(0) @binding(2) var<storage, read_write> result: array<f32>;     // [4]

var<workgroup> red: array<vec2<f32>, SSIM_GROUP>;

@compute @workgroup_size(SSIM_GROUP)
fn main(@builtin(local_invocation_index) li: u32) {
    let n = (sp.width * ((sp.height + SSIM_SEG - 1u) / SSIM_SEG) + SSIM_GROUP - 1u) / SSIM_GROUP;   // ssim_loss's groups
    var s = vec2<f32>(0.0);
    for (var i = li; i < n; i += SSIM_GROUP) {
        s += partials[i];
    }
    red[li] = s;
    workgroupBarrier();
    for (var off = SSIM_GROUP / 2u; off > 0u; off = off / 2u) {
        if (li < off) {
            red[li] = red[li] + red[li + off];
        }
        workgroupBarrier();
    }
    if (li == 0u) {
        let l1 = red[0].x * sp.inv_n;
        let ssim = red[0].y * sp.inv_n;
        result[0] = L1_WEIGHT * l1 + SSIM_WEIGHT * (1.0 - ssim);
        result[1] = l1;
        result[2] = ssim;
        result[3] = 0.0;
    }
}
