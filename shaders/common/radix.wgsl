// Portable stable LSD radix sort, 4 bits per pass (no subgroups, no inter-workgroup
// waiting). A block of 2048 keys per workgroup: 128 threads x 16 consecutive keys.
struct SortParams {
    n: u32,
    shift: u32,
    num_blocks: u32,
    _pad0: u32,
}

const RADIX_BITS: u32 = 4u;                     // bits sorted per pass
const RADIX: u32 = 1u << RADIX_BITS;             // digits per pass
const SORT_THREADS: u32 = 128u;
const SORT_ITEMS: u32 = 16u;                     // a multiple of 4: keys are read as vec4
const SORT_BLOCK: u32 = SORT_THREADS * SORT_ITEMS;
