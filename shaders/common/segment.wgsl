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
    width: u32,    // vec4s per element (at most MAX_WIDTH)
    gather: u32,   // 1: level 0, values through index
    top: u32,      // 1: coarsest level (n <= CHUNK), every run start writes its whole run
}

const CHUNK: u32 = 64u;
const MAX_WIDTH: u32 = 5u;

fn seg_value(sp: SegParams, i: u32, w: u32) -> vec4<f32> {
    var e = i;
    if (sp.gather != 0u) {
        e = index[i];
    }
    return vals_in[e * sp.width + w];
}

// Sum of the run of `key` from element i (inclusive) up to `end` (exclusive).
fn seg_run(sp: SegParams, i: u32, end: u32, key: u32) -> array<vec4<f32>, 5> {
    var s: array<vec4<f32>, 5>;
    var live = true;
    for (var e = i; e < end; e++) {
        live = live && keys_in[e] == key;
        if (live) {
            for (var w = 0u; w < sp.width; w++) {
                s[w] += seg_value(sp, e, w);
            }
        }
    }
    return s;
}
