// Backward blend: one workgroup per 16x16 tile, one invocation per pixel, front to back
// over the tile's pairs in the forward's order, up to the pixel's last contributing pair
// (n_contrib.x). With Z = image . v + T_final * v_T (the pixel's whole loss) and
// acc_j = (colour accumulated up to and including j) . v, the derivative of alpha_j is
//   dL/d alpha_j = T_j (c_j(p) . v) - (Z - acc_j) / (1 - alpha_j),
// which needs no division of T (no error growth through deep stacks).
//
// Deterministic and atomic-free for floats: the triangles are taken RB at a time; every
// pixel writes its per-(pixel, triangle) record (colour weight alpha*T, dL/d ratio with
// the argmin edge, dL/d o) to workgroup memory; then fixed groups of invocations sum the
// records in a fixed pixel order into the 19 statistics of grad_stats.wgsl, written per
// sorted pair index to `partials` (pairs past the tile's last contribution stay zero).
#import frame
#import triangle
#import grad_stats

@group(0) @binding(0) var<uniform> params: FrameParams;
@group(0) @binding(1) var<storage, read> ranges: array<vec2<u32>>;      // [tiles]
@group(0) @binding(2) var<storage, read> pair_tris: array<u32>;         // [P] sorted
@group(0) @binding(3) var<storage, read> tris: array<Tri2D>;            // [M]
@group(0) @binding(4) var<storage, read> image: array<f32>;             // [H, W, 3]
@group(0) @binding(5) var<storage, read> final_t: array<f32>;           // [H, W]
@group(0) @binding(6) var<storage, read> n_contrib: array<vec2<u32>>;   // [H, W]
@group(0) @binding(7) var<storage, read> v_out: array<vec4<f32>>;       // [H, W]: dL/d image (xyz), dL/d T (w)
@group(0) @binding(8) var<storage, read_write> partials: array<f32>;    // [P, NSTAT]

const RB: u32 = 2u;          // triangles per round (workgroup memory: 4 KiB of records each)
const HELPERS: u32 = 4u;     // invocations per statistic, each summing 64 pixels
const PIX_PER_HELPER: u32 = 64u;

var<workgroup> rtris: array<Tri2D, 2>;
var<workgroup> rec_w: array<f32, 512>;     // [RB, 256] alpha * T (0: no contribution)
var<workgroup> rec_vr: array<f32, 512>;    // [RB, 256] dL/d ratio
var<workgroup> rec_vo: array<f32, 512>;    // [RB, 256] dL/d o
var<workgroup> rec_k: array<u32, 512>;     // [RB, 256] argmin edge
var<workgroup> vo_r: array<f32, 256>;
var<workgroup> vo_g: array<f32, 256>;
var<workgroup> vo_b: array<f32, 256>;
var<workgroup> part: array<f32, 160>;      // [RB, NSTAT, HELPERS]
var<workgroup> live: array<atomic<u32>, 2>;
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
    workgroupBarrier();
    var last = 0u;
    var vout = vec3<f32>(0.0);
    var Z = 0.0;
    if (inside) {
        let pix = py * params.width + px;
        last = n_contrib[pix].x;
        let v = v_out[pix];
        vout = v.xyz;
        Z = dot(vec3<f32>(image[3u * pix], image[3u * pix + 1u], image[3u * pix + 2u]), vout) + final_t[pix] * v.w;
        atomicMax(&max_last, last);
    }
    vo_r[li] = vout.x;
    vo_g[li] = vout.y;
    vo_b[li] = vout.z;
    workgroupBarrier();
    if (li == 0u) {
        rounds_shared = (atomicLoad(&max_last) + RB - 1u) / RB;
    }
    let rounds = workgroupUniformLoad(&rounds_shared);
    var T = 1.0;
    var acc = 0.0;
    for (var b = 0u; b < rounds; b++) {
        let first = range.x + b * RB;
        if (li < RB) {
            if (first + li < range.y) {
                rtris[li] = tris[pair_tris[first + li]];
            }
            atomicStore(&live[li], 0u);
        }
        workgroupBarrier();
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
            rec_w[slot] = w;
            rec_vr[slot] = vr;
            rec_vo[slot] = vo;
            rec_k[slot] = kmin;
        }
        workgroupBarrier();
        // ---- phase 2: statistic q of triangle j, HELPERS partial sums of 64 pixels each
        if (li < RB * NSTAT * HELPERS) {
            let j = li / (NSTAT * HELPERS);
            let rem = li % (NSTAT * HELPERS);
            let q = rem / HELPERS;
            let i0 = (rem % HELPERS) * PIX_PER_HELPER;
            var sum = 0.0;
            if (atomicLoad(&live[j]) != 0u && q < 19u) {
                let s = rtris[j].s;
                var mom = 0u;
                if (q < 9u) {
                    mom = q % 3u;
                } else if (q < 18u) {
                    mom = (q - 9u) % 3u;
                }
                let ch = q / 3u;
                let kk = (q - 9u) / 3u;
                for (var i = i0; i < i0 + PIX_PER_HELPER; i++) {
                    let slot = j * 256u + i;
                    let d = vec2<f32>(f32(wid.x * TILE + (i % TILE)) + 0.5, f32(wid.y * TILE + i / TILE) + 0.5) - s;
                    var val: f32;
                    if (q < 9u) {
                        let vc = select(select(vo_b[i], vo_g[i], ch == 1u), vo_r[i], ch == 0u);
                        val = rec_w[slot] * vc;
                    } else if (q < 18u) {
                        val = select(0.0, rec_vr[slot], rec_k[slot] == kk);
                    } else {
                        val = rec_vo[slot];
                    }
                    sum += val * select(select(d.y, d.x, mom == 1u), 1.0, mom == 0u);
                }
            }
            part[li] = sum;
        }
        workgroupBarrier();
        // ---- phase 3: the HELPERS partial sums in a fixed order, one pair per triangle
        if (li < RB * NSTAT) {
            let j = li / NSTAT;
            let q = li % NSTAT;
            if (first + j < range.y) {
                var s = 0.0;
                for (var h = 0u; h < HELPERS; h++) {
                    s += part[(j * NSTAT + q) * HELPERS + h];
                }
                partials[(first + j) * NSTAT + q] = s;
            }
        }
        workgroupBarrier();
    }
}
