// Per triangle: one count for the vertex at the corner holding the minimum opacity (ties to the
// lowest vertex index, as project_backward). The early opacity loss is weight * mean_T(o_T),
// o_T the min of T's corners' opacities, so its gradient at vertex v is weight / M times the
// number of triangles whose minimum v holds: opacity_reg_scale.wgsl makes that product. Integer
// atomics add in any order to the same count, so the result is deterministic.
// (host: tsplus_wgpu.kernels.optim.OpacityRegGradient; twin: tsplus_wgpu.reference.optim.opacity_reg_count)
#import dispatch

struct CountParams {
    num_triangles: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> cp: CountParams;
@group(0) @binding(1) var<storage, read> triangles: array<u32>;               // [M, 3]
@group(0) @binding(2) var<storage, read> opacity: array<f32>;                 // [N]
@group(0) @binding(3) var<storage, read_write> counts: array<atomic<u32>>;    // [N], zeroed first

@compute @workgroup_size(256)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let t = linear_group(wid, nwg) * 256u + li;
    if (t >= cp.num_triangles) {
        return;
    }
    var vid: array<u32, 3>;
    var op: array<f32, 3>;
    for (var k = 0u; k < 3u; k++) {
        vid[k] = triangles[3u * t + k];
        op[k] = opacity[vid[k]];
    }
    let om = min(op[0], min(op[1], op[2]));
    var best = 3u;
    for (var k = 0u; k < 3u; k++) {
        if (op[k] == om && (best == 3u || vid[k] < vid[best])) {
            best = k;
        }
    }
    atomicAdd(&counts[vid[best]], 1u);
}
