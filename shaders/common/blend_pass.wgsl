// The uniform of one dispatch of the forward blend (and its triangle-ID variant), shared by
// both kernel layouts (rasterize_forward.wgsl, rasterize_forward_gpu.wgsl) so that the host
// fills one struct for either (kernels/blend.py: RasterizeForward.passes).
struct BlendPass {
    begin: u32,   // window of pairs [begin, end) within every tile's range
    end: u32,
    first: u32,   // 1: no state to resume
    last: u32,    // 1: write the final outputs
    // Where the projected triangles outgrow one binding (gathered = 1), the pairs go in windows
    // of whole tiles: only the tiles whose first pair is in [pair_lo, pair_hi) are done, and
    // tris holds the window's records in pair order (gather_tris): pair p's at p - pair_lo.
    pair_lo: u32,
    pair_hi: u32,
    gathered: u32,
    _pad0: u32,
}
