// Exclusive prefix sum, level 1: each workgroup scans 1024 u32 in place and writes
// its total to block_sums (scanned recursively, then added back by scan_add).
#import dispatch

struct ScanParams {
    n: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> sp: ScanParams;
@group(0) @binding(1) var<storage, read_write> data: array<u32>;
@group(0) @binding(2) var<storage, read_write> block_sums: array<u32>;

var<workgroup> buf: array<array<u32, 256>, 2>;

@compute @workgroup_size(256)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let block = linear_group(wid, nwg);
    let base = block * 1024u + li * 4u;
    var v: array<u32, 4>;
    var run = 0u;
    for (var i = 0u; i < 4u; i++) {
        let x = select(0u, data[base + i], base + i < sp.n);
        v[i] = run;
        run += x;
    }
    // Hillis-Steele inclusive scan of the per-thread totals.
    buf[0][li] = run;
    var src = 0u;
    workgroupBarrier();
    for (var off = 1u; off < 256u; off = off * 2u) {
        var acc = buf[src][li];
        if (li >= off) {
            acc += buf[src][li - off];
        }
        buf[1u - src][li] = acc;
        src = 1u - src;
        workgroupBarrier();
    }
    let incl = buf[src][li];
    let excl = incl - run;
    for (var i = 0u; i < 4u; i++) {
        if (base + i < sp.n) {
            data[base + i] = excl + v[i];
        }
    }
    if (li == 255u) {
        block_sums[block] = incl;
    }
}
