// Per triangle: the gradient of the early opacity loss weight * mean_T(o_T), o_T = the min of
// its corners' opacities, per corner (vec4, .x): weight / M at the corner holding the minimum
// (ties to the lowest vertex index, as project_backward), 0 elsewhere. The corners are then
// summed per vertex with the deterministic segmented sum (tsplus_wgpu.kernels.reduce.SegmentSum; twin: tsplus_wgpu.reference.optim.opacity_reg).
#import dispatch

// The corners may outgrow one binding: then one dispatch per range of triangles [first, first +
// num_triangles), corner_vals bound to their corners (tsplus_wgpu.gpu.chunks).
struct RegParams {
    num_triangles: u32,
    first: u32,
    _pad1: u32,
    _pad2: u32,
    per_triangle: f32,   // weight / M
    _pad3: f32,
    _pad4: f32,
    _pad5: f32,
}

@group(0) @binding(0) var<uniform> rp: RegParams;
@group(0) @binding(1) var<storage, read> triangles: array<u32>;          // [M, 3]
@group(0) @binding(2) var<storage, read> opacity: array<f32>;            // [N]
@group(0) @binding(3) var<storage, read_write> corner_vals: array<vec4<f32>>; // [3M]

@compute @workgroup_size(256)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let l = linear_group(wid, nwg) * 256u + li;
    if (l >= rp.num_triangles) {
        return;
    }
    let t = rp.first + l;
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
    for (var k = 0u; k < 3u; k++) {
        corner_vals[3u * l + k] = vec4<f32>(select(0.0, rp.per_triangle, k == best), 0.0, 0.0, 0.0);
    }
}
