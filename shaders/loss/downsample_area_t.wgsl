// Transpose of downsample_area.wgsl for the gradient: dL/d fine sub-pixel = dL/d its output
// pixel / s^2, written straight into the backward pass's [s H * s W] vec4 input layout
// (dL/d rgb, dL/d T = 0), so no separate pack_v_out pass. One invocation per sub-pixel, one
// output write, three loads. Twin: tsplus_wgpu.reference.loss.downsample_area_t.
#import dispatch

struct DownParams {
    width: u32,            // coarse width W
    height: u32,           // coarse height H
    factor: u32,           // s
    inv_area: f32,         // 1 / s^2
}

@group(0) @binding(0) var<uniform> dp: DownParams;
@group(0) @binding(1) var<storage, read> v_coarse: array<f32>;            // [H * W * 3]
@group(0) @binding(2) var<storage, read_write> v_fine: array<vec4<f32>>;  // [s H * s W]

@compute @workgroup_size(256)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let q = linear_group(wid, nwg) * 256u + li;
    let s = dp.factor;
    let fw = dp.width * s;
    if (q >= fw * dp.height * s) {
        return;
    }
    let fi = q / fw;
    let fj = q - fi * fw;
    let p = (fi / s) * dp.width + fj / s;
    v_fine[q] = vec4<f32>(v_coarse[3u * p], v_coarse[3u * p + 1u], v_coarse[3u * p + 2u], 0.0) * dp.inv_area;
}
