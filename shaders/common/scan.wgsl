// Portable exclusive prefix sum of u32 (scan_block, then the block sums scanned
// recursively and added back by scan_add). A block of 1024 values per workgroup:
// 256 threads x 4 consecutive values.
struct ScanParams {
    n: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

const SCAN_THREADS: u32 = 256u;
const SCAN_ITEMS: u32 = 4u;
const SCAN_BLOCK: u32 = SCAN_THREADS * SCAN_ITEMS;
