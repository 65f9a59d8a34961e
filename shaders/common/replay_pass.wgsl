// The uniform of one dispatch of the backward blend, shared by both kernel layouts
// (rasterize_backward.wgsl, rasterize_backward_gpu.wgsl) so that the host fills one struct
// for either (kernels/backward.py: RasterizeBackward).
struct PassParams {
    round_begin: u32,   // rounds [round_begin, round_end) of RB pairs in this dispatch: lavapipe
    round_end: u32,     // stops any invocation's loops after 65535 iterations in total
    pair_lo: u32,       // the pair window: only tiles whose first pair is in [pair_lo, pair_hi)
    pair_hi: u32,       // replay, and pair p's statistics go to partials[p - pair_lo]
    gathered: u32,      // 1: tris holds the window's records in pair order (gather_tris), pair p's
    _pad0: u32,         // at p - pair_lo (the projected triangles outgrow one binding)
    _pad1: u32,
    _pad2: u32,
}
