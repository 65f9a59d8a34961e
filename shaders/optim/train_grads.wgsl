// Per vertex: the gradients of the trained parameters from the renderer's
// (host: tsplus_wgpu.kernels.optim.TrainGrads; twin: tsplus_wgpu.reference.optim.train_grads).
//   v_logits[v] = (v_opacity[v] + reg[v].x) * (1 - floor) * s (1 - s),  s = sigmoid(w[v])
//     (reg: the early opacity loss's gradient per vertex, opacity_reg_count + opacity_reg_scale;
//      read only when use_reg is 1)
//   v_sh[v, k, c] = 0 for k >= active_k, in place (bands above the SH degree of the schedule
//     are not trained yet); the SH parameters share the renderer's [N, K, 3] layout, so v_sh
//     is their gradient as it is.
// The per-vertex arrays may be bound a range of vertices at a time (n: that range's count;
// tsplus_wgpu.gpu.chunks).
#import dispatch

struct GradParams {
    n: u32,
    k: u32,
    active_k: u32,
    use_reg: u32,
    floor: f32,
    _pad0: f32,
    _pad1: f32,
    _pad2: f32,
}

@group(0) @binding(0) var<uniform> gp: GradParams;
@group(0) @binding(1) var<storage, read> logits: array<f32>;            // [N]
@group(0) @binding(2) var<storage, read_write> v_sh: array<f32>;        // [N, K, 3]
@group(0) @binding(3) var<storage, read> v_opacity: array<f32>;         // [N]
@group(0) @binding(4) var<storage, read> reg: array<vec4<f32>>;         // [N] (.x)
@group(0) @binding(5) var<storage, read_write> v_logits: array<f32>;    // [N]

@compute @workgroup_size(256)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let v = linear_group(wid, nwg) * 256u + li;
    if (v >= gp.n) {
        return;
    }
    let w = logits[v];
    let e = exp(-abs(w));
    let s = select(e / (1.0 + e), 1.0 / (1.0 + e), w >= 0.0);
    var vo = v_opacity[v];
    if (gp.use_reg != 0u) {
        vo += reg[v].x;
    }
    v_logits[v] = vo * (1.0 - gp.floor) * (s * (1.0 - s));
    for (var k = gp.active_k; k < gp.k; k++) {
        let base = (v * gp.k + k) * 3u;
        v_sh[base] = 0.0;
        v_sh[base + 1u] = 0.0;
        v_sh[base + 2u] = 0.0;
    }
}
