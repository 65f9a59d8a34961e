// Per vertex: colour = max(0, SH(dir) + 0.5), dir = unit vector camera centre -> vertex.
// The per-vertex arrays may be bound a range of vertices at a time (items: that range's count;
// tsplus_wgpu.gpu.chunks), so SH larger than one storage binding are evaluated in chunks.
#import frame
#import dispatch
#import sh

@group(0) @binding(0) var<uniform> params: FrameParams;
@group(0) @binding(1) var<storage, read> positions: array<f32>;   // [N, 3]
@group(0) @binding(2) var<storage, read> sh_coeffs: array<f32>;   // [N, K, 3]
@group(0) @binding(3) var<storage, read_write> colors: array<vec4<f32>>;  // [N]
@group(0) @binding(4) var<uniform> items: ItemRange;

const THREADS: u32 = 256u;   // one item per invocation

@compute @workgroup_size(THREADS)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let v = linear_group(wid, nwg) * THREADS + li;
    if (v >= items.count) {
        return;
    }
    let x = vec3<f32>(positions[3u * v], positions[3u * v + 1u], positions[3u * v + 2u]);
    let delta = x - params.cam_center.xyz;
    let len = length(delta);
    // A vertex at the camera centre has no direction: only the DC term is used.
    let d = select(vec3<f32>(0.0), delta / len, len > 0.0);
    var c = vec3<f32>(0.0);
    let k_count = params.sh_k;
    for (var k = 0u; k < k_count; k++) {
        let base = (v * k_count + k) * 3u;
        let coeff = vec3<f32>(sh_coeffs[base], sh_coeffs[base + 1u], sh_coeffs[base + 2u]);
        c += sh_basis(k, d) * coeff;
    }
    colors[v] = vec4<f32>(max(c + 0.5, vec3<f32>(0.0)), 1.0);
}
