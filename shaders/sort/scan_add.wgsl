// Exclusive prefix sum, level 2: add each block's scanned offset to its SCAN_BLOCK
// (1024) values.
#import dispatch
#import scan

@group(0) @binding(0) var<uniform> sp: ScanParams;
@group(0) @binding(1) var<storage, read_write> data: array<u32>;
@group(0) @binding(2) var<storage, read> block_offsets: array<u32>;

@compute @workgroup_size(SCAN_THREADS)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let block = linear_group(wid, nwg);
    let add = block_offsets[block];
    let base = block * SCAN_BLOCK + li * SCAN_ITEMS;
    for (var i = 0u; i < SCAN_ITEMS; i++) {
        if (base + i < sp.n) {
            data[base + i] += add;
        }
    }
}
