// Exclusive prefix sum, level 1: each workgroup scans SCAN_BLOCK (1024) u32 in place and writes
// its total to block_sums (scanned recursively, then added back by scan_add).
#import dispatch
#import scan

@group(0) @binding(0) var<uniform> sp: ScanParams;
@group(0) @binding(1) var<storage, read_write> data: array<u32>;
@group(0) @binding(2) var<storage, read_write> block_sums: array<u32>;

var<workgroup> buf: array<array<u32, SCAN_THREADS>, 2>;

@compute @workgroup_size(SCAN_THREADS)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let block = linear_group(wid, nwg);
    let base = block * SCAN_BLOCK + li * SCAN_ITEMS;
    var v: array<u32, SCAN_ITEMS>;
    var run = 0u;
    for (var i = 0u; i < SCAN_ITEMS; i++) {
        let x = select(0u, data[base + i], base + i < sp.n);
        v[i] = run;
        run += x;
    }
    // Hillis-Steele inclusive scan of the per-thread totals.
    buf[0][li] = run;
    var src = 0u;
    workgroupBarrier();
    for (var off = 1u; off < SCAN_THREADS; off = off * 2u) {
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
    for (var i = 0u; i < SCAN_ITEMS; i++) {
        if (base + i < sp.n) {
            data[base + i] = excl + v[i];
        }
    }
    if (li == SCAN_THREADS - 1u) {
        block_sums[block] = incl;
    }
}
