// Portable stable LSD radix sort, 4 bits per pass (no subgroups, no inter-workgroup
// waiting). A block of 2048 keys per workgroup: 128 threads x 16 consecutive keys.
struct SortParams {
    n: u32,
    shift: u32,
    num_blocks: u32,
    _pad0: u32,
}

const RADIX: u32 = 16u;
const SORT_THREADS: u32 = 128u;
const SORT_ITEMS: u32 = 16u;
const SORT_BLOCK: u32 = 2048u;
