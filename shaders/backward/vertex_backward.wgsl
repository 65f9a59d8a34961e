// Per vertex: its corners' gradients summed (vertex_sums: corners sorted by vertex with a
// stable radix sort, then the bounded segmented sum of segment_up/segment_down:
// deterministic, nothing lost), then the SH chain rule: colour = max(0, SH(dir) . sh + 0.5), dir = (x - centre) / |x - centre|;
// dL/d sh and the view-direction term of dL/d position (zero where the colour is clamped).
// The per-vertex arrays may be bound a range of vertices at a time (items: that range's count;
// tsplus_wgpu.gpu.chunks).
#import frame
#import dispatch
#import sh_grad

@group(0) @binding(0) var<uniform> params: FrameParams;
@group(0) @binding(1) var<storage, read> positions: array<f32>;          // [N, 3]
@group(0) @binding(2) var<storage, read> sh_coeffs: array<f32>;          // [N, K, 3]
@group(0) @binding(3) var<storage, read> vertex_sums: array<vec4<f32>>; // [N, 2]: d colour, d opacity; d position
@group(0) @binding(4) var<storage, read_write> v_positions: array<f32>;  // [N, 3]
@group(0) @binding(5) var<storage, read_write> v_sh: array<f32>;         // [N, K, 3]
@group(0) @binding(6) var<storage, read_write> v_opacity: array<f32>;    // [N]
@group(0) @binding(7) var<uniform> items: ItemRange;

const WG: u32 = 256u;   // invocations per workgroup

@compute @workgroup_size(WG)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let v = linear_group(wid, nwg) * WG + li;
    if (v >= items.count) {
        return;
    }
    let a = vertex_sums[2u * v];
    let vc = a.xyz;
    let vo = a.w;
    var vx = vertex_sums[2u * v + 1u].xyz;
    let x = vec3<f32>(positions[3u * v], positions[3u * v + 1u], positions[3u * v + 2u]);
    let delta = x - params.cam_center.xyz;
    let len = length(delta);
    let d = select(vec3<f32>(0.0), delta / len, len > 0.0);
    let k_count = params.sh_k;
    var raw = vec3<f32>(0.0);
    for (var k = 0u; k < k_count; k++) {
        let base = (v * k_count + k) * 3u;
        raw += sh_basis(k, d) * vec3<f32>(sh_coeffs[base], sh_coeffs[base + 1u], sh_coeffs[base + 2u]);
    }
    let vraw = select(vec3<f32>(0.0), vc, raw + 0.5 > vec3<f32>(0.0));
    var vdir = vec3<f32>(0.0);
    for (var k = 0u; k < k_count; k++) {
        let base = (v * k_count + k) * 3u;
        let coeff = vec3<f32>(sh_coeffs[base], sh_coeffs[base + 1u], sh_coeffs[base + 2u]);
        let g = sh_basis(k, d) * vraw;
        v_sh[base] = g.x;
        v_sh[base + 1u] = g.y;
        v_sh[base + 2u] = g.z;
        vdir += sh_basis_grad(k, d) * dot(coeff, vraw);
    }
    if (len > 0.0) {
        vx += (vdir - d * dot(d, vdir)) / len;
    }
    v_positions[3u * v] = vx.x;
    v_positions[3u * v + 1u] = vx.y;
    v_positions[3u * v + 2u] = vx.z;
    v_opacity[v] = vo;
}
