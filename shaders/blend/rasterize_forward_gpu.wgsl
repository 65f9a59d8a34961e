// Forward blend, the GPU layout: one workgroup of 256 invocations per 16x16 tile, one pixel
// each (lavapipe's layout, rasterize_forward.wgsl, gives each of 16 invocations a column of
// 16 pixels in the lanes of vec4s; a GPU's 32/64-wide SIMD units would idle on it). The same
// model, inputs, outputs, passes and windows as rasterize_forward.wgsl, whose header says
// what each output holds; the host picks one of the two (kernels/blend.py: forward_stage).
// Triangles of the tile arrive in depth order in batches of 128 staged in workgroup memory,
// one record per invocation; the workgroup stops when all its pixels have stopped.
//   I = max(0, min_k e_k(p))^sigma, alpha = min(0.99, o I), skip alpha < 1/255,
//   stop before T would fall below 1e-4; C += c(p) alpha T; T *= 1 - alpha.
// TRIANGLE_IDS: the triangle-ID pass, as in rasterize_forward.wgsl.
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
// [0] evaluations that reached the power (ratio >= tau), [1] contributions
@group(0) @binding(9) var<storage, read_write> work: array<atomic<u32>>;  // [2]

override TRIANGLE_IDS: bool = false;

const BATCH: u32 = 128u;
const STOPPED: u32 = 0x80000000u;
const NONE: u32 = 0xFFFFFFFFu;
const THREADS: u32 = 256u;         // one invocation per pixel of the tile
// Pairs per tile that one dispatch blends at most: one trip of the blend loop a pair and 2
// a batch, within lavapipe's 65535 loop iterations an invocation (frame.wgsl).
const PASS_PAIRS: u32 = 256u * BATCH;

// The staged records as raw vec4s, laid out as rasterize_forward.wgsl's:
//   [0] s.x, s.y, opacity, tau   [1] g0, g1   [2] g2, depth, inradius
//   [3] colour at s, s.y         [4] d colour / dx   [5] d colour / dy
var<workgroup> staged: array<vec4<f32>, 768>;
var<workgroup> batch_ids: array<u32, 128>;
var<workgroup> batch_maxw: array<atomic<u32>, 128>;
var<workgroup> num_done: atomic<u32>;
var<workgroup> num_done_seen: u32;
var<workgroup> counts: array<atomic<u32>, 2>;    // the tile's work counters

@compute @workgroup_size(THREADS)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let px = wid.x * TILE + li % TILE;
    let py = wid.y * TILE + li / TILE;
    let tile = wid.y * params.tiles_x + wid.x;
    let range = ranges[tile];
    if (range.x < pass_.pair_lo || range.x >= pass_.pair_hi) {   // another window's tile (uniform)
        return;
    }
    let inside = px < params.width && py < params.height;
    let pix = py * params.width + px;
    let x = f32(px) + 0.5;
    let y = f32(py) + 0.5;
    let sigma = params.sigma;

    var T = 1.0;
    var c = vec3<f32>(0.0);
    var last = 0u;
    var evaluated = 0u;
    var done = !inside;
    var best_w = 0.0;     // TRIANGLE_IDS: the largest weight alpha * T so far, and its triangle
    var best = NONE;
    var powered = 0u;
    var added = 0u;
    if (pass_.first == 0u && inside) {
        let st = n_contrib[pix];
        T = final_t[pix];
        done = (st.y & STOPPED) != 0u;
        if (TRIANGLE_IDS) {
            best = st.x;
            best_w = bitcast<f32>(st.y & ~STOPPED);
        } else {
            c = vec3<f32>(image[3u * pix], image[3u * pix + 1u], image[3u * pix + 2u]);
            last = st.x;
            evaluated = st.y & ~STOPPED;
        }
    }
    if (li == 0u) {
        atomicStore(&num_done, 0u);
        atomicStore(&counts[0], 0u);
        atomicStore(&counts[1], 0u);
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
        if (workgroupUniformLoad(&num_done_seen) == TILE * TILE) {
            break;
        }
        let first = lo + b * BATCH;
        let count = min(BATCH, hi - first);
        if (li < count) {
            let id = pair_tris[first + li];
            let t = tris[select(id, first + li - pass_.pair_lo, pass_.gathered != 0u)];
            batch_ids[li] = id;
            staged[6u * li] = vec4<f32>(t.s, t.opacity, t.tau);
            staged[6u * li + 1u] = vec4<f32>(t.g0, t.g1);
            staged[6u * li + 2u] = vec4<f32>(t.g2, t.depth, t.inradius);
            if (!TRIANGLE_IDS) {
                staged[6u * li + 3u] = vec4<f32>(t.color.xyz, t.s.y);
                staged[6u * li + 4u] = t.dcolor_dx;
                staged[6u * li + 5u] = t.dcolor_dy;
                atomicStore(&batch_maxw[li], 0u);
            }
        }
        workgroupBarrier();
        // Uniform trip count: j stays uniform across the workgroup (the barriers need it).
        for (var j = 0u; j < count; j++) {
            if (done) {
                continue;
            }
            let w0 = staged[6u * j];
            let w1 = staged[6u * j + 1u];
            let w2 = staged[6u * j + 2u];
            let dx = x - w0.x;
            let a = vec3<f32>(1.0 + w1.x * dx, 1.0 + w1.z * dx, 1.0 + w2.x * dx);
            let ratio = ratio1(y - w0.y, a, vec3<f32>(w1.y, w1.w, w2.y));
            if (!(ratio > 0.0 && ratio >= w0.w)) {    // ratio < tau means alpha < 1/255
                continue;
            }
            powered += 1u;
            let alpha = alpha1(ratio, w0.z, sigma);
            if (alpha < ALPHA_MIN) {
                continue;
            }
            let next_t = T * (1.0 - alpha);
            if (next_t < T_MIN) {
                done = true;
                atomicAdd(&num_done, 1u);
                if (!TRIANGLE_IDS) {
                    evaluated = first - range.x + j + 1u;   // pairs visited
                }
                continue;
            }
            let w = alpha * T;
            if (TRIANGLE_IDS) {
                if (w > best_w) {
                    best_w = w;
                    best = batch_ids[j];
                }
            } else {
                added += 1u;
                let c0 = staged[6u * j + 3u];
                let cx = staged[6u * j + 4u];
                let cy = staged[6u * j + 5u];
                let dy = y - c0.w;   // c0.w carries s.y
                c.x += (c0.x + cx.x * dx + cy.x * dy) * w;
                c.y += (c0.y + cx.y * dx + cy.y * dy) * w;
                c.z += (c0.z + cx.z * dx + cy.z * dy) * w;
                last = first - range.x + j + 1u;
                // most pixels lose to the tile's best so far: test before the atomic
                if (bitcast<u32>(w) > atomicLoad(&batch_maxw[j])) {
                    atomicMax(&batch_maxw[j], bitcast<u32>(w));
                }
            }
            T = next_t;
        }
        workgroupBarrier();
        if (!TRIANGLE_IDS && li < count) {
            let w = atomicLoad(&batch_maxw[li]);
            if (w != 0u) {
                atomicMax(&max_weight[batch_ids[li]], w);
            }
        }
    }
    // pixels still running visited every pair of the window (stopped ones kept their index)
    if (!done) {
        evaluated = hi - range.x;
    }
    if (!TRIANGLE_IDS) {
        if (powered != 0u) {
            atomicAdd(&counts[0], powered);
        }
        if (added != 0u) {
            atomicAdd(&counts[1], added);
        }
    }
    workgroupBarrier();
    if (!TRIANGLE_IDS && li == 0u) {
        atomicAdd(&work[0], atomicLoad(&counts[0]));
        atomicAdd(&work[1], atomicLoad(&counts[1]));
    }
    if (inside) {
        let flags = select(0u, STOPPED, pass_.last == 0u && done);
        final_t[pix] = T;
        if (TRIANGLE_IDS) {
            n_contrib[pix] = vec2<u32>(best, bitcast<u32>(best_w) | flags);
        } else {
            var out = c;
            if (pass_.last != 0u) {
                out += T * params.background.xyz;
            }
            image[3u * pix] = out.x;
            image[3u * pix + 1u] = out.y;
            image[3u * pix + 2u] = out.z;
            n_contrib[pix] = vec2<u32>(last, evaluated | flags);
        }
    }
}
