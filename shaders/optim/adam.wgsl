// Adam over one parameter group: elements [offset, offset + n) of flat f32 buffers (or of
// the range of them bound: tsplus_wgpu.gpu.chunks, for buffers larger than one binding).
//   m = b1 m + (1 - b1) g;  v = b2 v + (1 - b2) g^2
//   p -= lr * (m / bias1) / (sqrt(v / bias2) + eps),  bias_k = 1 - b_k^step (host, float64)
// Two learning rates in one group (the SH, [N, K, 3]: DC and the rest): element k of the group
// takes lr where period is 0 or (phase + k) mod period < head, else lr_tail (phase: where this
// dispatch's first element lies in the group, mod period).
// A scale per item (scale_stride > 0: element k belongs to item (scale_elem + k) / scale_stride
// of the group, bound from item scale_first): its learning rate times scale[item - scale_first]
// (the positions' step by depth, shaders/optim/depth_scale.wgsl; scale_stride 0: no scale).
// One element per invocation; grids beyond 65535 workgroups are 2-D (linear_group).
#import dispatch

// The defaults of the host (tsplus_wgpu.kernels.optim.Adam), which passes them in AdamParams.
const BETA1: f32 = 0.9;
const BETA2: f32 = 0.999;
const ADAM_EPS: f32 = 1e-15;

struct AdamParams {
    offset: u32,
    n: u32,
    period: u32,
    head: u32,
    phase: u32,
    scale_stride: u32,
    lr_tail: f32,
    lr: f32,
    beta1: f32,
    beta2: f32,
    one_minus_beta1: f32,   // from the host in float64: 1 - 0.999 in f32 is 1.3e-5 off
    one_minus_beta2: f32,
    eps: f32,
    bias1: f32,
    bias2: f32,
    scale_elem: u32,
    scale_first: u32,
}

@group(0) @binding(0) var<uniform> ap: AdamParams;
@group(0) @binding(1) var<storage, read_write> param: array<f32>;
@group(0) @binding(2) var<storage, read> grad: array<f32>;
@group(0) @binding(3) var<storage, read_write> exp_avg: array<f32>;
@group(0) @binding(4) var<storage, read_write> exp_avg_sq: array<f32>;
@group(0) @binding(5) var<storage, read> scale: array<f32>;

@compute @workgroup_size(256)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let k = linear_group(wid, nwg) * 256u + li;
    if (k >= ap.n) {
        return;
    }
    let i = ap.offset + k;
    var lr = select(ap.lr_tail, ap.lr, ap.period == 0u || (ap.phase + k) % max(ap.period, 1u) < ap.head);
    if (ap.scale_stride != 0u) {
        lr = lr * scale[(ap.scale_elem + k) / ap.scale_stride - ap.scale_first];
    }
    let g = grad[i];
    let m = ap.beta1 * exp_avg[i] + ap.one_minus_beta1 * g;
    let v = ap.beta2 * exp_avg_sq[i] + ap.one_minus_beta2 * (g * g);
    exp_avg[i] = m;
    exp_avg_sq[i] = v;
    param[i] = param[i] - lr * (m / ap.bias1) / (sqrt(v / ap.bias2) + ap.eps);
}
