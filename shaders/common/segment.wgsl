// Deterministic segmented sum with bounded work per invocation (lavapipe's loop budget,
// see frame.wgsl), shared by segment_up and segment_down.
//
// Input (level 0): n elements with sorted segment keys; element i's value is `width`
// vec4s, read at vals[index[i] * width + w] (level 0 gathers through `index`) or at
// vals[i * width + w] (higher levels). Level l + 1 has one element per chunk of CHUNK
// elements of level l: the sum of the chunk's leading run (its elements whose key is
// the chunk's first key), keyed by that key. Then, from the coarsest level (at most
// CHUNK elements) down to level 0, the invocation at each run start that is not at a
// chunk start adds its run's elements within its chunk to out[key]:
//   total_l(key) = head_l(key) + total_{l+1}(key)
// Every sum has a fixed order that depends only on the keys, so the result is
// bit-identical from run to run, and no invocation reads more than CHUNK elements.

struct SegParams {
    n: u32,        // elements at this level
    width: u32,    // vec4s per element: 1, 2 or 5
    gather: u32,   // 1: level 0, values through index
    top: u32,      // 1: coarsest level (n <= CHUNK), every run start writes its whole run
    // Arrays larger than one storage binding, bound a page at a time (tsplus_wgpu.gpu.chunks):
    // vals_in holds the values [val_lo, val_hi) of the gather (the others count 0: a sum over
    // pages adds the passes), out the keys [key_lo, key_hi) (the others are not written).
    val_lo: u32,
    val_hi: u32,
    key_lo: u32,
    key_hi: u32,
}

const CHUNK: u32 = 64u;

struct Sum5 {
    a: vec4<f32>,
    b: vec4<f32>,
    c: vec4<f32>,
    d: vec4<f32>,
    e: vec4<f32>,
}

// Sum of the run of `key` from element i (inclusive) up to `end` (exclusive), in order.
// (Five named sums rather than an indexed array: no private-memory indexing.)
fn seg_run(sp: SegParams, i: u32, end: u32, key: u32) -> Sum5 {
    var s = Sum5(vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0));
    for (var e = i; e < end; e++) {
        if (keys_in[e] != key) {
            break;
        }
        var base = e;
        if (sp.gather != 0u) {
            base = index[e];
            if (base - sp.val_lo >= sp.val_hi - sp.val_lo) {
                continue;   // another page's value (base < val_lo wraps)
            }
            base -= sp.val_lo;
        }
        base *= sp.width;
        s.a += vals_in[base];
        if (sp.width > 1u) {
            s.b += vals_in[base + 1u];
        }
        if (sp.width > 2u) {
            s.c += vals_in[base + 2u];
            s.d += vals_in[base + 3u];
            s.e += vals_in[base + 4u];
        }
    }
    return s;
}

fn seg_get(s: Sum5, w: u32) -> vec4<f32> {
    switch (w) {
        case 0u: { return s.a; }
        case 1u: { return s.b; }
        case 2u: { return s.c; }
        case 3u: { return s.d; }
        default: { return s.e; }
    }
}
