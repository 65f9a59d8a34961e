// The largest of n u32 values (one workgroup; each invocation strides over n / WG).
struct ReduceParams {
    n: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> rp: ReduceParams;
@group(0) @binding(1) var<storage, read> values: array<u32>;
@group(0) @binding(2) var<storage, read_write> result: array<u32>;

const WG: u32 = 256u;   // invocations of the one workgroup (a power of two)

var<workgroup> best: array<u32, WG>;

@compute @workgroup_size(WG)
fn main(@builtin(local_invocation_index) li: u32) {
    var m = 0u;
    for (var i = li; i < rp.n; i += WG) {
        m = max(m, values[i]);
    }
    best[li] = m;
    workgroupBarrier();
    for (var off = WG / 2u; off > 0u; off = off / 2u) {
        if (li < off) {
            best[li] = max(best[li], best[li + off]);
        }
        workgroupBarrier();
    }
    if (li == 0u) {
        result[0] = best[0];
    }
}
