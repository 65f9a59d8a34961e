"""Host classes of ``shaders/blend/``: the forward blend and, as a pipeline-constant variant
of the same WGSL, the triangle-ID pass; the gather of a window's projected triangles where they
outgrow one storage binding."""

from __future__ import annotations

from ..gpu.chunks import pages
from ..gpu.context import layout_kernel
from ..gpu.stage import Stage
from ..gpu.wgsl import constant

#: Pairs per tile that one blend dispatch handles at most (lavapipe's loop budget; the
#: WGSL's ``PASS_PAIRS``, a whole number of ``BATCH``es).
BLEND_PASS_PAIRS = constant("PASS_PAIRS", "rasterize_forward")


def kernel_layout(ctx=None):
    """The blend kernels' layout as the benchmarks name it: its name (``ctx.layout``,
    :attr:`~tsplus_wgpu.gpu.GpuContext.layout`; the CPU layout when ``ctx`` is None) and, read
    from the WGSL, each kernel's invocations a tile and pixels each."""
    name = "cpu" if ctx is None else ctx.layout
    tile = int(constant("TILE", "frame"))
    parts = []
    for kernel, short in (("rasterize_forward", "forward"), ("rasterize_backward", "backward")):
        suffix = "_gpu" if layout_kernel(name, short) == "pixel" else ""
        threads = int(constant("THREADS", kernel + suffix))
        parts.append(f"{short} {threads} invocations a {tile}x{tile} tile, {tile * tile // threads} px each")
    return f"{name} ({'; '.join(parts)})"


class RasterizeForward(Stage):
    """The forward blend: image, final T, per-pixel (last contributing, evaluated) pair counts,
    per-triangle max weight and the work counters."""

    stage = "rasterize_forward"
    label = "rasterize_forward"     # profiler label

    def passes(self, enc, max_tile_pairs, buffers, tiles_x, tiles_y, profiler=None, window=None):
        """Record ceil(max_tile_pairs / PASS_PAIRS) dispatches (one in practice), each over the
        next window of every tile's pairs, the pixel state carried in the bound outputs.
        ``window`` ``(lo, hi)``: only the tiles whose first pair is in it, ``tris`` holding the
        records of pairs ``lo, lo + 1, ...`` (:class:`GatherTris`)."""
        step = self.const("PASS_PAIRS")
        passes = max(1, -(-int(max_tile_pairs) // step))
        lo, hi = (0, 0xFFFFFFFF) if window is None else window
        for i in range(passes):
            bp = self.uniform("BlendPass", begin=i * step, end=(i + 1) * step,
                              first=int(i == 0), last=int(i == passes - 1), pair_lo=lo, pair_hi=hi,
                              gathered=int(window is not None))
            self.dispatch(enc, (tiles_x, tiles_y, 1), dict(buffers, pass_=bp), profiler, self.label)

    def __call__(self, enc, params, ranges, pair_tris, tris, image, final_t, n_contrib, max_weight, work,
                 tiles_x, tiles_y, max_tile_pairs, profiler=None, window=None, clear=True):
        """``window``: see :meth:`passes`; ``clear``: zero the max weights and work counters
        first (the first window)."""
        if clear:
            enc.clear_buffer(max_weight)
            enc.clear_buffer(work)
        self.passes(enc, max_tile_pairs, dict(params=params, ranges=ranges, pair_tris=pair_tris, tris=tris,
                                              image=image, final_t=final_t, n_contrib=n_contrib,
                                              max_weight=max_weight, work=work), tiles_x, tiles_y, profiler,
                    window)


class RasterizeForwardGpu(RasterizeForward):
    """The same blend as the pixel kernel (``rasterize_forward_gpu.wgsl``: one invocation a pixel,
    256 a tile): the same bindings, passes and outputs."""

    stage = "rasterize_forward_gpu"


class RasterizeIds(RasterizeForward):
    """The triangle-ID pass: ``rasterize_forward.wgsl`` with ``TRIANGLE_IDS`` set, walking the
    same sorted tile lists in as many passes."""

    label = "rasterize_ids"

    def __init__(self, ctx):
        super().__init__(ctx, constants={"TRIANGLE_IDS": 1})
        #: bound where the forward writes its image, max weights and work (unused by this variant)
        self.placeholder = ctx.buffer(16, "rasterize_ids.placeholder")

    def __call__(self, enc, params, ranges, pair_tris, tris, id_t, id_state, tiles_x, tiles_y, max_tile_pairs,
                 profiler=None, window=None):
        """Per pixel the triangle of largest alpha * T, ties to the front-most: ``id_state``
        ``[H, W]`` vec2<u32> gets (its index, its weight as f32 bits), (0xFFFFFFFF, 0) where none
        contributes; ``id_t`` ``[H, W]`` f32 the transmittance of the walk."""
        ph = self.placeholder
        self.passes(enc, max_tile_pairs, dict(params=params, ranges=ranges, pair_tris=pair_tris, tris=tris,
                                              image=ph, final_t=id_t, n_contrib=id_state, max_weight=ph,
                                              work=ph), tiles_x, tiles_y, profiler, window)


class RasterizeIdsGpu(RasterizeIds):
    """The triangle-ID pass as the pixel kernel."""

    stage = "rasterize_forward_gpu"


def forward_stage(ctx, triangle_ids=False):
    """The forward blend (or, with ``triangle_ids``, the ID pass) in ``ctx``'s kernel layout."""
    gpu = layout_kernel(ctx.layout, "forward") == "pixel"
    if triangle_ids:
        return (RasterizeIdsGpu if gpu else RasterizeIds)(ctx)
    return (RasterizeForwardGpu if gpu else RasterizeForward)(ctx)


class GatherTris(Stage):
    """The projected triangles of pairs ``[lo, lo + count)`` in pair order (``out[p] =
    tris[pair_tris[lo + p]]``), reading ``tris`` a binding's page of triangles at a time: where
    the projected triangles of a model outgrow one binding, the rasterizers read a window's."""

    stage = "gather_tris"

    def __call__(self, enc, pair_tris, tris, out, lo, count, num_triangles, itemsize, profiler=None):
        for page_lo, page_hi, page in pages(self.ctx, tris, num_triangles, itemsize):
            gp = self.uniform("GatherParams", lo=lo, count=count, page_lo=page_lo, page_hi=page_hi)
            self.dispatch(enc, self.groups(count), dict(gp=gp, pair_tris=pair_tris, tris=page, out=out), profiler,
                          "gather_tris")


__all__ = ["BLEND_PASS_PAIRS", "kernel_layout", "forward_stage", "RasterizeForward", "RasterizeForwardGpu",
           "RasterizeIds", "RasterizeIdsGpu", "GatherTris"]
