// Triangle-ID buffer: per pixel, the triangle with the largest blending weight alpha * T,
// walking the same depth-sorted tile lists as rasterize_forward with the same model
// (window, 1/255 skip, alpha cap, stop before T < 1e-4). Ties go to the front-most
// triangle (the weight must grow strictly to replace the current best); 0xFFFFFFFF where
// no triangle contributes. A separate pass, dispatched only when asked for, so the normal
// forward blend does not pay for it.
//
// Layout as the forward blend: one workgroup of 16 invocations per 16x16 tile, each
// invocation holds the 16 pixels of one column as four vec4 groups; triangles staged
// 128 at a time in workgroup memory (only the window part of Tri2D: no colour).
// Tiles longer than one pass (32768 pairs, lavapipe's loop budget) are walked in several
// dispatches; between them a pixel's state lives in id_state:
// (best triangle, best weight bits, T bits, stopped flag).
#import frame
#import triangle
#import window4

struct BlendPass {
    begin: u32,   // window of pairs [begin, end) within every tile's range
    end: u32,
    first: u32,   // 1: no state to resume
    last: u32,    // 1: write the final IDs
}

@group(0) @binding(0) var<uniform> params: FrameParams;
@group(0) @binding(1) var<storage, read> ranges: array<vec2<u32>>;          // [tiles]
@group(0) @binding(2) var<storage, read> pair_tris: array<u32>;             // [P] sorted
@group(0) @binding(3) var<storage, read> tris: array<Tri2D>;                // [M]
@group(0) @binding(4) var<storage, read_write> id_state: array<vec4<u32>>;  // [H, W]
@group(0) @binding(5) var<storage, read_write> triangle_ids: array<u32>;    // [H, W]
@group(0) @binding(6) var<uniform> pass_: BlendPass;

const BATCH: u32 = 128u;
const NONE: u32 = 0xFFFFFFFFu;
const THREADS: u32 = 16u;

// [0] s.x, s.y, opacity, tau   [1] g0, g1   [2] g2, depth, inradius
var<workgroup> staged: array<vec4<f32>, 384>;
var<workgroup> batch_ids: array<u32, 128>;
var<workgroup> num_done: atomic<u32>;
var<workgroup> num_done_seen: u32;

struct Ids4 {
    y: vec4<f32>,
    T: vec4<f32>,
    best_w: vec4<f32>,
    best: vec4<u32>,
    done: vec4<bool>,
}


// One triangle over four pixels (where live): the forward blend's weight and T update,
// keeping the triangle whose weight beats the best so far.
fn visit4(q: ptr<function, Ids4>, live: vec4<bool>, ratio: vec4<f32>, opacity: f32, sigma: f32, id: u32) {
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

@compute @workgroup_size(16)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let px = wid.x * TILE + li;
    let row0 = wid.y * TILE;
    let tile = wid.y * params.tiles_x + wid.x;
    let range = ranges[tile];
    let x = f32(px) + 0.5;
    let sigma = params.sigma;

    var q: array<Ids4, 4>;
    var ndone = 0u;
    for (var g = 0u; g < 4u; g++) {
        let py = vec4<u32>(row0 + 4u * g) + vec4<u32>(0u, 1u, 2u, 3u);
        let inside = (py < vec4<u32>(params.height)) & vec4<bool>(px < params.width);
        q[g].y = vec4<f32>(py) + 0.5;
        q[g].T = vec4<f32>(1.0);
        q[g].best_w = vec4<f32>(0.0);
        q[g].best = vec4<u32>(NONE);
        q[g].done = !inside;
        if (pass_.first == 0u) {
            for (var k = 0u; k < 4u; k++) {
                if (inside[k]) {
                    let st = id_state[py[k] * params.width + px];
                    q[g].best[k] = st.x;
                    q[g].best_w[k] = bitcast<f32>(st.y);
                    q[g].T[k] = bitcast<f32>(st.z);
                    q[g].done[k] = st.w != 0u;
                }
            }
        }
        ndone += dot(select(vec4<u32>(0u), vec4<u32>(1u), q[g].done), vec4<u32>(1u));
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
            let t = tris[id];
            batch_ids[h] = id;
            staged[3u * h] = vec4<f32>(t.s, t.opacity, t.tau);
            staged[3u * h + 1u] = vec4<f32>(t.g0, t.g1);
            staged[3u * h + 2u] = vec4<f32>(t.g2, t.depth, t.inradius);
        }
        workgroupBarrier();
        for (var j = 0u; j < count; j++) {
            let w0 = staged[3u * j];
            let w1 = staged[3u * j + 1u];
            let w2 = staged[3u * j + 2u];
            let dx = x - w0.x;
            let a = vec3<f32>(1.0 + w1.x * dx, 1.0 + w1.z * dx, 1.0 + w2.x * dx);
            let gy = vec3<f32>(w1.y, w1.w, w2.y);
            let tau = vec4<f32>(w0.w);
            let zero = vec4<f32>(0.0);
            let r0 = ratio4(q0.y - w0.y, a, gy);
            let r1 = ratio4(q1.y - w0.y, a, gy);
            let r2 = ratio4(q2.y - w0.y, a, gy);
            let r3 = ratio4(q3.y - w0.y, a, gy);
            let l0 = !q0.done & (r0 > zero) & (r0 >= tau);
            let l1 = !q1.done & (r1 > zero) & (r1 >= tau);
            let l2 = !q2.done & (r2 > zero) & (r2 >= tau);
            let l3 = !q3.done & (r3 > zero) & (r3 >= tau);
            if (any(l0 | l1 | l2 | l3)) {
                let id = batch_ids[j];
                visit4(&q0, l0, r0, w0.z, sigma, id);
                visit4(&q1, l1, r1, w0.z, sigma, id);
                visit4(&q2, l2, r2, w0.z, sigma, id);
                visit4(&q3, l3, r3, w0.z, sigma, id);
            }
        }
        workgroupBarrier();
    }
    q[0] = q0;
    q[1] = q1;
    q[2] = q2;
    q[3] = q3;
    for (var g = 0u; g < 4u; g++) {
        for (var k = 0u; k < 4u; k++) {
            let py = row0 + 4u * g + k;
            if (py < params.height && px < params.width) {
                let pix = py * params.width + px;
                id_state[pix] = vec4<u32>(q[g].best[k], bitcast<u32>(q[g].best_w[k]), bitcast<u32>(q[g].T[k]),
                                          select(0u, 1u, q[g].done[k]));
                if (pass_.last != 0u) {
                    triangle_ids[pix] = q[g].best[k];
                }
            }
        }
    }
}
