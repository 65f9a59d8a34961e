// Per vertex: the renderer's opacity from the trained logit (host: tsplus_wgpu.kernels.optim.TrainActivate; twin: tsplus_wgpu.reference.optim.train_activate).
//   reinvert (when the opacity floor moves from floor_old to floor): the logit is rewritten so
//     the vertex keeps its opacity: q = clamp((o_old - floor) / (1 - floor), eps, 1 - eps),
//     w = log(q) - log(1 - q), with o_old = floor_old + (1 - floor_old) sigmoid(w_old).
//   opacity[v] = floor + (1 - floor) * sigmoid(w[v])
// The SH need no activation: the trainer keeps them in the renderer's [N, K, 3] layout and the
// renderer reads the parameter buffer itself.
#import dispatch

// The default clamp of q when re-inverting (the host passes it as ActivateParams.eps).
const REINVERT_EPS: f32 = 1e-6;

struct ActivateParams {
    n: u32,
    reinvert: u32,
    _pad0: u32,
    _pad1: u32,
    floor: f32,
    floor_old: f32,
    eps: f32,
    _pad2: f32,
}

@group(0) @binding(0) var<uniform> ap: ActivateParams;
@group(0) @binding(1) var<storage, read_write> logits: array<f32>;    // [N]
@group(0) @binding(2) var<storage, read_write> opacity: array<f32>;   // [N]

fn sigmoid(w: f32) -> f32 {
    let e = exp(-abs(w));
    return select(e / (1.0 + e), 1.0 / (1.0 + e), w >= 0.0);
}

@compute @workgroup_size(256)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let v = linear_group(wid, nwg) * 256u + li;
    if (v >= ap.n) {
        return;
    }
    var w = logits[v];
    if (ap.reinvert != 0u) {
        let o_old = ap.floor_old + (1.0 - ap.floor_old) * sigmoid(w);
        let q = clamp((o_old - ap.floor) / (1.0 - ap.floor), ap.eps, 1.0 - ap.eps);
        w = log(q) - log(1.0 - q);
        logits[v] = w;
    }
    opacity[v] = ap.floor + (1.0 - ap.floor) * sigmoid(w);
}
