// Workgroup grids larger than 65535 are split into 2-D (tsplus_wgpu.gpu.grid).
fn linear_group(wid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return wid.x + wid.y * nwg.x;
}
