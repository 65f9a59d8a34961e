"""Host classes of shaders/backward/: the backward blend's start state (``backward_prepare``)
and replay (``rasterize_backward``), and the chain rule to the triangles' corners
(``project_backward``) and to the vertices (``vertex_backward``)."""

from __future__ import annotations

from ..gpu import Stage, layout_kernel
from .project import per_item
from ..gpu.wgsl import constant

#: Sufficient statistics per (triangle, tile) pair and per triangle (``shaders/common/grad_stats.wgsl``).
NSTAT = constant("NSTAT", "grad_stats")


class BackwardPrepare(Stage):
    stage = "backward_prepare"

    def __call__(self, enc, params, image, final_t, n_contrib, v_out, state, num_pixels, profiler=None):
        self.dispatch(enc, self.groups(num_pixels),
                      dict(params=params, image=image, final_t=final_t, n_contrib=n_contrib, v_out=v_out,
                           state=state), profiler)


class RasterizeBackward(Stage):
    """One workgroup per tile; a tile's pairs in rounds of ``RB`` pairs, ``rounds_per_pass``
    rounds per dispatch (``ROUNDS_PER_PASS`` of the WGSL: lavapipe's loop budget).

    ``window = (lo, hi)``: only the tiles whose first pair is in ``[lo, hi)`` replay, and pair
    p's statistics go to ``partials[p - lo]`` (a view whose pairs outgrow one binding is done
    window by window; :class:`~tsplus_wgpu.render.backward.BackwardPass`). ``partials`` is
    zeroed first; the ``work`` counters too unless ``clear`` is False (the later windows)."""

    stage = "rasterize_backward"

    def __init__(self, ctx, constants=None):
        super().__init__(ctx, constants)
        self.pairs_per_round = self.const("RB")
        self.rounds_per_pass = self.const("ROUNDS_PER_PASS")

    def __call__(self, enc, params, ranges, pair_tris, tris, v_out, state, partials, work, tiles_x, tiles_y,
                 max_range, profiler=None, window=None, clear=True, gathered=False):
        """``gathered``: ``tris`` holds the window's records in pair order
        (:class:`~tsplus_wgpu.kernels.blend.GatherTris`), not every triangle's."""
        lo, hi = (0, 2**32 - 1) if window is None else (int(window[0]), int(window[1]))
        enc.clear_buffer(partials)
        if clear:
            enc.clear_buffer(work)
        rounds = (int(max_range) + self.pairs_per_round - 1) // self.pairs_per_round
        step = self.rounds_per_pass
        for r0 in range(0, max(rounds, 1), step):
            pp = self.uniform("PassParams", round_begin=r0, round_end=r0 + step, pair_lo=lo, pair_hi=hi,
                              gathered=int(bool(gathered)))
            self.dispatch(enc, (tiles_x, tiles_y, 1),
                          dict(params=params, pp=pp, ranges=ranges, pair_tris=pair_tris, tris=tris, v_out=v_out,
                               state=state, partials=partials, work=work), profiler, "rasterize_backward")


class RasterizeBackwardGpu(RasterizeBackward):
    """The same backward blend as the pixel kernel (``rasterize_backward_gpu.wgsl``, the
    ``pixel`` layout's: one invocation a pixel, 256 a tile): the same bindings, rounds, windows
    and outputs."""

    stage = "rasterize_backward_gpu"


def backward_stage(ctx):
    """The backward blend in ``ctx``'s kernel layout (:attr:`~tsplus_wgpu.gpu.GpuContext.layout`)."""
    return (RasterizeBackwardGpu if layout_kernel(ctx.layout, "backward") == "pixel" else RasterizeBackward)(ctx)


class ProjectBackward(Stage):
    stage = "project_backward"

    def __call__(self, enc, params, positions, triangles, opacities, colors, tris, pixel_rects, tri_stats,
                 corner_grads, num_triangles, profiler=None):
        """In ranges of triangles where the per-triangle records outgrow one binding."""
        size = int(self.src.structs["Tri2D"].itemsize)
        per_item(self, enc, num_triangles,
                   dict(tris=(tris, size), tri_stats=(tri_stats, 4 * NSTAT), corner_grads=(corner_grads, 96)),
                   dict(params=params, positions=positions, triangles=triangles, opacities=opacities, colors=colors,
                        pixel_rects=pixel_rects), profiler)


class VertexBackward(Stage):
    stage = "vertex_backward"

    def __call__(self, enc, params, positions, sh, vertex_sums, v_positions, v_sh, v_opacity, num_vertices,
                 profiler=None, sh_size=None):
        """In chunks of vertices where the SH are larger than one binding; ``sh_size``: K
        (default: from the buffer's size)."""
        n = int(num_vertices)
        k = int(sh_size) if sh_size is not None else max(1, sh.size // max(12 * n, 1))
        per_item(self, enc, n, dict(positions=(positions, 12), sh_coeffs=(sh, 12 * k), vertex_sums=(vertex_sums, 32),
                                      v_positions=(v_positions, 12), v_sh=(v_sh, 12 * k), v_opacity=(v_opacity, 4)),
                   dict(params=params), profiler)


__all__ = ["NSTAT", "BackwardPrepare", "RasterizeBackward", "RasterizeBackwardGpu", "backward_stage", "ProjectBackward",
           "VertexBackward"]
