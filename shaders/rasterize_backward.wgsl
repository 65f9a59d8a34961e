// Backward blend: one workgroup per 16x16 tile, one invocation per pixel, front to back
// over the tile's pairs in the forward's order, up to the pixel's last contributing pair
// (n_contrib.x). With Z = image . v + T_final * v_T (the pixel's whole loss) and
// acc_j = (colour accumulated up to and including j) . v, the derivative of alpha_j is
//   dL/d alpha_j = T_j (c_j(p) . v) - (Z - acc_j) / (1 - alpha_j),
// which needs no division of T (no error growth through deep stacks). T, acc, Z and
// the pixel's last pair come from `state` (backward_prepare) and go back to it, so the
// rounds can be split over several dispatches (PassParams).
//
// Deterministic and atomic-free for floats: the triangles are taken RB at a time; every
// pixel writes its per-(pixel, triangle) record (colour weight alpha*T with the argmin
// edge in its two lowest mantissa bits, dL/d ratio, dL/d o) to workgroup memory; then
// fixed groups of invocations sum the records in a fixed pixel order into the 19
// statistics of grad_stats.wgsl (each invocation: one quantity, its three moments, over
// 32 pixels; then the 8 partial sums in order), written per sorted pair index to
// `partials` (pairs past the tile's last contribution stay zero). Three barriers per round.
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

const RB: u32 = 4u;          // triangles per round
const KINDS: u32 = 7u;       // summed quantities: colour weight x v (rgb), dL/d ratio per argmin edge (3), dL/d o
const HELPERS: u32 = 8u;     // invocations per (triangle, quantity), each summing 32 pixels
const PIX_PER_HELPER: u32 = 32u;

var<workgroup> rtris: array<Tri2D, 4>;
var<workgroup> rec_w: array<f32, 1024>;    // [RB, 256] alpha * T, argmin edge in the low 2 bits (0: none)
var<workgroup> rec_vr: array<f32, 1024>;   // [RB, 256] dL/d ratio
var<workgroup> rec_vo: array<f32, 1024>;   // [RB, 256] dL/d o
var<workgroup> part: array<f32, 672>;      // [RB, KINDS, HELPERS, 3 moments]
var<workgroup> live: array<atomic<u32>, 4>;
var<workgroup> max_last: atomic<u32>;
var<workgroup> rounds_shared: u32;

@compute @workgroup_size(16, 16)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let px = wid.x * TILE + lid.x;
    let py = wid.y * TILE + lid.y;
    let inside = px < params.width && py < params.height;
    let tile = wid.y * params.tiles_x + wid.x;
    let range = ranges[tile];
    let p = vec2<f32>(f32(px) + 0.5, f32(py) + 0.5);
    let sigma = params.sigma;
    if (li == 0u) {
        atomicStore(&max_last, 0u);
    }
    var last = 0u;
    var T = 1.0;
    var acc = 0.0;
    var Z = 0.0;
    var vout = vec3<f32>(0.0);
    let pix = py * params.width + px;
    if (inside) {
        let st = state[pix];
        T = st.x;
        acc = st.y;
        Z = st.z;
        last = bitcast<u32>(st.w);
        vout = v_out[pix].xyz;
    }
    workgroupBarrier();
    if (inside) {
        atomicMax(&max_last, last);
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
        if (range.x + round_begin * RB + li < range.y) {
            rtris[li] = tris[pair_tris[range.x + round_begin * RB + li]];
        }
        atomicStore(&live[li], 0u);
    }
    workgroupBarrier();
    for (var b = round_begin; b < round_end; b++) {
        let first = range.x + b * RB;
        // ---- phase 1: per pixel, the forward's decisions and the per-pair records
        for (var j = 0u; j < RB; j++) {
            var w = 0.0;
            var vr = 0.0;
            var vo = 0.0;
            var kmin = 0u;
            if (b * RB + j < last) {
                let t = rtris[j];
                let d = p - t.s;
                let e0 = 1.0 + dot(t.g0, d);
                let e1 = 1.0 + dot(t.g1, d);
                let e2 = 1.0 + dot(t.g2, d);
                let ratio = min(min(e0, e1), e2);
                // same decisions as rasterize_forward (ratio < tau: alpha < 1/255)
                if (ratio > 0.0 && ratio >= t.tau) {
                    let win = exp2(sigma * log2(ratio));
                    let oi = t.opacity * win;
                    let alpha = min(ALPHA_MAX, oi);
                    if (alpha >= ALPHA_MIN) {
                        let c = t.color.xyz + t.dcolor_dx.xyz * d.x + t.dcolor_dy.xyz * d.y;
                        let cv = dot(c, vout);
                        w = alpha * T;
                        acc += cv * w;
                        let v_alpha = T * cv - (Z - acc) / (1.0 - alpha);
                        if (oi < ALPHA_MAX) {
                            vo = v_alpha * win;
                            vr = v_alpha * t.opacity * sigma * win / ratio;
                        }
                        kmin = select(select(2u, 1u, e1 <= e2), 0u, e0 <= e1 && e0 <= e2);
                        T = T * (1.0 - alpha);
                        atomicOr(&live[j], 1u);
                    }
                }
            }
            let slot = j * 256u + li;
            rec_w[slot] = bitcast<f32>((bitcast<u32>(w) & 0xfffffffcu) | kmin);
            rec_vr[slot] = vr;
            rec_vo[slot] = vo;
        }
        workgroupBarrier();
        // ---- phase 2: (triangle, quantity, helper): the quantity times 1, d.x, d.y over 32 pixels
        if (li < RB * KINDS * HELPERS) {
            let j = li / (KINDS * HELPERS);
            let kind = (li / HELPERS) % KINDS;
            let i0 = (li % HELPERS) * PIX_PER_HELPER;
            var s0 = 0.0;
            var s1 = 0.0;
            var s2 = 0.0;
            if (atomicLoad(&live[j]) != 0u) {
                let s = rtris[j].s;
                for (var i = i0; i < i0 + PIX_PER_HELPER; i++) {
                    let slot = j * 256u + i;
                    let qx = wid.x * TILE + (i % TILE);
                    let qy = wid.y * TILE + i / TILE;
                    let bits = bitcast<u32>(rec_w[slot]);
                    var val = 0.0;
                    if (kind < 3u) {
                        let wt = bitcast<f32>(bits & 0xfffffffcu);
                        if (wt != 0.0) {
                            val = wt * v_out[qy * params.width + qx][kind];
                        }
                    } else if (kind < 6u) {
                        val = select(0.0, rec_vr[slot], (bits & 3u) == kind - 3u);
                    } else {
                        val = rec_vo[slot];
                    }
                    let d = vec2<f32>(f32(qx) + 0.5, f32(qy) + 0.5) - s;
                    s0 += val;
                    s1 += val * d.x;
                    s2 += val * d.y;
                }
            }
            part[3u * li] = s0;
            part[3u * li + 1u] = s1;
            part[3u * li + 2u] = s2;
        }
        workgroupBarrier();
        // ---- phase 3: the HELPERS partial sums in a fixed order, one pair per triangle;
        // meanwhile other invocations stage the next round's triangles
        if (li < RB * NSTAT) {
            let j = li / NSTAT;
            let q = li % NSTAT;
            if (first + j < range.y) {
                var kind = 6u;
                var m = 0u;
                if (q < 9u) {
                    kind = q / 3u;
                    m = q % 3u;
                } else if (q < 18u) {
                    kind = 3u + (q - 9u) / 3u;
                    m = (q - 9u) % 3u;
                }
                var sum = 0.0;
                if (q < 19u) {
                    for (var h = 0u; h < HELPERS; h++) {
                        sum += part[3u * ((j * KINDS + kind) * HELPERS + h) + m];
                    }
                }
                partials[(first + j) * NSTAT + q] = sum;
            }
        } else if (li >= 128u && li < 128u + RB) {
            let j = li - 128u;
            let nxt = first + RB + j;
            if (b + 1u < round_end && nxt < range.y) {
                rtris[j] = tris[pair_tris[nxt]];
            }
            atomicStore(&live[j], 0u);
        }
        workgroupBarrier();
    }
    if (inside) {
        state[pix] = vec4<f32>(T, acc, Z, bitcast<f32>(last));
    }
}
