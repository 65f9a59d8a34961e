// Per key: the segmented sum of segment_up + segment_down (common/segment.wgsl) over elements
// of two vec4s each, with the very same additions in the very same order (so the same bits),
// but one invocation per key that reads only its own elements, instead of a pass over every
// element on each level. For keys sorted once and reused (the backward's corners sorted by
// vertex, once per topology), with each key's run [a, b) of the sorted elements given.
//
// The segmented sum's total for the run [a, b): on level l the run is [a_l, b_l) with
// a_{l+1} = ceil(a_l / CHUNK), b_{l+1} = ceil(b_l / CHUNK) (the chunks that start inside it);
// level l + 1's element c is the in-order sum of level l's [c * CHUNK, min((c + 1) * CHUNK, b_l)).
// The down-sweep, coarsest level first, does out = head_l + out at every level where the run
// does not start at a chunk start (head_l: its elements up to the end of that chunk), and at
// the top level (every run start, the whole run). No invocation reads more than its own run,
// and the host keeps runs short enough for lavapipe's loop budget (else it takes SegmentSum).
// (host: tsplus_wgpu.kernels.reduce.SegmentGather; twin: tsplus_wgpu.reference.reduce.segment_gather)
#import dispatch

struct GatherParams {
    count: u32,   // keys in this range (spans and out are bound from the range's first key)
    top: u32,     // the segmented sum's coarsest level over all the elements
    _pad0: u32,
    _pad1: u32,
}

const CHUNK: u32 = 64u;   // elements per chunk and level: common/segment.wgsl's (the host checks)

@group(0) @binding(0) var<uniform> gp: GatherParams;
@group(0) @binding(1) var<storage, read> spans: array<vec2<u32>>;     // [keys]: the run [a, b)
@group(0) @binding(2) var<storage, read> index: array<u32>;           // [n]: element -> value
@group(0) @binding(3) var<storage, read> vals: array<vec4<f32>>;      // [n, 2]
@group(0) @binding(4) var<storage, read_write> out: array<vec4<f32>>; // [keys, 2]

struct Pair {
    a: vec4<f32>,
    b: vec4<f32>,
}

fn ceil_chunk(x: u32) -> u32 {
    return x / CHUNK + select(0u, 1u, x % CHUNK != 0u);
}

fn element0(i: u32) -> Pair {
    let base = 2u * index[i];
    return Pair(vals[base], vals[base + 1u]);
}

// Level 1's element c of a run ending at b0 (level 0): its elements in order, from zero.
fn element1(c: u32, b0: u32) -> Pair {
    var s = Pair(vec4<f32>(0.0), vec4<f32>(0.0));
    for (var i = c * CHUNK; i < min(c * CHUNK + CHUNK, b0); i++) {
        let x = element0(i);
        s.a += x.a;
        s.b += x.b;
    }
    return s;
}

fn element2(c: u32, b0: u32) -> Pair {
    var s = Pair(vec4<f32>(0.0), vec4<f32>(0.0));
    for (var i = c * CHUNK; i < min(c * CHUNK + CHUNK, ceil_chunk(b0)); i++) {
        let x = element1(i, b0);
        s.a += x.a;
        s.b += x.b;
    }
    return s;
}

fn element3(c: u32, b0: u32) -> Pair {
    var s = Pair(vec4<f32>(0.0), vec4<f32>(0.0));
    for (var i = c * CHUNK; i < min(c * CHUNK + CHUNK, ceil_chunk(ceil_chunk(b0))); i++) {
        let x = element2(i, b0);
        s.a += x.a;
        s.b += x.b;
    }
    return s;
}

fn element4(c: u32, b0: u32) -> Pair {
    var s = Pair(vec4<f32>(0.0), vec4<f32>(0.0));
    for (var i = c * CHUNK; i < min(c * CHUNK + CHUNK, ceil_chunk(ceil_chunk(ceil_chunk(b0)))); i++) {
        let x = element3(i, b0);
        s.a += x.a;
        s.b += x.b;
    }
    return s;
}

// Level l's element c (l <= 4: the host takes SegmentSum past CHUNK^5 elements).
fn element(l: u32, c: u32, b0: u32) -> Pair {
    switch (l) {
        case 0u: { return element0(c); }
        case 1u: { return element1(c, b0); }
        case 2u: { return element2(c, b0); }
        case 3u: { return element3(c, b0); }
        default: { return element4(c, b0); }
    }
}

@compute @workgroup_size(256)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let v = linear_group(wid, nwg) * 256u + li;
    if (v >= gp.count) {
        return;
    }
    let a0 = spans[v].x;
    let b0 = spans[v].y;
    var t = Pair(vec4<f32>(0.0), vec4<f32>(0.0));
    for (var up = gp.top + 1u; up > 0u; up--) {   // level up - 1, coarsest first
        let l = up - 1u;
        var al = a0;
        var bl = b0;
        for (var k = 0u; k < l; k++) {
            al = ceil_chunk(al);
            bl = ceil_chunk(bl);
        }
        if (al >= bl) {
            continue;   // the run has no element on this level
        }
        var hi = bl;
        if (l < gp.top) {
            if (al % CHUNK == 0u) {
                continue;   // its whole run is in the coarser levels' total
            }
            hi = min(bl, (al / CHUNK + 1u) * CHUNK);
        }
        var s = Pair(vec4<f32>(0.0), vec4<f32>(0.0));
        for (var c = al; c < hi; c++) {
            let x = element(l, c, b0);
            s.a += x.a;
            s.b += x.b;
        }
        t.a = s.a + t.a;
        t.b = s.b + t.b;
    }
    out[2u * v] = t.a;
    out[2u * v + 1u] = t.b;
}
