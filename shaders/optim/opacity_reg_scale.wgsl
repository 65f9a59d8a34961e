// Per vertex: the early opacity loss's gradient, out[v].x = counts[v] * weight / M (the counts of
// opacity_reg_count.wgsl; one rounding of an exact integer times the per-triangle value).
// (host: tsplus_wgpu.kernels.optim.OpacityRegGradient; twin: tsplus_wgpu.reference.optim.opacity_reg_scale)
#import dispatch

struct ScaleParams {
    n: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
    per_triangle: f32,   // weight / M
    _pad3: f32,
    _pad4: f32,
    _pad5: f32,
}

@group(0) @binding(0) var<uniform> sp: ScaleParams;
@group(0) @binding(1) var<storage, read> counts: array<u32>;              // [N]
@group(0) @binding(2) var<storage, read_write> out: array<vec4<f32>>;     // [N]

@compute @workgroup_size(256)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let v = linear_group(wid, nwg) * 256u + li;
    if (v >= sp.n) {
        return;
    }
    out[v] = vec4<f32>(f32(counts[v]) * sp.per_triangle, 0.0, 0.0, 0.0);
}
