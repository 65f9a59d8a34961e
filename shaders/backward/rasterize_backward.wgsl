// Backward blend: one workgroup of 16 invocations per 16x16 tile; each invocation replays
// the 16 pixels of one column as four groups of 4 in the lanes of vec4s (as
// rasterize_forward), front to back over the tile's pairs in the forward's order, up to
// each pixel's last contributing pair (n_contrib.x). With Z = image . v + T_final * v_T
// (the pixel's whole loss) and acc_j = (colour accumulated up to and including j) . v,
// the derivative of alpha_j is
//   dL/d alpha_j = T_j (c_j(p) . v) - (Z - acc_j) / (1 - alpha_j),
// which needs no division of T (no error growth through deep stacks). T, acc, Z and
// the pixel's last pair come from `state` (backward_prepare) and go back to it, so the
// rounds can be split over several dispatches (PassParams).
//
// A view with more pairs than one binding of `partials` holds is done in windows of
// pairs (whole tiles each, PassParams.pair_lo / pair_hi), one after the other.
//
// Deterministic and atomic-free for floats. Pairs are taken RB at a time (a round); the
// triangles are staged as 5 raw vec4s, the window's 9 numbers first, the colour read only
// where some pixel of the invocation reaches the triangle (every load from workgroup
// memory is costly per instruction on CPU drivers). Per pair, an invocation whose pixels
// took it sums its 16 pixels' quantities (colour weight x v per channel, dL/d ratio for
// each argmin edge, dL/d o) times 1 and d.y in its lanes (d.x is the same for the whole
// column, so the d.x moment is d.x times the plain sum), writes these 13 numbers as 4
// vec4s to workgroup memory and sets its bit in the pair's `touched` mask. After a
// barrier, invocation j sums pair j's statistics over the invocations of its mask in
// ascending order (a fixed order; the others hold zeros, which add nothing) and writes
// the 19 statistics of grad_stats.wgsl per sorted pair index to `partials` (pairs no
// pixel took stay zero); meanwhile the next round's triangles are staged (double-buffered).
// Two barriers per round.
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
@group(0) @binding(7) var<storage, read_write> partials: array<vec4<f32>>;  // [window, NSTAT / 4]
// Work done, for the benchmark's FLOP count: [0] pixel-pair evaluations, [1] those that
// reached the power (ratio >= tau), [2] contributions.
@group(0) @binding(8) var<storage, read_write> work: array<atomic<u32>>; // [3]

const RB: u32 = 8u;          // pairs per round (<= THREADS)
const THREADS: u32 = 16u;    // one invocation per column of the tile: 16 pixels, 4 groups of 4
// Rounds per dispatch (the host splits a tile's rounds into passes of this many): at most
// RB + THREADS + 1 = 25 loop iterations per round and invocation (the round's pairs, the sum
// over at most THREADS invocations' entries, the loop itself), so about 51,200 per dispatch,
// under lavapipe's limit of 65535 per invocation.
const ROUNDS_PER_PASS: u32 = 2048u;
const REC: u32 = 5u;         // vec4s per staged triangle, the window first (read for every
//   pixel-pair), the rest only where some pixel is inside (c: colour at s, cx, cy: d colour / dx, dy):
//   [0] s.x, s.y, g0   [1] g1, g2   [2] tau, opacity, c.x, c.y   [3] c.z, cx   [4] cy, s.y

var<workgroup> staged: array<vec4<f32>, 80>;     // [2, RB, REC] double-buffered
var<workgroup> red: array<vec4<f32>, 512>;       // [RB, THREADS, 4] per-invocation sums
var<workgroup> touched: array<atomic<u32>, 16>;  // [2, RB] bit i: invocation i wrote sums
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
    powered: vec4<u32>,
    added: vec4<u32>,
}

// One pair's quantities summed over an invocation's pixel groups, per lane.
struct Sums {
    wr: vec4<f32>,
    wg: vec4<f32>,
    wb: vec4<f32>,
    vo: vec4<f32>,
    wry: vec4<f32>,
    wgy: vec4<f32>,
    wby: vec4<f32>,
    e0: vec4<f32>,
    e1: vec4<f32>,
    e2: vec4<f32>,
    e0y: vec4<f32>,
    e1y: vec4<f32>,
    e2y: vec4<f32>,
}

fn hsum(v: vec4<f32>) -> f32 {
    return (v.x + v.y) + (v.z + v.w);
}

// Replay the staged triangle at the four pixels where live (same decisions and arithmetic
// as rasterize_forward), adding its derivatives to `s`; true if some pixel took it.
fn replay4(q: ptr<function, Px4>, s: ptr<function, Sums>, live: vec4<bool>, ratio: vec4<f32>,
           e0: vec4<f32>, e1: vec4<f32>, e2: vec4<f32>, opacity: f32, sigma: f32,
           c0: vec4<f32>, cx: vec4<f32>, cy: vec4<f32>, dx: f32) -> bool {
    if (!any(live)) {
        return false;
    }
    (*q).powered += select(vec4<u32>(0u), vec4<u32>(1u), live);
    let pr = max(ratio, vec4<f32>(1e-30));
    let win = exp2(sigma * log2(pr));
    let oi = opacity * win;
    let alpha = min(vec4<f32>(ALPHA_MAX), oi);
    let valid = live & (alpha >= vec4<f32>(ALPHA_MIN));
    if (!any(valid)) {
        return false;
    }
    (*q).added += select(vec4<u32>(0u), vec4<u32>(1u), valid);
    let T = (*q).T;
    let dy = (*q).y - c0.w;   // c0.w carries s.y (see staging)
    let cr = c0.x + cx.x * dx + cy.x * dy;
    let cg = c0.y + cx.y * dx + cy.y * dy;
    let cb = c0.z + cx.z * dx + cy.z * dy;
    let cv = cr * (*q).vr + cg * (*q).vg + cb * (*q).vb;
    let w = select(vec4<f32>(0.0), alpha * T, valid);
    let acc = (*q).acc + cv * w;
    (*q).acc = acc;
    let v_alpha = T * cv - ((*q).Z - acc) / (1.0 - alpha);
    let unclamped = valid & (oi < vec4<f32>(ALPHA_MAX));
    let zero = vec4<f32>(0.0);
    let vo = select(zero, v_alpha * win, unclamped);
    let vrat = select(zero, v_alpha * opacity * sigma * win / pr, unclamped);
    let k0 = (e0 <= e1) & (e0 <= e2);
    let k1 = !k0 & (e1 <= e2);
    let k2 = !(k0 | k1);
    let r0 = select(zero, vrat, k0);
    let r1 = select(zero, vrat, k1);
    let r2 = select(zero, vrat, k2);
    let wr = w * (*q).vr;
    let wg = w * (*q).vg;
    let wb = w * (*q).vb;
    (*s).wr += wr;
    (*s).wg += wg;
    (*s).wb += wb;
    (*s).vo += vo;
    (*s).wry += wr * dy;
    (*s).wgy += wg * dy;
    (*s).wby += wb * dy;
    (*s).e0 += r0;
    (*s).e1 += r1;
    (*s).e2 += r2;
    (*s).e0y += r0 * dy;
    (*s).e1y += r1 * dy;
    (*s).e2y += r2 * dy;
    (*q).T = select(T, T * (1.0 - alpha), valid);
    return true;
}

// The state of pixels (px, row0 + 0..3); pixels outside the image: T = 1, nothing to replay.
fn load4(row0: u32, px: u32) -> Px4 {
    let z = vec4<f32>(0.0);
    let zu = vec4<u32>(0u);
    var q = Px4(z, vec4<f32>(1.0), z, z, z, z, z, zu, zu, zu);
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

// Pixel-pair evaluations of rounds [lo, hi) of RB pairs at four pixels.
fn evals4(q: Px4, lo: u32, hi: u32) -> u32 {
    let a = vec4<u32>(lo * RB);
    let b = vec4<u32>(hi * RB);
    return dot(clamp(q.last, a, b) - a, vec4<u32>(1u));
}

// Stage the sorted pair k (if it exists) into slot `slot` of `staged`; clear its mask.
fn stage(slot: u32, k: u32, end: u32) {
    if (k < end) {
        let base = 6u * select(pair_tris[k], k - pp.pair_lo, pp.gathered != 0u);   // Tri2D: (s, opacity, tau), (g0, g1), (g2, depth, inradius), c, cx, cy
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
    atomicStore(&touched[slot], 0u);
}

@compute @workgroup_size(THREADS)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let px = wid.x * TILE + li;
    let row0 = wid.y * TILE;
    let tile = wid.y * params.tiles_x + wid.x;
    let range = ranges[tile];
    let x = f32(px) + 0.5;
    let sigma = params.sigma;
    if (li == 0u) {
        atomicStore(&max_last, 0u);
    }
    var q0 = load4(row0, px);
    var q1 = load4(row0 + 4u, px);
    var q2 = load4(row0 + 8u, px);
    var q3 = load4(row0 + 12u, px);
    let l4 = max(max(q0.last, q1.last), max(q2.last, q3.last));
    let mylast = max(max(l4.x, l4.y), max(l4.z, l4.w));
    workgroupBarrier();
    if (mylast != 0u) {
        atomicMax(&max_last, mylast);
    }
    workgroupBarrier();
    if (li == 0u) {   // a tile outside the pair window replays nothing in this dispatch
        let inside = range.x >= pp.pair_lo && range.x < pp.pair_hi;
        rounds_shared = select(0u, atomicLoad(&max_last), inside);
    }
    let tile_last = workgroupUniformLoad(&rounds_shared);   // pairs any pixel of the tile replays
    let round_end = min((tile_last + RB - 1u) / RB, pp.round_end);
    let round_begin = pp.round_begin;
    if (round_begin >= round_end) {
        return;
    }
    let evals = evals4(q0, round_begin, round_end) + evals4(q1, round_begin, round_end)
              + evals4(q2, round_begin, round_end) + evals4(q3, round_begin, round_end);
    let stager = li >= THREADS - RB;       // these stage the next round's pairs
    let sj = li - (THREADS - RB);          // (the pair they stage)
    if (stager) {
        stage((round_begin % 2u) * RB + sj, range.x + round_begin * RB + sj, range.y);
    }
    workgroupBarrier();
    var sums: Sums;
    for (var b = round_begin; b < round_end; b++) {
        let buf = (b % 2u) * RB;
        let first = range.x + b * RB;
        let count = min(RB, tile_last - b * RB);
        // ---- phase 1: replay the round's pairs at this invocation's 16 pixels
        for (var j = 0u; j < count; j++) {
            let w0 = staged[REC * (buf + j)];
            let w1 = staged[REC * (buf + j) + 1u];
            let w2 = staged[REC * (buf + j) + 2u];
            let dx = x - w0.x;
            let a = vec3<f32>(1.0 + w0.z * dx, 1.0 + w1.x * dx, 1.0 + w1.z * dx);
            let gy = vec3<f32>(w0.w, w1.y, w1.w);
            let tau = vec4<f32>(w2.x);
            let zero = vec4<f32>(0.0);
            let index = vec4<u32>(b * RB + j);
            let d0 = q0.y - w0.y;
            let d1 = q1.y - w0.y;
            let d2 = q2.y - w0.y;
            let d3 = q3.y - w0.y;
            let e00 = a.x + gy.x * d0;
            let e01 = a.y + gy.y * d0;
            let e02 = a.z + gy.z * d0;
            let e10 = a.x + gy.x * d1;
            let e11 = a.y + gy.y * d1;
            let e12 = a.z + gy.z * d1;
            let e20 = a.x + gy.x * d2;
            let e21 = a.y + gy.y * d2;
            let e22 = a.z + gy.z * d2;
            let e30 = a.x + gy.x * d3;
            let e31 = a.y + gy.y * d3;
            let e32 = a.z + gy.z * d3;
            let r0 = min(min(e00, e01), e02);
            let r1 = min(min(e10, e11), e12);
            let r2 = min(min(e20, e21), e22);
            let r3 = min(min(e30, e31), e32);
            // same decisions as rasterize_forward (ratio < tau: alpha < 1/255)
            let l0 = (index < q0.last) & (r0 > zero) & (r0 >= tau);
            let l1 = (index < q1.last) & (r1 > zero) & (r1 >= tau);
            let l2 = (index < q2.last) & (r2 > zero) & (r2 >= tau);
            let l3 = (index < q3.last) & (r3 > zero) & (r3 >= tau);
            if (any(l0 | l1 | l2 | l3)) {
                let w3 = staged[REC * (buf + j) + 3u];
                let w4 = staged[REC * (buf + j) + 4u];
                let c0 = vec4<f32>(w2.zw, w3.x, w4.w);   // c0.w carries s.y
                let cx = w3.yzww;
                let cy = w4;
                sums = Sums(zero, zero, zero, zero, zero, zero, zero, zero, zero, zero, zero, zero, zero);
                let t0 = replay4(&q0, &sums, l0, r0, e00, e01, e02, w2.y, sigma, c0, cx, cy, dx);
                let t1 = replay4(&q1, &sums, l1, r1, e10, e11, e12, w2.y, sigma, c0, cx, cy, dx);
                let t2 = replay4(&q2, &sums, l2, r2, e20, e21, e22, w2.y, sigma, c0, cx, cy, dx);
                let t3 = replay4(&q3, &sums, l3, r3, e30, e31, e32, w2.y, sigma, c0, cx, cy, dx);
                if (t0 || t1 || t2 || t3) {
                    let o = 4u * (j * THREADS + li);
                    red[o] = vec4<f32>(hsum(sums.wr), hsum(sums.wg), hsum(sums.wb), hsum(sums.vo));
                    red[o + 1u] = vec4<f32>(hsum(sums.wry), hsum(sums.wgy), hsum(sums.wby), 0.0);
                    red[o + 2u] = vec4<f32>(hsum(sums.e0), hsum(sums.e1), hsum(sums.e2), 0.0);
                    red[o + 3u] = vec4<f32>(hsum(sums.e0y), hsum(sums.e1y), hsum(sums.e2y), 0.0);
                    atomicOr(&touched[buf + j], 1u << li);
                }
            }
        }
        workgroupBarrier();
        // ---- phase 2: invocation j sums pair j over the invocations that took it, in
        // order (the d.x moment from the plain sums and each column's d.x); meanwhile the
        // next round's triangles are staged in the other buffer
        if (li < RB) {
            let m = atomicLoad(&touched[buf + li]);
            if (m != 0u) {
                let sx = staged[REC * (buf + li)].x;
                let x0 = f32(wid.x * TILE) + 0.5;
                var s0 = vec4<f32>(0.0);   // wr, wg, wb, vo
                var s1 = vec4<f32>(0.0);   // d.y moments of wr, wg, wb
                var s2 = vec4<f32>(0.0);   // e0, e1, e2
                var s3 = vec4<f32>(0.0);   // d.y moments of e0, e1, e2
                var m0 = vec4<f32>(0.0);   // d.x moments of s0
                var m2 = vec4<f32>(0.0);   // d.x moments of s2
                for (var bits = m; bits != 0u; bits &= bits - 1u) {
                    let i = firstTrailingBit(bits);
                    let o = 4u * (li * THREADS + i);
                    let a0 = red[o];
                    let a2 = red[o + 2u];
                    let dxi = (x0 + f32(i)) - sx;
                    s0 += a0;
                    s1 += red[o + 1u];
                    s2 += a2;
                    s3 += red[o + 3u];
                    m0 += a0 * dxi;
                    m2 += a2 * dxi;
                }
                // grad_stats layout: [3 c + m] colour c, moment m; [9 + 3 k + m] edge k; [18] o
                let pb = (first + li - pp.pair_lo) * (NSTAT / 4u);
                partials[pb] = vec4<f32>(s0.x, m0.x, s1.x, s0.y);
                partials[pb + 1u] = vec4<f32>(m0.y, s1.y, s0.z, m0.z);
                partials[pb + 2u] = vec4<f32>(s1.z, s2.x, m2.x, s3.x);
                partials[pb + 3u] = vec4<f32>(s2.y, m2.y, s3.y, s2.z);
                partials[pb + 4u] = vec4<f32>(m2.z, s3.z, s0.w, 0.0);
            }
        }
        if (stager && b + 1u < round_end) {
            stage(((b + 1u) % 2u) * RB + sj, first + RB + sj, range.y);
        }
        workgroupBarrier();
    }
    let one = vec4<u32>(1u);
    atomicAdd(&work[0], evals);
    atomicAdd(&work[1], dot(q0.powered + q1.powered + q2.powered + q3.powered, one));
    atomicAdd(&work[2], dot(q0.added + q1.added + q2.added + q3.added, one));
    store4(q0, row0, px);
    store4(q1, row0 + 4u, px);
    store4(q2, row0 + 8u, px);
    store4(q3, row0 + 12u, px);
}
