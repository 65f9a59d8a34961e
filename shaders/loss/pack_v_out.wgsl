// Per pixel: dL/d image [H, W, 3] (ImageLoss) -> the backward pass's input layout
// [H * W] vec4 (dL/d rgb, dL/d T = 0).
#import dispatch

struct PackParams {
    num_pixels: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> pp: PackParams;
@group(0) @binding(1) var<storage, read> v_image: array<f32>;          // [H * W * 3]
@group(0) @binding(2) var<storage, read_write> v_out: array<vec4<f32>>; // [H * W]

@compute @workgroup_size(256)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let i = linear_group(wid, nwg) * 256u + li;
    if (i >= pp.num_pixels) {
        return;
    }
    v_out[i] = vec4<f32>(v_image[3u * i], v_image[3u * i + 1u], v_image[3u * i + 2u], 0.0);
}
