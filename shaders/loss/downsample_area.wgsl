// Area downsampling (anti-aliasing, method.md): the [s H, s W, 3] image rendered with the
// s-times camera (fx s, fy s, cx s, cy s) -> [H, W, 3], each output pixel the mean of its s x s
// block of sub-pixels. With the pixel-centre convention (j + 0.5, i + 0.5) the sub-pixel centres
// of output pixel j lie at j + (a + 0.5) / s, a = 0..s-1, whose mean is j + 0.5: the block is
// exactly the pixel's footprint. Fixed summation order (rows, then columns), then one multiply
// by 1 / s^2 (exact for s a power of two). At most s^2 = 16 iterations per invocation for s <= 4.
// Twin: tsplus_wgpu.reference.loss.downsample_area; transpose: downsample_area_t.wgsl.
#import dispatch

struct DownParams {
    width: u32,            // output (coarse) width W
    height: u32,           // output height H
    factor: u32,           // s
    inv_area: f32,         // 1 / s^2
}

@group(0) @binding(0) var<uniform> dp: DownParams;
@group(0) @binding(1) var<storage, read> fine: array<f32>;            // [s H * s W * 3]
@group(0) @binding(2) var<storage, read_write> coarse: array<f32>;    // [H * W * 3]

@compute @workgroup_size(256)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let p = linear_group(wid, nwg) * 256u + li;
    if (p >= dp.width * dp.height) {
        return;
    }
    let s = dp.factor;
    let i = p / dp.width;
    let j = p - i * dp.width;
    let fw = dp.width * s;
    var acc = vec3<f32>(0.0, 0.0, 0.0);
    for (var a = 0u; a < s; a = a + 1u) {
        let row = (i * s + a) * fw + j * s;
        for (var b = 0u; b < s; b = b + 1u) {
            let q = 3u * (row + b);
            acc = acc + vec3<f32>(fine[q], fine[q + 1u], fine[q + 2u]);
        }
    }
    acc = acc * dp.inv_area;
    coarse[3u * p] = acc.x;
    coarse[3u * p + 1u] = acc.y;
    coarse[3u * p + 2u] = acc.z;
}
