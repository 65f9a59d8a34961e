// Per triangle: the normal loss's gradient from the backward pass of the normal render
// model (normal_model.wgsl; corners 3t + k) to per-corner values of the shared model,
// written as vec4 (d position xyz, d opacity w) for the segmented sum over the corners
// sorted by vertex. Both paths of the loss reach the vertices:
//  * the blending weights (window, alpha, T): the corner positions' gradient of the
//    backward pass (projection, incenter, inradius, pinhole Jacobian) goes to the corner's
//    vertex; the corners' opacity gradients (all three corners carry o_T) summed go to the
//    vertex holding the minimum opacity (ties to the lowest vertex index, as project_backward);
//  * the 3D normal: dL/dn = sum_k dL/d dc_k / (2 SH_C0); n = s R u, u = e / |e|,
//    e = cross(x1 - x0, x2 - x0) (s: the camera-facing sign, piecewise constant):
//    dL/du = s R^T dL/dn, dL/de = (dL/du - u (u . dL/du)) / |e|,
//    dL/dx1 = cross(x2 - x0, dL/de), dL/dx2 = cross(dL/de, x1 - x0), dL/dx0 = -(dL/dx1 + dL/dx2).
#import dispatch
#import sh
#import normal

@group(0) @binding(0) var<uniform> np_: NormalParams;
@group(0) @binding(1) var<storage, read> positions: array<f32>;          // [N, 3]
@group(0) @binding(2) var<storage, read> triangles: array<u32>;          // [M, 3]
@group(0) @binding(3) var<storage, read> opacity: array<f32>;            // [N]
@group(0) @binding(4) var<storage, read> v_corner_positions: array<f32>; // [3M, 3]
@group(0) @binding(5) var<storage, read> v_corner_sh: array<f32>;        // [3M, 1, 3]
@group(0) @binding(6) var<storage, read> v_corner_opacity: array<f32>;   // [3M]
@group(0) @binding(7) var<storage, read_write> corner_vals: array<vec4<f32>>;  // [3M]

@compute @workgroup_size(256)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let t = linear_group(wid, nwg) * 256u + li;
    if (t >= np_.num_triangles) {
        return;
    }
    var x: array<vec3<f32>, 3>;
    var vid: array<u32, 3>;
    var op: array<f32, 3>;
    var v_n = vec3<f32>(0.0);
    var v_o = 0.0;
    for (var k = 0u; k < 3u; k++) {
        let v = triangles[3u * t + k];
        vid[k] = v;
        x[k] = vec3<f32>(positions[3u * v], positions[3u * v + 1u], positions[3u * v + 2u]);
        op[k] = opacity[v];
        let j = 3u * t + k;
        v_n += vec3<f32>(v_corner_sh[3u * j], v_corner_sh[3u * j + 1u], v_corner_sh[3u * j + 2u]);
        v_o += v_corner_opacity[j];
    }
    v_n *= 0.5 / SH_C0;
    let tn = tri_normal(np_, x[0], x[1], x[2]);
    var g: array<vec3<f32>, 3>;
    g[0] = vec3<f32>(0.0);
    g[1] = vec3<f32>(0.0);
    g[2] = vec3<f32>(0.0);
    if (tn.len > 0.0) {
        let v_u = tn.sign * rot_transpose_apply(np_, v_n);
        let v_e = (v_u - tn.u * dot(tn.u, v_u)) / tn.len;
        g[1] = cross(x[2] - x[0], v_e);
        g[2] = cross(v_e, x[1] - x[0]);
        g[0] = -(g[1] + g[2]);
    }
    let om = min(op[0], min(op[1], op[2]));
    var best = 3u;
    for (var k = 0u; k < 3u; k++) {
        if (op[k] == om && (best == 3u || vid[k] < vid[best])) {
            best = k;
        }
    }
    for (var k = 0u; k < 3u; k++) {
        let j = 3u * t + k;
        let vp = vec3<f32>(v_corner_positions[3u * j], v_corner_positions[3u * j + 1u],
                           v_corner_positions[3u * j + 2u]);
        corner_vals[j] = vec4<f32>(vp + g[k], select(0.0, v_o, k == best));
    }
}
