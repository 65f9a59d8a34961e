// Backward blend: one workgroup of 32 invocations per 16x16 tile; each invocation replays
// 8 pixels of one column as two groups of 4 in the lanes of vec4s (as rasterize_forward),
// front to back over the tile's pairs in the forward's order, up to each pixel's last
// contributing pair (n_contrib.x). With Z = image . v + T_final * v_T (the pixel's whole
// loss) and acc_j = (colour accumulated up to and including j) . v, the derivative of alpha_j is
//   dL/d alpha_j = T_j (c_j(p) . v) - (Z - acc_j) / (1 - alpha_j),
// which needs no division of T (no error growth through deep stacks). T, acc, Z and
// the pixel's last pair come from `state` (backward_prepare) and go back to it, so the
// rounds can be split over several dispatches (PassParams).
//
// Deterministic and atomic-free for floats. Pairs are taken RB at a time. Per pair, every
// invocation sums its 8 pixels' quantities (colour weight x v per channel, dL/d ratio
// for each argmin edge, dL/d o) times 1 and d.y in its lanes (d.x is the same for the
// whole column, so the d.x moment is d.x times the plain sum) and writes these 13 numbers
// to workgroup memory; then the 19 statistics of grad_stats.wgsl of the RB pairs are
// summed over the 32 invocations in a fixed order and written per sorted pair index to
// `partials` (pairs no pixel took stay zero). Two barriers per round; the next round's
// triangles are staged (double-buffered) during the sums.
#import frame
#import triangle
#import grad_stats

struct PassParams {
    round_begin: u32,   // rounds [round_begin, round_end) of RB pairs in this dispatch: lavapipe
    round_end: u32,     // stops any invocation's loops after 65535 iterations in total
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<uniform> params: FrameParams;
@group(0) @binding(1) var<uniform> pp: PassParams;
@group(0) @binding(2) var<storage, read> ranges: array<vec2<u32>>;      // [tiles]
@group(0) @binding(3) var<storage, read> pair_tris: array<u32>;         // [P] sorted
@group(0) @binding(4) var<storage, read> tris: array<Tri2D>;            // [M]
@group(0) @binding(5) var<storage, read> v_out: array<vec4<f32>>;       // [H, W]: dL/d image (xyz), dL/d T (w)
@group(0) @binding(6) var<storage, read_write> state: array<vec4<f32>>; // [H, W]: T, acc, Z, last (backward_prepare)
@group(0) @binding(7) var<storage, read_write> partials: array<f32>;    // [P, NSTAT]
// Work done, for the benchmark's FLOP count: [0] pixel-pair evaluations, [1] those that
// reached the power (ratio >= tau), [2] contributions.
@group(0) @binding(8) var<storage, read_write> work: array<atomic<u32>>; // [3]

const RB: u32 = 8u;          // pairs per round
const THREADS: u32 = 32u;    // 16 columns x 2 (each: 8 rows = 2 groups of 4)
const SLOTS: u32 = 13u;      // per (pair, invocation): (sum, sum d.y) of w v_r, w v_g, w v_b, vr_0, vr_1, vr_2; sum vo

var<workgroup> rtris: array<Tri2D, 16>;        // [2, RB] double-buffered
var<workgroup> red: array<f32, 3328>;          // [RB, SLOTS, THREADS]
var<workgroup> live: array<atomic<u32>, 16>;   // [2, RB]
var<workgroup> max_last: atomic<u32>;
var<workgroup> rounds_shared: u32;

// Four pixels of one column.
struct Px4 {
    y: vec4<f32>,
    T: vec4<f32>,
    acc: vec4<f32>,
    Z: vec4<f32>,
    vr: vec4<f32>,
    vg: vec4<f32>,
    vb: vec4<f32>,
    last: vec4<u32>,
}

// Per-lane quantities of one pair at four pixels.
struct Q4 {
    wr: vec4<f32>,
    wg: vec4<f32>,
    wb: vec4<f32>,
    e0: vec4<f32>,
    e1: vec4<f32>,
    e2: vec4<f32>,
    vo: vec4<f32>,
    evals: u32,
    powered: u32,
    added: u32,
}

fn count(m: vec4<bool>) -> u32 {
    return dot(select(vec4<u32>(0u), vec4<u32>(1u), m), vec4<u32>(1u));
}

fn hsum(v: vec4<f32>) -> f32 {
    return (v.x + v.y) + (v.z + v.w);
}

fn replay4(q: ptr<function, Px4>, t: Tri2D, index: u32, dx: f32, sigma: f32) -> Q4 {
    var r: Q4;
    let inrange = vec4<u32>(index) < (*q).last;
    if (!any(inrange)) {
        return r;
    }
    r.evals = count(inrange);
    let dy = (*q).y - t.s.y;
    let e0 = 1.0 + t.g0.x * dx + t.g0.y * dy;
    let e1 = 1.0 + t.g1.x * dx + t.g1.y * dy;
    let e2 = 1.0 + t.g2.x * dx + t.g2.y * dy;
    let ratio = min(min(e0, e1), e2);
    // same decisions as rasterize_forward (ratio < tau: alpha < 1/255)
    let reach = inrange & (ratio > vec4<f32>(0.0)) & (ratio >= vec4<f32>(t.tau));
    if (!any(reach)) {
        return r;
    }
    r.powered = count(reach);
    let pr = max(ratio, vec4<f32>(1e-30));
    let win = exp2(sigma * log2(pr));
    let oi = t.opacity * win;
    let alpha = min(vec4<f32>(ALPHA_MAX), oi);
    let valid = reach & (alpha >= vec4<f32>(ALPHA_MIN));
    if (!any(valid)) {
        return r;
    }
    r.added = count(valid);
    let T = (*q).T;
    let cr = t.color.x + t.dcolor_dx.x * dx + t.dcolor_dy.x * dy;
    let cg = t.color.y + t.dcolor_dx.y * dx + t.dcolor_dy.y * dy;
    let cb = t.color.z + t.dcolor_dx.z * dx + t.dcolor_dy.z * dy;
    let cv = cr * (*q).vr + cg * (*q).vg + cb * (*q).vb;
    let w = select(vec4<f32>(0.0), alpha * T, valid);
    let acc = (*q).acc + cv * w;
    (*q).acc = acc;
    let v_alpha = T * cv - ((*q).Z - acc) / (1.0 - alpha);
    let unclamped = valid & (oi < vec4<f32>(ALPHA_MAX));
    r.vo = select(vec4<f32>(0.0), v_alpha * win, unclamped);
    let vrat = select(vec4<f32>(0.0), v_alpha * t.opacity * sigma * win / pr, unclamped);
    let k0 = (e0 <= e1) & (e0 <= e2);
    let k1 = !k0 & (e1 <= e2);
    let k2 = !(k0 | k1);
    r.e0 = select(vec4<f32>(0.0), vrat, k0);
    r.e1 = select(vec4<f32>(0.0), vrat, k1);
    r.e2 = select(vec4<f32>(0.0), vrat, k2);
    r.wr = w * (*q).vr;
    r.wg = w * (*q).vg;
    r.wb = w * (*q).vb;
    (*q).T = select(T, T * (1.0 - alpha), valid);
    return r;
}

// The state of pixels (px, row0 + 0..3); pixels outside the image: T = 1, nothing to replay.
fn load4(row0: u32, px: u32) -> Px4 {
    var q = Px4(vec4<f32>(0.0), vec4<f32>(1.0), vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0),
                vec4<f32>(0.0), vec4<u32>(0u));
    let py = vec4<u32>(row0) + vec4<u32>(0u, 1u, 2u, 3u);
    q.y = vec4<f32>(py) + 0.5;
    for (var k = 0u; k < 4u; k++) {
        if (py[k] < params.height && px < params.width) {
            let pix = py[k] * params.width + px;
            let st = state[pix];
            let v = v_out[pix];
            q.T[k] = st.x;
            q.acc[k] = st.y;
            q.Z[k] = st.z;
            q.last[k] = bitcast<u32>(st.w);
            q.vr[k] = v.x;
            q.vg[k] = v.y;
            q.vb[k] = v.z;
        }
    }
    return q;
}

fn store4(q: Px4, row0: u32, px: u32) {
    for (var k = 0u; k < 4u; k++) {
        let py = row0 + k;
        if (py < params.height && px < params.width) {
            state[py * params.width + px] = vec4<f32>(q.T[k], q.acc[k], q.Z[k], bitcast<f32>(q.last[k]));
        }
    }
}

@compute @workgroup_size(32)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let px = wid.x * TILE + li % TILE;
    let row0 = wid.y * TILE + (li / TILE) * 8u;
    let tile = wid.y * params.tiles_x + wid.x;
    let range = ranges[tile];
    let x = f32(px) + 0.5;
    let sigma = params.sigma;
    if (li == 0u) {
        atomicStore(&max_last, 0u);
    }
    var q0 = load4(row0, px);
    var q1 = load4(row0 + 4u, px);
    let l4 = max(q0.last, q1.last);
    let mylast = max(max(l4.x, l4.y), max(l4.z, l4.w));
    workgroupBarrier();
    if (mylast != 0u) {
        atomicMax(&max_last, mylast);
    }
    workgroupBarrier();
    if (li == 0u) {
        rounds_shared = min((atomicLoad(&max_last) + RB - 1u) / RB, pp.round_end);
    }
    let round_end = workgroupUniformLoad(&rounds_shared);
    let round_begin = pp.round_begin;
    if (round_begin >= round_end) {
        return;
    }
    if (li < RB) {
        let k = range.x + round_begin * RB + li;
        if (k < range.y) {
            rtris[(round_begin % 2u) * RB + li] = tris[pair_tris[k]];
        }
        atomicStore(&live[(round_begin % 2u) * RB + li], 0u);
    }
    workgroupBarrier();
    var evals = 0u;
    var powered = 0u;
    var added = 0u;
    for (var b = round_begin; b < round_end; b++) {
        let buf = (b % 2u) * RB;
        let first = range.x + b * RB;
        // ---- phase 1: replay RB pairs at this invocation's 8 pixels; 13 sums per pair
        for (var j = 0u; j < RB; j++) {
            let t = rtris[buf + j];
            let dx = x - t.s.x;
            let index = b * RB + j;
            let a = replay4(&q0, t, index, dx, sigma);
            let c = replay4(&q1, t, index, dx, sigma);
            evals += a.evals + c.evals;
            powered += a.powered + c.powered;
            added += a.added + c.added;
            let base = j * SLOTS * THREADS + li;
            if (a.added + c.added != 0u) {
                let dy0 = q0.y - t.s.y;
                let dy1 = q1.y - t.s.y;
                red[base] = hsum(a.wr + c.wr);
                red[base + THREADS] = hsum(a.wr * dy0 + c.wr * dy1);
                red[base + 2u * THREADS] = hsum(a.wg + c.wg);
                red[base + 3u * THREADS] = hsum(a.wg * dy0 + c.wg * dy1);
                red[base + 4u * THREADS] = hsum(a.wb + c.wb);
                red[base + 5u * THREADS] = hsum(a.wb * dy0 + c.wb * dy1);
                red[base + 6u * THREADS] = hsum(a.e0 + c.e0);
                red[base + 7u * THREADS] = hsum(a.e0 * dy0 + c.e0 * dy1);
                red[base + 8u * THREADS] = hsum(a.e1 + c.e1);
                red[base + 9u * THREADS] = hsum(a.e1 * dy0 + c.e1 * dy1);
                red[base + 10u * THREADS] = hsum(a.e2 + c.e2);
                red[base + 11u * THREADS] = hsum(a.e2 * dy0 + c.e2 * dy1);
                red[base + 12u * THREADS] = hsum(a.vo + c.vo);
                atomicOr(&live[buf + j], 1u);
            } else {
                // (unrolled: no loop, see the loop budget note in frame.wgsl)
                red[base] = 0.0;
                red[base + THREADS] = 0.0;
                red[base + 2u * THREADS] = 0.0;
                red[base + 3u * THREADS] = 0.0;
                red[base + 4u * THREADS] = 0.0;
                red[base + 5u * THREADS] = 0.0;
                red[base + 6u * THREADS] = 0.0;
                red[base + 7u * THREADS] = 0.0;
                red[base + 8u * THREADS] = 0.0;
                red[base + 9u * THREADS] = 0.0;
                red[base + 10u * THREADS] = 0.0;
                red[base + 11u * THREADS] = 0.0;
                red[base + 12u * THREADS] = 0.0;
            }
        }
        workgroupBarrier();
        // ---- phase 2: the 19 statistics of each live pair, summed over the 32 invocations
        // in order (the d.x moment from the plain sums and each column's d.x); meanwhile
        // the next round's triangles are staged in the other buffer
        for (var o = li; o < RB * NSTAT; o += THREADS) {
            let j = o / NSTAT;
            let qs = o % NSTAT;
            if (qs < 19u && first + j < range.y && atomicLoad(&live[buf + j]) != 0u) {
                var slot = 12u;
                var m = 0u;
                if (qs < 18u) {
                    slot = 2u * (qs / 3u);
                    m = qs % 3u;
                }
                let row = (j * SLOTS + slot) * THREADS;
                var sum = 0.0;
                if (m == 0u) {
                    for (var i = 0u; i < THREADS; i++) {
                        sum += red[row + i];
                    }
                } else if (m == 1u) {
                    let x0 = f32(wid.x * TILE) + 0.5 - rtris[buf + j].s.x;
                    for (var i = 0u; i < THREADS; i++) {
                        sum += red[row + i] * (x0 + f32(i % TILE));
                    }
                } else {
                    for (var i = 0u; i < THREADS; i++) {
                        sum += red[row + THREADS + i];
                    }
                }
                partials[(first + j) * NSTAT + qs] = sum;
            }
        }
        if (li < RB) {
            let nb = ((b + 1u) % 2u) * RB;
            let nxt = first + RB + li;
            if (b + 1u < round_end && nxt < range.y) {
                rtris[nb + li] = tris[pair_tris[nxt]];
            }
            atomicStore(&live[nb + li], 0u);
        }
        workgroupBarrier();
    }
    atomicAdd(&work[0], evals);
    atomicAdd(&work[1], powered);
    atomicAdd(&work[2], added);
    store4(q0, row0, px);
    store4(q1, row0 + 4u, px);
}
