// Per vertex: add the normal loss's gradient (its corners summed per vertex: vertex_sums,
// xyz = d position, w = d opacity, for a unit loss weight) times the loss weight into the
// trainer's gradient buffers, after the photometric backward and before train_grads / Adam.
#import dispatch
#import normal

@group(0) @binding(0) var<uniform> np_: NormalParams;
@group(0) @binding(1) var<storage, read> vertex_sums: array<vec4<f32>>;     // [N]
@group(0) @binding(2) var<storage, read_write> v_positions: array<f32>;     // [N, 3]
@group(0) @binding(3) var<storage, read_write> v_opacity: array<f32>;       // [N]

@compute @workgroup_size(256)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let v = linear_group(wid, nwg) * 256u + li;
    if (v >= np_.num_vertices) {
        return;
    }
    let s = vertex_sums[v] * np_.weight;
    v_positions[3u * v] += s.x;
    v_positions[3u * v + 1u] += s.y;
    v_positions[3u * v + 2u] += s.z;
    v_opacity[v] += s.w;
}
