"""The backward pass on the device: portable (no float atomics) and deterministic.

Stages, each a ``shaders/<group>/<kernel>.wgsl`` with a class of the same name in
:mod:`tsplus_wgpu.kernels` and a float64 twin in :mod:`tsplus_wgpu.reference`:

1. ``backward_prepare`` (per pixel): the blend's starting state; ``rasterize_backward``
   (per tile, in passes of ``ROUNDS_PER_PASS`` rounds of its WGSL): front-to-back replay of
   the forward blend up to each pixel's last contributing pair; per (triangle, tile) pair the 19 sufficient statistics
   of ``common/grad_stats.wgsl``, summed over the tile's pixels in a fixed order.
2. pair reduce: the pairs sorted by triangle with the stable :class:`RadixSort` (so each
   triangle's pairs come in tile order), then :class:`SegmentSum` (``segment_up`` /
   ``segment_down``) of their statistics per triangle.

   Steps 1 (the replay) and 2 go window by window of pairs (:func:`pair_windows`) when a
   view has more pairs than one binding of their statistics holds (80 bytes a pair: 1.68 M
   pairs in 128 MiB); each window's sums are added to the triangles' totals.
3. ``project_backward`` (per triangle): exact chain rule to its three corners.
4. corner -> vertex: the triangle index buffer sorted by vertex with the stable
   :class:`RadixSort` (values: corner indices), so each vertex's corners come in order;
   :class:`SegmentSum` of their gradients per vertex. Where each vertex's run of the sorted
   corners is known (a host model's, or a ``DeviceModel``'s ``corner_spans``),
   :class:`SegmentGather` instead: the same sums to the bit, one invocation per vertex.
5. ``vertex_backward`` (per vertex): the SH chain rule.

Every float sum has a fixed order, so the gradients are bit-identical from run to run on
one adapter, and nothing is lost on shared vertices. No invocation loops more than a
bounded number of times whatever the scene (lavapipe ends an invocation's loops after
65535 iterations in total): the segmented sums read at most ``CHUNK`` elements each, on
as many levels as needed, and the per-vertex gather at most ``SegmentGather.MAX_RUN``
corners (a vertex with more takes the segmented sum).
"""

from __future__ import annotations

import hashlib
import weakref

import numpy as np
import wgpu

from ..gpu.chunks import binding_bytes, pair_windows
from ..gpu.recorder import Recorder
from ..kernels.backward import NSTAT, BackwardPrepare, ProjectBackward, VertexBackward, backward_stage
from ..kernels.reduce import SegmentGather, SegmentSum
from ..kernels.sort import RadixSort
from .device_model import corner_order, corner_spans
from ..types import Grads, TriangleModel, check_cotangents


def pair_window_capacity(ctx):
    """The most pairs one window of the backward holds on ``ctx``: their statistics (``NSTAT``
    floats each) in one storage binding and one buffer."""
    lim = ctx.limits
    return min(int(lim["max-storage-buffer-binding-size"]), int(lim["max-buffer-size"])) // (4 * NSTAT)


class BackwardPass:
    """The stages of the backward pass for one :class:`Renderer` (pipelines compiled once)."""

    def __init__(self, renderer):
        c = renderer.ctx
        self.renderer = renderer
        self.ctx = c
        self.prepare = BackwardPrepare(c)
        self.raster = backward_stage(c)     # in the context's kernel layout
        self.pair_sort = RadixSort(c, renderer.scratch, "pair_sort")
        self.pair_sum = SegmentSum(c, renderer.scratch, "pair_sum")
        self.corner_sum = SegmentSum(c, renderer.scratch, "corner_sum")
        self.corner_gather = SegmentGather(c)
        self.project = ProjectBackward(c)
        self.vertex = VertexBackward(c)
        self.corner_sort = RadixSort(c, renderer.scratch, "corner_sort")
        self._corner_cache = None   # (topology key, sorted corner keys, corner ids, (spans, longest))
        self._ids = None            # (buffer of 0, 1, ..., its count): _pair_ids
        #: the most pairs whose statistics one window holds (None: as many as one binding of
        #: the device holds; tests set fewer to exercise the windows)
        self.pair_capacity = None

    def window_capacity(self, num_triangles=0):
        """Pairs per window (:func:`pair_window_capacity`, or the tests' ``pair_capacity``); where
        the projected triangles of ``num_triangles`` outgrow one binding, also no more than one
        binding of their records in pair order holds."""
        cap = pair_window_capacity(self.ctx) if self.pair_capacity is None else int(self.pair_capacity)
        size = self.renderer.tri2d_dtype.itemsize
        if num_triangles * size > binding_bytes(self.ctx):
            cap = min(cap, binding_bytes(self.ctx) // size)
        return cap

    def _pair_ids(self, count):
        """A buffer holding 0, 1, ..., at least ``count`` of them (kept; grown when short)."""
        if self._ids is None or self._ids[1] < count:
            size = max(int(count), 3 * self._ids[1] // 2 if self._ids else 0)
            self._ids = (self.ctx.upload(np.arange(size, dtype=np.uint32), "pair_ids_fresh"), size)
        return self._ids[0]

    def _corner_order(self, enc, model, triangles, m, n, profiler):
        """The corners sorted by vertex (stable): (vertex keys, corner ids) buffers, and each
        vertex's run of them ``(spans buffer, longest run)`` or None.

        It depends only on the index buffer, so for a host :class:`TriangleModel` it is
        sorted on the host (:func:`~.device_model.corner_order`, as the trainer does) and kept
        for the next call with the same topology, keyed on the index array's content (a
        digest, so a changed topology is never served a stale order). A model already on the
        device carries its ``corner_order`` (:class:`~tsplus_wgpu.DeviceModel`), or is sorted on
        the device every call."""
        if isinstance(model, TriangleModel):
            idx = np.ascontiguousarray(model.triangles, dtype=np.uint32)
            key = (int(n), int(m), hashlib.blake2b(idx.tobytes(), digest_size=20).digest())
            if self._corner_cache is None or self._corner_cache[0] != key:
                self._corner_cache = (key, *corner_order(self.ctx, idx), corner_spans(self.ctx, idx, n))
            return self._corner_cache[1:]
        known = getattr(model, "corner_order", None)   # a DeviceModel whose owner knows the order
        if known is not None:
            return known[0], known[1], getattr(model, "corner_spans", None)
        c = self.ctx
        keys = c.buffer(12 * m, "corner_keys")
        vals = c.upload(np.arange(3 * m, dtype=np.uint32), "corner_ids")
        enc.copy_buffer_to_buffer(triangles, 0, keys, 0, 12 * m)
        bits = max(1, int(n - 1).bit_length())
        skeys, svals = self.corner_sort.record(enc, keys, vals, 3 * m, bits, profiler)
        return skeys, svals, None

    def run(self, result, v_image, v_transmittance=None, profile=False, read=True, out=None):
        """The backward pass of ``result``.

        Args:
            v_image: ``[H, W, 3]`` array, or a device buffer already in the kernel's layout
                ``[H * W]`` vec4 (dL/d rgb, dL/d T) (then ``v_transmittance`` must be None).
            read: read the gradients back (``Grads``); with False return the timings only.
            out: optional dict of device buffers ``v_positions`` (``[N, 3]`` f32), ``v_sh``
                (``[N, K, 3]``), ``v_opacity`` (``[N]``) to write the gradients into (reused
                between calls). With ``read=False`` nothing is read back and nothing waits.
        """
        c = self.ctx
        model = result.model
        n, k = model.num_vertices, model.sh_size
        v_out = self._v_out(result.camera, v_image, v_transmittance)
        self._check_sizes(result)
        given = out is not None
        out = self._outputs(out, n, k)
        if result.num_pairs == 0:   # nothing reached the image: every gradient is zero (cheap for empty views)
            enc = c.device.create_command_encoder()
            for buf_ in out.values():
                enc.clear_buffer(buf_)
            c.queue.submit([enc.finish()])
            return self._finish(out, n, k, {}, {}, read, wait=not given)
        rec = Recorder(c, profile)
        buf = self._record(rec, result, v_out, out)
        return self._finish(out, n, k, buf, rec.resolve(), read, wait=not given)

    def _v_out(self, cam, v_image, v_transmittance):
        """The cotangent as the kernels read it: a device buffer ``[H * W]`` vec4, or the
        host array ``[H * W, 4]`` to upload."""
        h, w = cam.height, cam.width
        if isinstance(v_image, wgpu.GPUBuffer):
            if v_transmittance is not None:
                raise ValueError("v_transmittance: must be None when v_image is a device buffer (its .w lanes)")
            if v_image.size < 16 * h * w:
                raise ValueError(f"v_image: buffer holds {v_image.size} bytes, needs {16 * h * w} ([H*W] vec4)")
            return v_image
        vi, vt = check_cotangents(v_image, v_transmittance, h, w)
        v_out = np.zeros((h * w, 4), np.float32)
        v_out[:, :3] = vi.reshape(-1, 3)
        v_out[:, 3] = vt.reshape(-1)
        return v_out

    def _check_sizes(self, result):
        model = result.model
        m, n, k = model.num_triangles, model.num_vertices, model.sh_size
        pair_windows(result.num_pairs, result.max_tile_pairs, self.window_capacity(m))   # a tile over a window
        # bound a range of triangles at a time, or read gathered per window of pairs (gpu/chunks.py)
        for name, nbytes in (("backward triangle statistics", 4 * NSTAT * m),
                             ("backward corner gradients", 32 * 3 * m)):
            self.ctx.check_size(name, nbytes, chunked=True)
        self.ctx.check_size("v_sh", 12 * n * k, chunked=True)   # bound a range of vertices at a time

    def _outputs(self, out, n, k):
        """The gradient buffers: the caller's (checked) or new ones."""
        c = self.ctx
        if out is None:
            return dict(v_positions=c.buffer(12 * n, "v_positions"), v_sh=c.buffer(12 * n * k, "v_sh", chunked=True),
                        v_opacity=c.buffer(4 * n, "v_opacity"))
        for key, nbytes in (("v_positions", 12 * n), ("v_sh", 12 * n * k), ("v_opacity", 4 * n)):
            if key not in out or out[key].size < nbytes:
                raise ValueError(f"out[{key!r}]: missing or smaller than {nbytes} bytes")
        return {key: out[key] for key in ("v_positions", "v_sh", "v_opacity")}

    def _record(self, rec, result, v_out, out):
        """Record and submit every stage (one submit per timing label); returns the scratch buffers."""
        r, c = self.renderer, self.ctx
        cam, model = result.camera, result.model
        h, w = cam.height, cam.width
        m, n = model.num_triangles, model.num_vertices
        tx, ty, _ = r.tiles(cam)
        P = result.num_pairs
        b = result.buffers
        dev = result.model_buffers if getattr(result, "model_buffers", None) is not None else r.upload_model(model)
        params = r.frame_params(model, cam, result.sigma, np.asarray(result.background), result.near, P)
        # the longest tile list sizes the passes of rasterize_backward and the windows; the
        # forward already read it back, so no second readback here
        max_range = int(result.max_tile_pairs)
        windows = pair_windows(P, max_range, self.window_capacity(m))
        span = max(length for _, _, length in windows)
        alloc = r.buffer_source(result.reused, "backward_")
        # projected triangles past one binding: each window reads its pairs' records, gathered
        size = r.tri2d_dtype.itemsize
        gathered = m * size > binding_bytes(c)
        tris = alloc(size * max(span, 1), "tris_window") if gathered else b["tris"]
        pkeys, pvals = alloc(4 * span, "pair_keys"), alloc(4 * span, "pair_ids")
        # the pair ids 0, 1, ... (kept): the sort may permute its inputs in place, so every
        # window starts from a copy
        ids = self._pair_ids(span)
        buf = dict(v_out=v_out if isinstance(v_out, wgpu.GPUBuffer) else c.upload(v_out, "v_out"),
                   partials=alloc(4 * NSTAT * span, "partials"),
                   tri_stats=alloc(4 * NSTAT * m, "tri_stats"), vertex_sums=alloc(32 * n, "vertex_sums"),
                   corner_grads=alloc(32 * 3 * m, "corner_grads"), state=alloc(16 * h * w, "backward_state"),
                   work=alloc(16, "backward_work"))
        prof = rec.profiler
        # one submit for all stages (each its own only when timed on the host); without the
        # host caching, one per stage as before it
        flush = rec.flush if c.host_caching else rec.submit
        rec.start()
        self.prepare(rec.encoder, params, b["image"], b["final_t"], b["n_contrib"], buf["v_out"], buf["state"],
                     h * w, prof)
        tbits = max(1, int(m - 1).bit_length())
        for i, (lo, hi, length) in enumerate(windows):
            if gathered:
                r.gather(rec.encoder, b["pair_tris"], b["tris"], tris, lo, length, m, size, prof)
            self.raster(rec.encoder, params, b["ranges"], b["pair_tris"], tris, buf["v_out"], buf["state"],
                        buf["partials"], buf["work"], tx, ty, max_range, prof,
                        window=None if len(windows) == 1 and not gathered else (lo, hi), clear=i == 0,
                        gathered=gathered)
            flush("rasterize_backward")
            # each triangle's pairs together, in tile order (stable sort by triangle), then summed
            # (added to the earlier windows' sums)
            rec.encoder.copy_buffer_to_buffer(b["pair_tris"], 4 * lo, pkeys, 0, 4 * length)
            rec.encoder.copy_buffer_to_buffer(ids, 0, pvals, 0, 4 * length)
            pk, pv = self.pair_sort.record(rec.encoder, pkeys, pvals, length, tbits, prof)
            self.pair_sum.record(rec.encoder, pk, pv, buf["partials"], length, NSTAT // 4, buf["tri_stats"], prof,
                                 "pair_reduce", clear=i == 0, num_keys=m)
            flush("pair_reduce")
        self.project(rec.encoder, params, dev["positions"], dev["triangles"], dev["opacity"], b["colors"],
                     b["tris"], b["pixel_rects"], buf["tri_stats"], buf["corner_grads"], m, prof)
        flush("project_backward")
        skeys, svals, spans = self._corner_order(rec.encoder, model, dev["triangles"], m, n, prof)
        if spans is not None and self.corner_gather.fits(3 * m, spans[1]):   # the same sums, per vertex
            self.corner_gather(rec.encoder, spans[0], svals, buf["corner_grads"], buf["vertex_sums"], n, 3 * m, prof,
                               "corner_sum")
        else:
            self.corner_sum.record(rec.encoder, skeys, svals, buf["corner_grads"], 3 * m, 2, buf["vertex_sums"], prof,
                                   "corner_sum", num_keys=n)
        flush("corner_sum")
        self.vertex(rec.encoder, params, dev["positions"], dev["sh"], buf["vertex_sums"], out["v_positions"],
                    out["v_sh"], out["v_opacity"], n, prof, model.sh_size)
        rec.submit("vertex_backward")
        return buf

    def _finish(self, out, n, k, buf, times, read, wait=True):
        c = self.ctx
        if not read:
            if wait:
                c.wait()
            return times
        grads = Grads(v_positions=c.read(out["v_positions"], np.float32, 3 * n).reshape(n, 3),
                      v_sh=c.read(out["v_sh"], np.float32, 3 * n * k).reshape(n, k, 3),
                      v_opacity=c.read(out["v_opacity"], np.float32, n))
        grads.timings = times
        grads.buffers = dict(buf, **out)
        return grads


_PASSES = weakref.WeakKeyDictionary()


def backward(renderer, result, v_image, v_transmittance=None, profile=False, read=True, out=None) -> Grads:
    """Gradients of ``sum(v_image * image) + sum(v_transmittance * T)`` of a forward pass.

    Args:
        renderer: the :class:`Renderer` that produced ``result``.
        result: a :class:`ForwardResult` (its device buffers are read, not changed).
        v_image: ``[H, W, 3]`` dL/d image, or a device buffer ``[H * W]`` vec4 (dL/d rgb, dL/d T).
        v_transmittance: ``[H, W]`` dL/d final transmittance, or None.
        profile: time each stage (``grads.timings``, ms).
        read, out: see :meth:`BackwardPass.run` (device-resident gradients without readback).

    Returns:
        :class:`Grads` with ``v_positions [N, 3]``, ``v_sh [N, K, 3]``, ``v_opacity [N]``
        (float32; w.r.t. the activated opacity given to ``forward``).
    """
    if not all(hasattr(result, a) for a in ("renderer", "buffers", "num_pairs", "max_tile_pairs")):  # a ForwardResult
        raise ValueError(f"result: expected a ForwardResult, got {type(result).__name__}")
    if result.renderer is not renderer:
        raise ValueError("result: it was produced by another Renderer")
    bp = _PASSES.get(renderer)
    if bp is None:
        bp = _PASSES[renderer] = BackwardPass(renderer)
    return bp.run(result, v_image, v_transmittance, profile, read=read, out=out)
