// Forward blend: one workgroup of 8 invocations per 16x16 tile; invocation i blends the 32
// pixels of columns i and i + 8, as eight groups of 4 held in the lanes of vec4s, so every
// triangle record read from workgroup memory serves 32 pixels. Triangles of the tile arrive
// in depth order in batches of 128 staged in workgroup memory.
//
// Why 8 x 32 (llvmpipe, Mesa 22.3; docs/measurements.md, "The forward blend's shape on
// llvmpipe"): a pair costs mostly what is paid once per trip of the pair loop (its record's
// loads, the branch on any pixel being live, the loop), not per pixel, and 8 invocations
// presumably fill one row of llvmpipe's 8 float lanes instead of two. The same blend with 16 invocations of
// one column was 10-13 % slower per forward on the shared scenes' initial meshes; 4 of four
// columns slower again (and 50 s to compile); skipping rows a triangle misses, in four
// loops, 25 % slower.
//   I = max(0, min_k e_k(p))^sigma, alpha = min(0.99, o I), skip alpha < 1/255,
//   stop before T would fall below 1e-4; C += c(p) alpha T; T *= 1 - alpha.
// Outputs the image (C + T background), final T, per pixel (x) the number of pairs of
// its tile up to and including the last one that contributed (for the backward pass)
// and (y) the number of pairs it evaluated, and per triangle the largest alpha * T.
//
// A tile with more than PASS_PAIRS pairs is blended in several dispatches (lavapipe's loop
// budget, see frame.wgsl); between them the pixel state lives in the output buffers:
// C (without background) in image, T in final_t, (last, evaluated) in n_contrib with
// the "stopped" flag in bit 31 of y.
//
// TRIANGLE_IDS (pipeline-overridable, host class RasterizeIds) makes the same walk the
// triangle-ID pass: per pixel the triangle with the largest blending weight alpha * T, ties
// to the front-most (the weight must grow strictly), 0xFFFFFFFF where none contributes.
// It writes no image, max_weight or work (bind placeholders there); final_t holds its T
// and n_contrib its (best triangle, best weight bits), with the "stopped" flag between
// passes in bit 31 of y (weights are positive: the sign bit is free). Sharing the slots
// keeps both variants within the 8 storage buffers per stage of WebGPU's default limits.
#import frame
#import triangle
#import window4
#import blend_pass

@group(0) @binding(0) var<uniform> params: FrameParams;
@group(0) @binding(1) var<storage, read> ranges: array<vec2<u32>>;   // [tiles]
@group(0) @binding(2) var<storage, read> pair_tris: array<u32>;      // [P] sorted
@group(0) @binding(3) var<storage, read> tris: array<Tri2D>;         // [M], or [window] when gathered
@group(0) @binding(4) var<storage, read_write> image: array<f32>;    // [H, W, 3]
@group(0) @binding(5) var<storage, read_write> final_t: array<f32>;  // [H, W]
// [H, W] (last, evaluated); with TRIANGLE_IDS (best triangle, best weight bits)
@group(0) @binding(6) var<storage, read_write> n_contrib: array<vec2<u32>>;
@group(0) @binding(7) var<storage, read_write> max_weight: array<atomic<u32>>;  // [M] f32 bits
@group(0) @binding(8) var<uniform> pass_: BlendPass;
// Work done, for the benchmark's FLOP count: [0] evaluations that reached the power
// (ratio >= tau), [1] contributions.
@group(0) @binding(9) var<storage, read_write> work: array<atomic<u32>>;  // [2]

override TRIANGLE_IDS: bool = false;   // the triangle-ID pass instead of the image

const BATCH: u32 = 128u;
const STOPPED: u32 = 0x80000000u;
const NONE: u32 = 0xFFFFFFFFu;     // triangle ID where no triangle contributes
const THREADS: u32 = 8u;           // one invocation per two columns of the tile (li, li + 8): 32 pixels
// Pairs per tile that one dispatch blends at most: each pair costs one trip of the blend
// loop, each batch 1 + 2 * BATCH / THREADS more, within lavapipe's 65535 (frame.wgsl).
const PASS_PAIRS: u32 = 256u * BATCH;

// The staged records as raw vec4s (6 per triangle, the layout of Tri2D): a load from
// workgroup memory is costly per instruction on CPU drivers, so each is a whole vec4.
//   [0] s.x, s.y, opacity, tau   [1] g0, g1   [2] g2, depth, inradius
//   [3] colour at s              [4] d colour / dx   [5] d colour / dy
var<workgroup> staged: array<vec4<f32>, 768>;
var<workgroup> batch_ids: array<u32, 128>;
var<workgroup> batch_maxw: array<atomic<u32>, 128>;
var<workgroup> num_done: atomic<u32>;
var<workgroup> num_done_seen: u32;

// Four pixels of one column, blended together in the lanes of vec4s.
struct Px4 {
    y: vec4<f32>,
    T: vec4<f32>,
    cr: vec4<f32>,
    cg: vec4<f32>,
    cb: vec4<f32>,
    last: vec4<u32>,
    evaluated: vec4<u32>,
    done: vec4<bool>,
    powered: vec4<u32>,
    added: vec4<u32>,
    best_w: vec4<f32>,   // TRIANGLE_IDS: the largest weight alpha * T so far
    best: vec4<u32>,     // TRIANGLE_IDS: its triangle
}

// Window ratio min_k e_k at four pixels of a column: e_k = a_k + gy_k (y - s.y), with the
// column's share a_k = 1 + gx_k (x - s.x) computed once per triangle.

// Blend the staged triangle into the four pixels where live; returns the largest weight.
fn blend4(q: ptr<function, Px4>, live: vec4<bool>, ratio: vec4<f32>, opacity: f32, c0: vec4<f32>,
          cx: vec4<f32>, cy: vec4<f32>, dx: f32, sigma: f32, index: u32) -> f32 {
    if (!any(live)) {
        return 0.0;
    }
    (*q).powered += select(vec4<u32>(0u), vec4<u32>(1u), live);
    let alpha = alpha4(ratio, opacity, sigma);
    let valid = live & (alpha >= vec4<f32>(ALPHA_MIN));
    let next_t = (*q).T * (1.0 - alpha);
    let stop = valid & (next_t < vec4<f32>(T_MIN));
    let add = valid & !stop;
    let w = select(vec4<f32>(0.0), alpha * (*q).T, add);
    (*q).added += select(vec4<u32>(0u), vec4<u32>(1u), add);
    let dy = (*q).y - c0.w;   // c0.w carries s.y (see staging)
    (*q).cr += (c0.x + cx.x * dx + cy.x * dy) * w;
    (*q).cg += (c0.y + cx.y * dx + cy.y * dy) * w;
    (*q).cb += (c0.z + cx.z * dx + cy.z * dy) * w;
    (*q).T = select((*q).T, next_t, add);
    (*q).last = select((*q).last, vec4<u32>(index), add);
    if (any(stop)) {
        (*q).done = (*q).done | stop;
        (*q).evaluated = select((*q).evaluated, vec4<u32>(index), stop);   // pairs visited
        atomicAdd(&num_done, dot(select(vec4<u32>(0u), vec4<u32>(1u), stop), vec4<u32>(1u)));
    }
    return max(max(w.x, w.y), max(w.z, w.w));
}

// TRIANGLE_IDS: the same weight and T update as blend4, keeping the triangle whose weight
// beats the best so far.
fn visit4(q: ptr<function, Px4>, live: vec4<bool>, ratio: vec4<f32>, opacity: f32, sigma: f32, id: u32) {
    if (!any(live)) {
        return;
    }
    let alpha = alpha4(ratio, opacity, sigma);
    let valid = live & (alpha >= vec4<f32>(ALPHA_MIN));
    let next_t = (*q).T * (1.0 - alpha);
    let stop = valid & (next_t < vec4<f32>(T_MIN));
    let add = valid & !stop;
    let w = alpha * (*q).T;
    let better = add & (w > (*q).best_w);
    (*q).best_w = select((*q).best_w, w, better);
    (*q).best = select((*q).best, vec4<u32>(id), better);
    (*q).T = select((*q).T, next_t, add);
    if (any(stop)) {
        (*q).done = (*q).done | stop;
        atomicAdd(&num_done, dot(select(vec4<u32>(0u), vec4<u32>(1u), stop), vec4<u32>(1u)));
    }
}

@compute @workgroup_size(THREADS)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let row0 = wid.y * TILE;
    let tile = wid.y * params.tiles_x + wid.x;
    let range = ranges[tile];
    if (range.x < pass_.pair_lo || range.x >= pass_.pair_hi) {   // another window's tile (uniform)
        return;
    }
    let xa = f32(wid.x * TILE + li) + 0.5;
    let xb = xa + 8.0;
    let sigma = params.sigma;

    // q[4c + g]: column c (li, li + 8), rows 4g..4g+3
    var q: array<Px4, 8>;
    var ndone = 0u;
    for (var i = 0u; i < 8u; i++) {
        let px = wid.x * TILE + li + 8u * (i / 4u);
        let py = vec4<u32>(row0 + 4u * (i % 4u)) + vec4<u32>(0u, 1u, 2u, 3u);
        let inside = (py < vec4<u32>(params.height)) & vec4<bool>(px < params.width);
        q[i].y = vec4<f32>(py) + 0.5;
        q[i].T = vec4<f32>(1.0);
        q[i].done = !inside;
        if (TRIANGLE_IDS) {
            q[i].best_w = vec4<f32>(0.0);
            q[i].best = vec4<u32>(NONE);
        }
        if (pass_.first == 0u) {
            for (var k = 0u; k < 4u; k++) {
                if (inside[k]) {
                    let pix = py[k] * params.width + px;
                    let st = n_contrib[pix];
                    q[i].T[k] = final_t[pix];
                    q[i].done[k] = (st.y & STOPPED) != 0u;
                    if (TRIANGLE_IDS) {
                        q[i].best[k] = st.x;
                        q[i].best_w[k] = bitcast<f32>(st.y & ~STOPPED);
                    } else {
                        q[i].cr[k] = image[3u * pix];
                        q[i].cg[k] = image[3u * pix + 1u];
                        q[i].cb[k] = image[3u * pix + 2u];
                        q[i].last[k] = st.x;
                        q[i].evaluated[k] = st.y & ~STOPPED;
                    }
                }
            }
        }
        ndone += dot(select(vec4<u32>(0u), vec4<u32>(1u), q[i].done), vec4<u32>(1u));
    }
    if (li == 0u) {
        atomicStore(&num_done, 0u);
    }
    workgroupBarrier();
    if (ndone != 0u) {
        atomicAdd(&num_done, ndone);
    }
    var q0 = q[0];
    var q1 = q[1];
    var q2 = q[2];
    var q3 = q[3];
    var q4 = q[4];
    var q5 = q[5];
    var q6 = q[6];
    var q7 = q[7];
    let lo = min(range.x + pass_.begin, range.y);
    let hi = min(range.x + pass_.end, range.y);
    let num_batches = (hi - lo + BATCH - 1u) / BATCH;
    for (var b = 0u; b < num_batches; b++) {
        if (li == 0u) {
            num_done_seen = atomicLoad(&num_done);
        }
        if (workgroupUniformLoad(&num_done_seen) == TILE * TILE) {
            break;
        }
        let first = lo + b * BATCH;
        let count = min(BATCH, hi - first);
        for (var h = li; h < count; h += THREADS) {
            let id = pair_tris[first + h];
            let t = tris[select(id, first + h - pass_.pair_lo, pass_.gathered != 0u)];
            batch_ids[h] = id;
            staged[6u * h] = vec4<f32>(t.s, t.opacity, t.tau);
            staged[6u * h + 1u] = vec4<f32>(t.g0, t.g1);
            staged[6u * h + 2u] = vec4<f32>(t.g2, t.depth, t.inradius);
            if (!TRIANGLE_IDS) {
                staged[6u * h + 3u] = vec4<f32>(t.color.xyz, t.s.y);
                staged[6u * h + 4u] = t.dcolor_dx;
                staged[6u * h + 5u] = t.dcolor_dy;
                atomicStore(&batch_maxw[h], 0u);
            }
        }
        workgroupBarrier();
        // Uniform trip count, no break/continue: j stays uniform across the workgroup.
        for (var j = 0u; j < count; j++) {
            let w0 = staged[6u * j];
            let w1 = staged[6u * j + 1u];
            let w2 = staged[6u * j + 2u];
            let dxa = xa - w0.x;
            let dxb = xb - w0.x;
            let aa = vec3<f32>(1.0 + w1.x * dxa, 1.0 + w1.z * dxa, 1.0 + w2.x * dxa);
            let ab = vec3<f32>(1.0 + w1.x * dxb, 1.0 + w1.z * dxb, 1.0 + w2.x * dxb);
            let gy = vec3<f32>(w1.y, w1.w, w2.y);
            let tau = vec4<f32>(w0.w);
            let zero = vec4<f32>(0.0);
            // ratio < tau means alpha < 1/255: no power needed
            let r0 = ratio4(q0.y - w0.y, aa, gy);
            let r1 = ratio4(q1.y - w0.y, aa, gy);
            let r2 = ratio4(q2.y - w0.y, aa, gy);
            let r3 = ratio4(q3.y - w0.y, aa, gy);
            let r4 = ratio4(q4.y - w0.y, ab, gy);
            let r5 = ratio4(q5.y - w0.y, ab, gy);
            let r6 = ratio4(q6.y - w0.y, ab, gy);
            let r7 = ratio4(q7.y - w0.y, ab, gy);
            let l0 = !q0.done & (r0 > zero) & (r0 >= tau);
            let l1 = !q1.done & (r1 > zero) & (r1 >= tau);
            let l2 = !q2.done & (r2 > zero) & (r2 >= tau);
            let l3 = !q3.done & (r3 > zero) & (r3 >= tau);
            let l4 = !q4.done & (r4 > zero) & (r4 >= tau);
            let l5 = !q5.done & (r5 > zero) & (r5 >= tau);
            let l6 = !q6.done & (r6 > zero) & (r6 >= tau);
            let l7 = !q7.done & (r7 > zero) & (r7 >= tau);
            if (any(l0 | l1 | l2 | l3 | l4 | l5 | l6 | l7)) {
                // TRIANGLE_IDS is a pipeline constant: the compiler keeps one branch
                if (TRIANGLE_IDS) {
                    let id = batch_ids[j];
                    visit4(&q0, l0, r0, w0.z, sigma, id);
                    visit4(&q1, l1, r1, w0.z, sigma, id);
                    visit4(&q2, l2, r2, w0.z, sigma, id);
                    visit4(&q3, l3, r3, w0.z, sigma, id);
                    visit4(&q4, l4, r4, w0.z, sigma, id);
                    visit4(&q5, l5, r5, w0.z, sigma, id);
                    visit4(&q6, l6, r6, w0.z, sigma, id);
                    visit4(&q7, l7, r7, w0.z, sigma, id);
                } else {
                    let c0 = staged[6u * j + 3u];
                    let cx = staged[6u * j + 4u];
                    let cy = staged[6u * j + 5u];
                    let index = first - range.x + j + 1u;
                    let wa = max(max(blend4(&q0, l0, r0, w0.z, c0, cx, cy, dxa, sigma, index),
                                     blend4(&q1, l1, r1, w0.z, c0, cx, cy, dxa, sigma, index)),
                                 max(blend4(&q2, l2, r2, w0.z, c0, cx, cy, dxa, sigma, index),
                                     blend4(&q3, l3, r3, w0.z, c0, cx, cy, dxa, sigma, index)));
                    let wb = max(max(blend4(&q4, l4, r4, w0.z, c0, cx, cy, dxb, sigma, index),
                                     blend4(&q5, l5, r5, w0.z, c0, cx, cy, dxb, sigma, index)),
                                 max(blend4(&q6, l6, r6, w0.z, c0, cx, cy, dxb, sigma, index),
                                     blend4(&q7, l7, r7, w0.z, c0, cx, cy, dxb, sigma, index)));
                    let wmax = max(wa, wb);
                    if (wmax > 0.0) {
                        atomicMax(&batch_maxw[j], bitcast<u32>(wmax));
                    }
                }
            }
        }
        workgroupBarrier();
        for (var h = li; h < count && !TRIANGLE_IDS; h += THREADS) {
            let w = atomicLoad(&batch_maxw[h]);
            if (w != 0u) {
                atomicMax(&max_weight[batch_ids[h]], w);
            }
        }
    }
    // pixels still running visited every pair of the window (stopped ones kept their index)
    let visited = vec4<u32>(hi - range.x);
    q0.evaluated = select(q0.evaluated, visited, !q0.done);
    q1.evaluated = select(q1.evaluated, visited, !q1.done);
    q2.evaluated = select(q2.evaluated, visited, !q2.done);
    q3.evaluated = select(q3.evaluated, visited, !q3.done);
    q4.evaluated = select(q4.evaluated, visited, !q4.done);
    q5.evaluated = select(q5.evaluated, visited, !q5.done);
    q6.evaluated = select(q6.evaluated, visited, !q6.done);
    q7.evaluated = select(q7.evaluated, visited, !q7.done);
    q[0] = q0;
    q[1] = q1;
    q[2] = q2;
    q[3] = q3;
    q[4] = q4;
    q[5] = q5;
    q[6] = q6;
    q[7] = q7;
    // One output loop for both variants (a helper function taking q by value made the ID
    // pass twice as slow on lavapipe).
    if (!TRIANGLE_IDS) {
        let one = vec4<u32>(1u);
        atomicAdd(&work[0], dot(q0.powered + q1.powered + q2.powered + q3.powered
                                + q4.powered + q5.powered + q6.powered + q7.powered, one));
        atomicAdd(&work[1], dot(q0.added + q1.added + q2.added + q3.added
                                + q4.added + q5.added + q6.added + q7.added, one));
    }
    for (var i = 0u; i < 8u; i++) {
        let px = wid.x * TILE + li + 8u * (i / 4u);
        for (var k = 0u; k < 4u; k++) {
            let py = row0 + 4u * (i % 4u) + k;
            if (py < params.height && px < params.width) {
                let pix = py * params.width + px;
                let flags = select(0u, STOPPED, pass_.last == 0u && q[i].done[k]);
                final_t[pix] = q[i].T[k];
                if (TRIANGLE_IDS) {
                    n_contrib[pix] = vec2<u32>(q[i].best[k], bitcast<u32>(q[i].best_w[k]) | flags);
                } else {
                    var out = vec3<f32>(q[i].cr[k], q[i].cg[k], q[i].cb[k]);
                    if (pass_.last != 0u) {
                        out += q[i].T[k] * params.background.xyz;
                    }
                    image[3u * pix] = out.x;
                    image[3u * pix + 1u] = out.y;
                    image[3u * pix + 2u] = out.z;
                    n_contrib[pix] = vec2<u32>(q[i].last[k], q[i].evaluated[k] | flags);
                }
            }
        }
    }
}
