// Workgroup grids larger than 65535 are split into 2-D (tsplus_wgpu.gpu.grid).
fn linear_group(wid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return wid.x + wid.y * nwg.x;
}

// One chunk of a dispatch over per-item arrays bound a range of items at a time
// (tsplus_wgpu.gpu.chunks): the kernel sees items [0, count) of every such binding, which
// are items [first, first + count) of the whole array.
struct ItemRange {
    count: u32,
    first: u32,
    _pad1: u32,
    _pad2: u32,
}
