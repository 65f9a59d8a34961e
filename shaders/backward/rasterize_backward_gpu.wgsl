// Backward blend, the GPU layout: one workgroup of 256 invocations per 16x16 tile, one pixel
// each (lavapipe's layout, rasterize_backward.wgsl, gives each of 16 invocations a column of
// 16 pixels). The same model, inputs, outputs, passes and windows as rasterize_backward.wgsl,
// whose header gives the derivative; the host picks one of the two (kernels/backward.py:
// backward_stage).
//
// Deterministic and atomic-free for floats. Pairs are staged RB at a time (a round). Per pair:
//   phase 1: every pixel replays the pair (if it reaches it: index < last) and writes its 13
//     quantities (colour weight x v per channel, dL/d o, their d.y moments, dL/d ratio of the
//     argmin edge and its d.y moment; zeros where it did not take the pair) to `red`;
//   phase 2a: invocation (q, column) sums quantity q down its column's 16 rows, in order;
//   phase 2b: invocation i computes statistic i of grad_stats.wgsl over the 16 columns, in
//     order (a column's d.x is the same for its 16 pixels: the d.x moments are d.x times the
//     column sums) and writes it to `partials`.
// Both phases are skipped where no pixel took the pair; two barriers a pair.
#import frame
#import triangle
#import grad_stats

struct PassParams {
    round_begin: u32,   // rounds [round_begin, round_end) of RB pairs in this dispatch
    round_end: u32,
    pair_lo: u32,       // the pair window (rasterize_backward.wgsl)
    pair_hi: u32,
    gathered: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> params: FrameParams;
@group(0) @binding(1) var<uniform> pp: PassParams;
@group(0) @binding(2) var<storage, read> ranges: array<vec2<u32>>;      // [tiles]
@group(0) @binding(3) var<storage, read> pair_tris: array<u32>;         // [P] sorted
@group(0) @binding(4) var<storage, read> tris: array<vec4<f32>>;        // [M, 6]: Tri2D as raw vec4s
@group(0) @binding(5) var<storage, read> v_out: array<vec4<f32>>;       // [H, W]: dL/d image (xyz), dL/d T (w)
@group(0) @binding(6) var<storage, read_write> state: array<vec4<f32>>; // [H, W]: T, acc, Z, last (backward_prepare)
@group(0) @binding(7) var<storage, read_write> partials: array<f32>;    // [window, NSTAT]
// [0] pixel-pair evaluations, [1] those that reached the power, [2] contributions
@group(0) @binding(8) var<storage, read_write> work: array<atomic<u32>>; // [3]

const RB: u32 = 16u;         // pairs per round
const THREADS: u32 = 256u;   // one invocation per pixel of the tile
const NQ: u32 = 13u;         // per-pixel quantities a pair
// Rounds per dispatch: at most 1 + RB (1 + 2 x TILE) = 529 loop iterations a round and
// invocation, so at most 59,248 a dispatch, under lavapipe's 65535 an invocation.
const ROUNDS_PER_PASS: u32 = 112u;
const REC: u32 = 5u;         // vec4s per staged triangle, as rasterize_backward.wgsl:
//   [0] s.x, s.y, g0   [1] g1, g2   [2] tau, opacity, c.x, c.y   [3] c.z, cx   [4] cy, s.y

var<workgroup> staged: array<vec4<f32>, 80>;        // [RB, REC]
var<workgroup> red: array<f32, 3328>;               // [NQ, 16 rows, 16 columns]
var<workgroup> colsum: array<f32, 208>;             // [NQ, 16 columns]
var<workgroup> taken: array<atomic<u32>, 16>;       // [RB] some pixel took the pair
var<workgroup> max_last: atomic<u32>;
var<workgroup> rounds_shared: u32;
var<workgroup> counts: array<atomic<u32>, 3>;       // the tile's work counters

// Stage the sorted pair k (if it exists) into slot `slot`; clear its flag.
fn stage(slot: u32, k: u32, end: u32) {
    if (k < end) {
        let base = 6u * select(pair_tris[k], k - pp.pair_lo, pp.gathered != 0u);
        let t0 = tris[base];
        let t1 = tris[base + 1u];
        let t2 = tris[base + 2u];
        let c = tris[base + 3u];
        let cx = tris[base + 4u];
        let cy = tris[base + 5u];
        staged[REC * slot] = vec4<f32>(t0.xy, t1.xy);
        staged[REC * slot + 1u] = vec4<f32>(t1.zw, t2.xy);
        staged[REC * slot + 2u] = vec4<f32>(t0.w, t0.z, c.xy);
        staged[REC * slot + 3u] = vec4<f32>(c.z, cx.xyz);
        staged[REC * slot + 4u] = vec4<f32>(cy.xyz, t0.y);
    }
    atomicStore(&taken[slot], 0u);
}

@compute @workgroup_size(THREADS)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let col = li % TILE;
    let row = li / TILE;
    let px = wid.x * TILE + col;
    let py = wid.y * TILE + row;
    let tile = wid.y * params.tiles_x + wid.x;
    let range = ranges[tile];
    let x = f32(px) + 0.5;
    let y = f32(py) + 0.5;
    let sigma = params.sigma;
    let inside = px < params.width && py < params.height;
    let pix = py * params.width + px;
    var T = 1.0;
    var acc = 0.0;
    var Z = 0.0;
    var last = 0u;
    var v = vec3<f32>(0.0);
    if (inside) {
        let st = state[pix];
        T = st.x;
        acc = st.y;
        Z = st.z;
        last = bitcast<u32>(st.w);
        v = v_out[pix].xyz;
    }
    if (li == 0u) {
        atomicStore(&max_last, 0u);
        atomicStore(&counts[0], 0u);
        atomicStore(&counts[1], 0u);
        atomicStore(&counts[2], 0u);
    }
    workgroupBarrier();
    if (last != 0u) {
        atomicMax(&max_last, last);
    }
    workgroupBarrier();
    if (li == 0u) {   // a tile outside the pair window replays nothing in this dispatch
        let in_window = range.x >= pp.pair_lo && range.x < pp.pair_hi;
        rounds_shared = select(0u, atomicLoad(&max_last), in_window);
    }
    let tile_last = workgroupUniformLoad(&rounds_shared);   // pairs any pixel of the tile replays
    let round_end = min((tile_last + RB - 1u) / RB, pp.round_end);
    let round_begin = pp.round_begin;
    if (round_begin >= round_end) {
        return;
    }
    let evals = clamp(last, round_begin * RB, round_end * RB) - round_begin * RB;
    var powered = 0u;
    var added = 0u;
    let x0 = f32(wid.x * TILE) + 0.5;
    for (var b = round_begin; b < round_end; b++) {
        let first = range.x + b * RB;
        let count = min(RB, tile_last - b * RB);
        if (li < RB) {
            stage(li, first + li, range.y);
        }
        workgroupBarrier();
        for (var j = 0u; j < count; j++) {
            // ---- phase 1: this pixel's quantities for pair j
            var q = array<f32, 13>(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
            let w0 = staged[REC * j];
            let w1 = staged[REC * j + 1u];
            let w2 = staged[REC * j + 2u];
            let dx = x - w0.x;
            let d = y - w0.y;
            let e0 = (1.0 + w0.z * dx) + w0.w * d;
            let e1 = (1.0 + w1.x * dx) + w1.y * d;
            let e2 = (1.0 + w1.z * dx) + w1.w * d;
            let ratio = min(min(e0, e1), e2);
            // same decisions as rasterize_forward (ratio < tau: alpha < 1/255)
            if (b * RB + j < last && ratio > 0.0 && ratio >= w2.x) {
                powered += 1u;
                let opacity = w2.y;
                let pr = max(ratio, 1e-30);
                let win = exp2(sigma * log2(pr));
                let oi = opacity * win;
                let alpha = min(ALPHA_MAX, oi);
                if (alpha >= ALPHA_MIN) {
                    added += 1u;
                    let w3 = staged[REC * j + 3u];
                    let w4 = staged[REC * j + 4u];
                    let dy = y - w4.w;     // w4.w carries s.y
                    let cr = w2.z + w3.y * dx + w4.x * dy;
                    let cg = w2.w + w3.z * dx + w4.y * dy;
                    let cb = w3.x + w3.w * dx + w4.z * dy;
                    let cv = cr * v.x + cg * v.y + cb * v.z;
                    let w = alpha * T;
                    acc = acc + cv * w;
                    let v_alpha = T * cv - (Z - acc) / (1.0 - alpha);
                    let unclamped = oi < ALPHA_MAX;
                    let vo = select(0.0, v_alpha * win, unclamped);
                    let vrat = select(0.0, v_alpha * opacity * sigma * win / pr, unclamped);
                    let k0 = e0 <= e1 && e0 <= e2;
                    let k1 = !k0 && e1 <= e2;
                    let kk = select(select(2u, 1u, k1), 0u, k0);
                    q[0] = w * v.x;
                    q[1] = w * v.y;
                    q[2] = w * v.z;
                    q[3] = vo;
                    q[4] = q[0] * dy;
                    q[5] = q[1] * dy;
                    q[6] = q[2] * dy;
                    q[7u + kk] = vrat;
                    q[10u + kk] = vrat * dy;
                    T = T * (1.0 - alpha);
                    atomicStore(&taken[j], 1u);
                }
            }
            // written out, not looped: no loop trips spent here (lavapipe's budget, above)
            red[li] = q[0];
            red[THREADS + li] = q[1];
            red[2u * THREADS + li] = q[2];
            red[3u * THREADS + li] = q[3];
            red[4u * THREADS + li] = q[4];
            red[5u * THREADS + li] = q[5];
            red[6u * THREADS + li] = q[6];
            red[7u * THREADS + li] = q[7];
            red[8u * THREADS + li] = q[8];
            red[9u * THREADS + li] = q[9];
            red[10u * THREADS + li] = q[10];
            red[11u * THREADS + li] = q[11];
            red[12u * THREADS + li] = q[12];
            workgroupBarrier();
            let any_taken = atomicLoad(&taken[j]) != 0u;
            // ---- phase 2a: quantity k's sum down column c, rows in order
            if (any_taken && li < NQ * TILE) {
                let k = li / TILE;
                let c = li % TILE;
                var s = 0.0;
                for (var r = 0u; r < TILE; r++) {
                    s += red[k * THREADS + r * TILE + c];
                }
                colsum[li] = s;
            }
            workgroupBarrier();
            // ---- phase 2b: statistic li over the columns, in order (grad_stats layout:
            // [3 c + m] colour c, [9 + 3 k + m] edge k, moment m = 1, d.x, d.y; [18] o)
            if (any_taken && li < NSTAT) {
                var s = 0.0;
                if (li < 18u) {
                    let group = li / 3u;         // 0..2 colours, 3..5 edges
                    let m = li % 3u;
                    let base = select(7u + group - 3u, group, group < 3u);   // the plain quantity
                    let k = select(base, base + 3u + select(0u, 1u, group < 3u), m == 2u);
                    let sx = staged[REC * j].x;
                    for (var c = 0u; c < TILE; c++) {
                        let f = select(1.0, (x0 + f32(c)) - sx, m == 1u);
                        s += colsum[k * TILE + c] * f;
                    }
                } else if (li == 18u) {
                    for (var c = 0u; c < TILE; c++) {
                        s += colsum[3u * TILE + c];
                    }
                }
                partials[(first + j - pp.pair_lo) * NSTAT + li] = s;
            }
        }
        workgroupBarrier();
    }
    if (powered != 0u) {
        atomicAdd(&counts[1], powered);
    }
    if (added != 0u) {
        atomicAdd(&counts[2], added);
    }
    if (evals != 0u) {
        atomicAdd(&counts[0], evals);
    }
    workgroupBarrier();
    if (li == 0u) {
        atomicAdd(&work[0], atomicLoad(&counts[0]));
        atomicAdd(&work[1], atomicLoad(&counts[1]));
        atomicAdd(&work[2], atomicLoad(&counts[2]));
    }
    if (inside) {
        state[pix] = vec4<f32>(T, acc, Z, bitcast<f32>(last));
    }
}
