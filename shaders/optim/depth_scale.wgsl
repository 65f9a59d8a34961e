// Per vertex: the scale of its position learning rate by its distance to the nearest training
// camera (host: tsplus_wgpu.kernels.optim.DepthScale; twin: tsplus_wgpu.reference.optim.depth_scale).
//   scale[v] = min(1, min_c |p_v - c| / reach)
// An Adam step moves a vertex by about the learning rate whatever its depth, so a vertex near a
// camera would jump many more pixels per step than a far one; the scale makes the step about
// the same angle from the nearest camera for every vertex within ``reach`` of one. Read from the
// positions before each step, so it needs no state (a resumed run recomputes it exactly).
#import dispatch

struct ScaleParams {
    n: u32,
    num_centres: u32,
    _pad0: u32,
    _pad1: u32,
    reach: f32,
    _pad2: f32,
    _pad3: f32,
    _pad4: f32,
}

@group(0) @binding(0) var<uniform> sp: ScaleParams;
@group(0) @binding(1) var<storage, read> positions: array<f32>;        // [N, 3]
@group(0) @binding(2) var<storage, read> centres: array<vec4<f32>>;    // [C] (xyz; w unused)
@group(0) @binding(3) var<storage, read_write> scale: array<f32>;      // [N]

@compute @workgroup_size(256)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let v = linear_group(wid, nwg) * 256u + li;
    if (v >= sp.n) {
        return;
    }
    let p = vec3<f32>(positions[3u * v], positions[3u * v + 1u], positions[3u * v + 2u]);
    var best = 3.4e38;
    for (var c = 0u; c < sp.num_centres; c = c + 1u) {
        let d = p - centres[c].xyz;
        best = min(best, dot(d, d));
    }
    scale[v] = min(1.0, sqrt(best) / sp.reach);
}
