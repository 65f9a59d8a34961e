// Per triangle: chain rule from its statistics (grad_stats.wgsl) to its three corners.
// With A_k the projected vertices relative to the stored incenter s, D = cross(A1 - A0,
// A2 - A0), n_k(d) = cross(A_{k+1} - d, A_{k+2} - d) = n_k0 + n_kx d.x + n_ky d.y, the
// barycentrics are b_k = n_k / D and the window edges e_k = b_k * perimeter / len_k.
// Every dependence is kept: barycentric colour interpolation, the perimeter and the side
// lengths (incenter and inradius), the pinhole Jacobian (fx/z, fy/z and the z terms).
// Output per corner: dL/d vertex colour (xyz) and dL/d opacity (w; only at the vertex
// holding the minimum, ties to the lowest vertex index), then dL/d position (world, xyz).
#import frame
#import dispatch
#import triangle
#import grad_stats

@group(0) @binding(0) var<uniform> params: FrameParams;
@group(0) @binding(1) var<storage, read> positions: array<f32>;          // [N, 3]
@group(0) @binding(2) var<storage, read> triangles: array<u32>;          // [M, 3]
@group(0) @binding(3) var<storage, read> opacities: array<f32>;          // [N]
@group(0) @binding(4) var<storage, read> colors: array<vec4<f32>>;       // [N]
@group(0) @binding(5) var<storage, read> tris: array<Tri2D>;             // [M]
@group(0) @binding(6) var<storage, read> pixel_rects: array<vec4<i32>>;  // [M]
@group(0) @binding(7) var<storage, read> tri_stats: array<f32>;          // [M, NSTAT]
@group(0) @binding(8) var<storage, read_write> corner_grads: array<vec4<f32>>;  // [3 M, 2]
// The per-triangle records may outgrow one binding: then one dispatch per range of triangles
// [items.first, items.first + items.count), tris, tri_stats and corner_grads bound to that
// range (tsplus_wgpu.gpu.chunks); the triangle's own index t indexes the rest.
@group(0) @binding(9) var<uniform> items: ItemRange;

fn cross2(a: vec2<f32>, b: vec2<f32>) -> f32 {
    return a.x * b.y - a.y * b.x;
}

const WG: u32 = 256u;   // invocations per workgroup

@compute @workgroup_size(WG)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let l = linear_group(wid, nwg) * WG + li;
    if (l >= items.count) {
        return;
    }
    let t = items.first + l;
    var out_c: array<vec3<f32>, 3>;
    var out_x: array<vec3<f32>, 3>;
    var out_o: array<f32, 3>;
    let rect = pixel_rects[t];
    if (rect.x <= rect.z && rect.y <= rect.w) {
        var S: array<f32, NSTAT>;
        for (var q = 0u; q < NSTAT; q++) {
            S[q] = tri_stats[l * NSTAT + q];
        }
        let origin = tris[l].s;
        var vid: array<u32, 3>;
        var xc: array<vec3<f32>, 3>;
        var A: array<vec2<f32>, 3>;
        var col: array<vec3<f32>, 3>;
        var op: array<f32, 3>;
        for (var k = 0u; k < 3u; k++) {
            let v = triangles[3u * t + k];
            vid[k] = v;
            let xw = vec3<f32>(positions[3u * v], positions[3u * v + 1u], positions[3u * v + 2u]);
            let c = world_to_camera(params, xw);
            xc[k] = c;
            A[k] = vec2<f32>(params.fx * c.x / c.z + params.cx, params.fy * c.y / c.z + params.cy) - origin;
            col[k] = colors[v].xyz;
            op[k] = opacities[v];
        }
        let len = vec3<f32>(length(A[1] - A[2]), length(A[2] - A[0]), length(A[0] - A[1]));
        let perim = len.x + len.y + len.z;
        let E1 = A[1] - A[0];
        let E2 = A[2] - A[0];
        let D = cross2(E1, E2);
        let Vc0 = vec3<f32>(S[0], S[3], S[6]);
        let Vcx = vec3<f32>(S[1], S[4], S[7]);
        let Vcy = vec3<f32>(S[2], S[5], S[8]);
        var gA: array<vec2<f32>, 3>;
        var F = 0.0;        // sum_k M_k . n_k   (the linearised loss times D)
        var vl = vec3<f32>(0.0);
        var y_over_l = 0.0;
        for (var k = 0u; k < 3u; k++) {
            let i = (k + 1u) % 3u;
            let j = (k + 2u) % 3u;
            let U = A[i];
            let V = A[j];
            let n = vec3<f32>(cross2(U, V), U.y - V.y, V.x - U.x);
            out_c[k] = (n.x * Vc0 + n.y * Vcx + n.z * Vcy) / D;
            let W = vec3<f32>(dot(Vc0, col[k]), dot(Vcx, col[k]), dot(Vcy, col[k]));
            let Rk = vec3<f32>(S[9u + 3u * k], S[10u + 3u * k], S[11u + 3u * k]);
            let M = W + (perim / len[k]) * Rk;
            F += dot(M, n);
            let Y = dot(Rk, n) / D;
            gA[i] += (M.x * vec2<f32>(V.y, -V.x) + vec2<f32>(-M.z, M.y)) / D;
            gA[j] += (M.x * vec2<f32>(-U.y, U.x) + vec2<f32>(M.z, -M.y)) / D;
            y_over_l += Y / len[k];
            vl[k] -= Y * perim / (len[k] * len[k]);
        }
        vl += vec3<f32>(y_over_l);   // the perimeter depends on every side
        for (var k = 0u; k < 3u; k++) {
            let i = (k + 1u) % 3u;
            let j = (k + 2u) % 3u;
            let u = (A[i] - A[j]) / len[k];
            gA[i] += vl[k] * u;
            gA[j] -= vl[k] * u;
        }
        let fd = F / (D * D);
        let dD1 = vec2<f32>(E2.y, -E2.x);
        let dD2 = vec2<f32>(-E1.y, E1.x);
        gA[1] -= fd * dD1;
        gA[2] -= fd * dD2;
        gA[0] += fd * (dD1 + dD2);
        for (var k = 0u; k < 3u; k++) {
            let c = xc[k];
            let g = gA[k];
            let vz = -(g.x * params.fx * c.x + g.y * params.fy * c.y) / (c.z * c.z);
            let vcam = vec3<f32>(g.x * params.fx / c.z, g.y * params.fy / c.z, vz);
            out_x[k] = vcam.x * params.rot0.xyz + vcam.y * params.rot1.xyz + vcam.z * params.rot2.xyz;
        }
        // o_T = min of the corners' opacities: the gradient goes to the minimum's vertex.
        let om = min(op[0], min(op[1], op[2]));
        var best = 3u;
        for (var k = 0u; k < 3u; k++) {
            if (op[k] == om && (best == 3u || vid[k] < vid[best])) {
                best = k;
            }
        }
        out_o[best] = S[18];
    }
    for (var k = 0u; k < 3u; k++) {
        corner_grads[2u * (3u * l + k)] = vec4<f32>(out_c[k], out_o[k]);
        corner_grads[2u * (3u * l + k) + 1u] = vec4<f32>(out_x[k], 0.0);
    }
}
