// Per triangle: the "normal render model" of the optional normal loss
// (tsplus_wgpu.train.normals). Every triangle gets three private corners (corner 3t + k at
// the position of its vertex k) carrying the triangle's unit normal n in camera space,
// oriented to face the camera (common/normal.wgsl), encoded as the SH DC colour 0.5 + n / 2
// (SH degree 0: dc = n / (2 SH_C0), so max(0, .) never clamps), and the triangle's opacity
// o_T = min of its vertices' as every corner's opacity. Rendered with the colour image's
// camera and sigma on a black background, the blend gives C = 0.5 (1 - T) + N / 2 with
// N = sum_i w_i n_i the alpha-blended normal: the same w_i = alpha_i T_i as the colour image,
// because positions, opacities, culling and depth order are the same.
#import dispatch
#import sh
#import normal

@group(0) @binding(0) var<uniform> np_: NormalParams;
@group(0) @binding(1) var<storage, read> positions: array<f32>;              // [N, 3]
@group(0) @binding(2) var<storage, read> triangles: array<u32>;              // [M, 3]
@group(0) @binding(3) var<storage, read> opacity: array<f32>;                // [N]
@group(0) @binding(4) var<storage, read_write> corner_positions: array<f32>; // [3M, 3]
@group(0) @binding(5) var<storage, read_write> corner_sh: array<f32>;        // [3M, 1, 3]
@group(0) @binding(6) var<storage, read_write> corner_opacity: array<f32>;   // [3M]

@compute @workgroup_size(256)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let t = linear_group(wid, nwg) * 256u + li;
    if (t >= np_.num_triangles) {
        return;
    }
    var x: array<vec3<f32>, 3>;
    var o = 1.0;
    for (var k = 0u; k < 3u; k++) {
        let v = triangles[3u * t + k];
        x[k] = vec3<f32>(positions[3u * v], positions[3u * v + 1u], positions[3u * v + 2u]);
        o = min(o, opacity[v]);
    }
    let tn = tri_normal(np_, x[0], x[1], x[2]);
    let dc = tn.n * (0.5 / SH_C0);
    for (var k = 0u; k < 3u; k++) {
        let j = 3u * t + k;
        corner_positions[3u * j] = x[k].x;
        corner_positions[3u * j + 1u] = x[k].y;
        corner_positions[3u * j + 2u] = x[k].z;
        corner_sh[3u * j] = dc.x;
        corner_sh[3u * j + 1u] = dc.y;
        corner_sh[3u * j + 2u] = dc.z;
        corner_opacity[j] = o;
    }
}
