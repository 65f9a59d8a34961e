// Forward blend: one workgroup per 16x16 tile, one invocation per pixel. Triangles of
// the tile arrive in depth order in batches of 128 staged in workgroup memory.
//   I = max(0, min_k e_k(p))^sigma, alpha = min(0.99, o I), skip alpha < 1/255,
//   stop before T would fall below 1e-4; C += c(p) alpha T; T *= 1 - alpha.
// Outputs the image (C + T background), final T, per pixel (x) the number of pairs of
// its tile up to and including the last one that contributed (for the backward pass)
// and (y) the number of pairs it evaluated, and per triangle the largest alpha * T.
//
// A tile with more than BLEND_PASS_BATCHES * 128 pairs is blended in several dispatches
// (lavapipe's loop budget, see frame.wgsl); between them the pixel state lives in the
// output buffers: C (without background) in image, T in final_t, (last, evaluated) in
// n_contrib with the "stopped" flag in bit 31 of y.
#import frame
#import triangle

struct BlendPass {
    begin: u32,   // window of pairs [begin, end) within every tile's range
    end: u32,
    first: u32,   // 1: no state to resume
    last: u32,    // 1: write the final outputs
}

@group(0) @binding(0) var<uniform> params: FrameParams;
@group(0) @binding(1) var<storage, read> ranges: array<vec2<u32>>;   // [tiles]
@group(0) @binding(2) var<storage, read> pair_tris: array<u32>;      // [P] sorted
@group(0) @binding(3) var<storage, read> tris: array<Tri2D>;         // [M]
@group(0) @binding(4) var<storage, read_write> image: array<f32>;    // [H, W, 3]
@group(0) @binding(5) var<storage, read_write> final_t: array<f32>;  // [H, W]
@group(0) @binding(6) var<storage, read_write> n_contrib: array<vec2<u32>>;  // [H, W]
@group(0) @binding(7) var<storage, read_write> max_weight: array<atomic<u32>>;  // [M] f32 bits
@group(0) @binding(8) var<uniform> pass_: BlendPass;

const BATCH: u32 = 128u;
const STOPPED: u32 = 0x80000000u;

var<workgroup> batch_tris: array<Tri2D, 128>;
var<workgroup> batch_ids: array<u32, 128>;
var<workgroup> batch_maxw: array<atomic<u32>, 128>;
var<workgroup> num_done: atomic<u32>;
var<workgroup> num_done_seen: u32;

@compute @workgroup_size(16, 16)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let px = wid.x * TILE + lid.x;
    let py = wid.y * TILE + lid.y;
    let inside = px < params.width && py < params.height;
    let pix = py * params.width + px;
    let tile = wid.y * params.tiles_x + wid.x;
    let range = ranges[tile];
    let p = vec2<f32>(f32(px) + 0.5, f32(py) + 0.5);
    let sigma = params.sigma;

    var T = 1.0;
    var C = vec3<f32>(0.0);
    var last = 0u;
    var evaluated = 0u;
    var done = !inside;
    if (pass_.first == 0u && inside) {
        C = vec3<f32>(image[3u * pix], image[3u * pix + 1u], image[3u * pix + 2u]);
        T = final_t[pix];
        let st = n_contrib[pix];
        last = st.x;
        evaluated = st.y & ~STOPPED;
        done = (st.y & STOPPED) != 0u;
    }
    if (li == 0u) {
        atomicStore(&num_done, 0u);
    }
    workgroupBarrier();
    if (done) {
        atomicAdd(&num_done, 1u);
    }
    let lo = min(range.x + pass_.begin, range.y);
    let hi = min(range.x + pass_.end, range.y);
    let num_batches = (hi - lo + BATCH - 1u) / BATCH;
    for (var b = 0u; b < num_batches; b++) {
        if (li == 0u) {
            num_done_seen = atomicLoad(&num_done);
        }
        if (workgroupUniformLoad(&num_done_seen) == 256u) {
            break;
        }
        let first = lo + b * BATCH;
        let count = min(BATCH, hi - first);
        if (li < count) {
            let id = pair_tris[first + li];
            batch_ids[li] = id;
            batch_tris[li] = tris[id];
            atomicStore(&batch_maxw[li], 0u);
        }
        workgroupBarrier();
        // Structured loop with a uniform trip count and no break/continue, so that j
        // stays uniform and the staged records are read once per SIMD group.
        for (var j = 0u; j < count; j++) {
            if (!done) {
                evaluated++;
                let d = p - batch_tris[j].s;
                let ratio = min(min(1.0 + dot(batch_tris[j].g0, d), 1.0 + dot(batch_tris[j].g1, d)),
                                1.0 + dot(batch_tris[j].g2, d));
                // ratio < tau means alpha < 1/255: skip without evaluating the power
                if (ratio > 0.0 && ratio >= batch_tris[j].tau) {
                    let alpha = min(ALPHA_MAX, batch_tris[j].opacity * exp2(sigma * log2(ratio)));
                    if (alpha >= ALPHA_MIN) {
                        let next_t = T * (1.0 - alpha);
                        if (next_t < T_MIN) {
                            done = true;
                            atomicAdd(&num_done, 1u);
                        } else {
                            let c = batch_tris[j].color.xyz + batch_tris[j].dcolor_dx.xyz * d.x
                                    + batch_tris[j].dcolor_dy.xyz * d.y;
                            let w = alpha * T;
                            C += c * w;
                            atomicMax(&batch_maxw[j], bitcast<u32>(w));
                            T = next_t;
                            last = first - range.x + j + 1u;
                        }
                    }
                }
            }
        }
        workgroupBarrier();
        if (li < count) {
            let w = atomicLoad(&batch_maxw[li]);
            if (w != 0u) {
                atomicMax(&max_weight[batch_ids[li]], w);
            }
        }
    }
    if (inside) {
        var out = C;
        var flags = 0u;
        if (pass_.last != 0u) {
            out += T * params.background.xyz;
        } else if (done) {
            flags = STOPPED;
        }
        image[3u * pix] = out.x;
        image[3u * pix + 1u] = out.y;
        image[3u * pix + 2u] = out.z;
        final_t[pix] = T;
        n_contrib[pix] = vec2<u32>(last, evaluated | flags);
    }
}
