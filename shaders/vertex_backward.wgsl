// Per vertex: gather its corners' gradients (corners sorted by vertex with a stable
// radix sort, so summed in corner order: deterministic, nothing lost), then the SH
// chain rule: colour = max(0, SH(dir) . sh + 0.5), dir = (x - centre) / |x - centre|;
// dL/d sh and the view-direction term of dL/d position (zero where the colour is clamped).
#import frame
#import dispatch
#import sh_grad

@group(0) @binding(0) var<uniform> params: FrameParams;
@group(0) @binding(1) var<storage, read> positions: array<f32>;          // [N, 3]
@group(0) @binding(2) var<storage, read> sh_coeffs: array<f32>;          // [N, K, 3]
@group(0) @binding(3) var<storage, read> sorted_keys: array<u32>;        // [3 M] vertex of each corner, sorted
@group(0) @binding(4) var<storage, read> sorted_corners: array<u32>;     // [3 M] corner index
@group(0) @binding(5) var<storage, read> corner_grads: array<vec4<f32>>; // [3 M, 2]
@group(0) @binding(6) var<storage, read_write> v_positions: array<f32>;  // [N, 3]
@group(0) @binding(7) var<storage, read_write> v_sh: array<f32>;         // [N, K, 3]
@group(0) @binding(8) var<storage, read_write> v_opacity: array<f32>;    // [N]

fn lower_bound(key: u32, n: u32) -> u32 {
    var lo = 0u;
    var hi = n;
    while (lo < hi) {
        let mid = lo + (hi - lo) / 2u;
        if (sorted_keys[mid] < key) {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    return lo;
}

@compute @workgroup_size(256)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let v = linear_group(wid, nwg) * 256u + li;
    if (v >= params.num_vertices) {
        return;
    }
    let n = 3u * params.num_triangles;
    var vc = vec3<f32>(0.0);
    var vo = 0.0;
    var vx = vec3<f32>(0.0);
    for (var i = lower_bound(v, n); i < n && sorted_keys[i] == v; i++) {
        let c = sorted_corners[i];
        let a = corner_grads[2u * c];
        vc += a.xyz;
        vo += a.w;
        vx += corner_grads[2u * c + 1u].xyz;
    }
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
