// Microbenchmark of the device's peak FMA rate: 8 independent vec4 FMA chains per
// invocation (2 FLOP per lane per FMA). Used by `tsplus bench-raster`, never by tests.
// Each chain: a = fma(a, FMA_MUL, FMA_ADD), CHAINS chains of vec4 per invocation, so
// FLOP_PER_ITERATION = CHAINS * 4 lanes * 2 per invocation and loop iteration.
const FMA_MUL: f32 = 0.999999;
const FMA_ADD: f32 = 1e-6;
const CHAINS: u32 = 8u;
const FLOP_PER_ITERATION: u32 = 64u;
// The sink is written only when the sum's x equals SENTINEL (never): it keeps the work alive.
const SENTINEL: f32 = 12345.678;

struct PeakParams {
    iterations: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> pp: PeakParams;
@group(0) @binding(1) var<storage, read_write> sink: array<vec4<f32>>;

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let seed = f32(gid.x) * 1e-7;
    var a0 = vec4<f32>(seed, seed + 0.1, seed + 0.2, seed + 0.3);
    var a1 = a0 + 0.01;
    var a2 = a0 + 0.02;
    var a3 = a0 + 0.03;
    var a4 = a0 + 0.04;
    var a5 = a0 + 0.05;
    var a6 = a0 + 0.06;
    var a7 = a0 + 0.07;
    let m = vec4<f32>(FMA_MUL);
    let c = vec4<f32>(FMA_ADD);
    for (var i = 0u; i < pp.iterations; i++) {
        a0 = fma(a0, m, c);
        a1 = fma(a1, m, c);
        a2 = fma(a2, m, c);
        a3 = fma(a3, m, c);
        a4 = fma(a4, m, c);
        a5 = fma(a5, m, c);
        a6 = fma(a6, m, c);
        a7 = fma(a7, m, c);
    }
    let s = a0 + a1 + a2 + a3 + a4 + a5 + a6 + a7;
    if (s.x == SENTINEL) {   // never true; keeps the work alive
        sink[gid.x] = s;
    }
}
