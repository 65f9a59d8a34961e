// Backward blend, the GPU layout: one workgroup of 256 invocations per 16x16 tile, one pixel
// each (lavapipe's layout, rasterize_backward.wgsl, gives each of 16 invocations a column of
// 16 pixels). The same model, inputs, outputs, passes and windows as rasterize_backward.wgsl,
// whose header gives the derivative; the host picks one of the two (kernels/backward.py:
// backward_stage).
//
// Deterministic and atomic-free for floats. Pairs are staged RB at a time (a round) and
// reduced PB at a time (a step):
//   phase 1: every pixel replays the step's pairs in order (those it reaches: index < last)
//     and writes, per pair, 5 numbers and an edge index to `red`: the colour weight x v per
//     channel, dL/d o, dL/d ratio and which edge is the argmin (zeros where it did not take
//     the pair);
//   phase 2a: invocation (pair, quantity, column) sums one of the 13 quantities of
//     grad_stats down its column's 16 rows, in order: the plain sums, their d.y moments
//     (d.y = row centre - s.y, multiplied in as the CPU layout does per pixel) and, per edge,
//     dL/d ratio where that edge is the argmin;
//   phase 2b: invocation (pair, statistic) sums the column sums across the 16 columns, in
//     order (a column's d.x is the same for its 16 pixels: the d.x moments are d.x times the
//     column sums) and writes it to `partials`.
// Phase 2 is skipped for a pair no pixel took; two barriers a step of PB pairs.
#import frame
#import triangle
#import grad_stats
#import replay_pass

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

const RB: u32 = 16u;         // pairs per round (staged together)
const PB: u32 = 2u;          // pairs per step (reduced together)
const THREADS: u32 = 256u;   // one invocation per pixel of the tile
const NW: u32 = 6u;          // words a pixel writes per pair: wr, wg, wb, vo, vrat, edge
const NQ: u32 = 13u;         // column sums per pair (grad_stats' statistics without d.x)
// Rounds per dispatch: a round is at most 1 + RB / PB steps of 1 + PB + 2 (1 + TILE) + TILE =
// 53 loop iterations an invocation (the step, phase 1, two tasks of phase 2a, phase 2b), so
// 425, and 144 rounds are 61,200, under lavapipe's 65535 an invocation.
const ROUNDS_PER_PASS: u32 = 144u;
const REC: u32 = 5u;         // vec4s per staged triangle, as rasterize_backward.wgsl:
//   [0] s.x, s.y, g0   [1] g1, g2   [2] tau, opacity, c.x, c.y   [3] c.z, cx   [4] cy, s.y

var<workgroup> staged: array<vec4<f32>, 80>;        // [RB, REC]
var<workgroup> red: array<f32, 3072>;               // [PB, NW, 16 rows, 16 columns]
var<workgroup> colsum: array<f32, 416>;             // [PB, NQ, 16 columns]
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
        for (var j0 = 0u; j0 < count; j0 += PB) {
            // ---- phase 1: this pixel's numbers for the step's pairs, front to back
            for (var p = 0u; p < PB; p++) {
                let j = j0 + p;
                var q = array<f32, 6>(0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
                if (j < count) {
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
                            let k0 = e0 <= e1 && e0 <= e2;
                            let k1 = !k0 && e1 <= e2;
                            q[0] = w * v.x;
                            q[1] = w * v.y;
                            q[2] = w * v.z;
                            q[3] = select(0.0, v_alpha * win, unclamped);
                            q[4] = select(0.0, v_alpha * opacity * sigma * win / pr, unclamped);
                            q[5] = select(select(2.0, 1.0, k1), 0.0, k0);
                            T = T * (1.0 - alpha);
                            atomicStore(&taken[j], 1u);
                        }
                    }
                }
                // written out, not looped: no loop trips spent here (lavapipe's budget, above)
                let o = p * NW * THREADS + li;
                red[o] = q[0];
                red[o + THREADS] = q[1];
                red[o + 2u * THREADS] = q[2];
                red[o + 3u * THREADS] = q[3];
                red[o + 4u * THREADS] = q[4];
                red[o + 5u * THREADS] = q[5];
            }
            workgroupBarrier();
            // ---- phase 2a: task (pair p, quantity k, column c) sums down the column's rows in
            // order. k: 0-2 colour weights, 3 dL/d o, 4-6 their d.y moments, 7-9 dL/d ratio of
            // edge k - 7, 10-12 its d.y moment (grad_stats' order, less the d.x moments)
            for (var task = li; task < PB * NQ * TILE; task += THREADS) {
                let p = task / (NQ * TILE);
                let k = (task / TILE) % NQ;
                let c = task % TILE;
                let j = j0 + p;
                if (j < count && atomicLoad(&taken[j]) != 0u) {
                    let sy = staged[REC * j + 4u].w;
                    let y0 = f32(wid.y * TILE) + 0.5;
                    let src = select(select(4u, k - 4u, k < 7u), k, k < 4u);   // the word summed
                    let edge = f32(select(k - 10u, k - 7u, k < 10u));
                    let moment = (k >= 4u && k < 7u) || k >= 10u;
                    let base = p * NW * THREADS + src * THREADS + c;
                    let ebase = p * NW * THREADS + 5u * THREADS + c;
                    var s = 0.0;
                    for (var r = 0u; r < TILE; r++) {
                        var val = red[base + r * TILE];
                        if (k >= 7u && red[ebase + r * TILE] != edge) {
                            val = 0.0;
                        }
                        if (moment) {
                            val = val * ((y0 + f32(r)) - sy);
                        }
                        s += val;
                    }
                    colsum[(p * NQ + k) * TILE + c] = s;
                }
            }
            workgroupBarrier();
            // ---- phase 2b: task (pair p, statistic i) over the columns, in order (grad_stats
            // layout: [3 c + m] colour c, [9 + 3 k + m] edge k, moment m = 1, d.x, d.y; [18] o)
            if (li < PB * NSTAT) {
                let p = li / NSTAT;
                let i = li % NSTAT;
                let j = j0 + p;
                if (j < count && atomicLoad(&taken[j]) != 0u) {
                    var s = 0.0;
                    if (i < 18u) {
                        let group = i / 3u;         // 0..2 colours, 3..5 edges
                        let m = i % 3u;
                        let plain = select(7u + group - 3u, group, group < 3u);
                        let k = select(plain, plain + 3u + select(0u, 1u, group < 3u), m == 2u);
                        let sx = staged[REC * j].x;
                        for (var c = 0u; c < TILE; c++) {
                            let f = select(1.0, (x0 + f32(c)) - sx, m == 1u);
                            s += colsum[(p * NQ + k) * TILE + c] * f;
                        }
                    } else if (i == 18u) {
                        for (var c = 0u; c < TILE; c++) {
                            s += colsum[(p * NQ + 3u) * TILE + c];
                        }
                    }
                    partials[(first + j - pp.pair_lo) * NSTAT + i] = s;
                }
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
