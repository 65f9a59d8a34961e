"""A model whose arrays live on the device: :class:`DeviceModel`.

:meth:`Renderer.forward` accepts a ``DeviceModel`` wherever it accepts a
:class:`~tsplus_wgpu.TriangleModel` and then uploads nothing; the forward result keeps the
model's buffers, so the backward pass does not upload them either. The trainer keeps its
model in one and rewrites the buffers in place every step.
"""

from __future__ import annotations

import numpy as np

from ..types import SH_SIZES, TriangleModel


class DeviceModel:
    """Device buffers of a triangle model (the layout :meth:`Renderer.upload_model` makes).

    Args:
        ctx: the :class:`~tsplus_wgpu.gpu.GpuContext` owning the buffers.
        buffers: dict with ``positions`` (f32 ``[N, 3]``), ``triangles`` (u32 ``[M, 3]``),
            ``sh`` (f32 ``[N, K, 3]``) and ``opacity`` (f32 ``[N]``, activated, in [0, 1]).
        num_vertices, num_triangles, sh_size: N, M, K (K in 1, 4, 9, 16).

    The buffers are used as they are: nothing checks that indices are in range or values
    finite (build it with :meth:`from_model` to get the checks of ``TriangleModel``).
    """

    KEYS = ("positions", "triangles", "sh", "opacity")

    def __init__(self, ctx, buffers, num_vertices, num_triangles, sh_size):
        missing = [k for k in self.KEYS if k not in buffers]
        if missing:
            raise ValueError(f"DeviceModel buffers: missing {missing}")
        if int(sh_size) not in SH_SIZES:
            raise ValueError(f"DeviceModel sh_size: expected one of {SH_SIZES}, got {sh_size!r}")
        n, m, k = int(num_vertices), int(num_triangles), int(sh_size)
        for key, nbytes in (("positions", 12 * n), ("triangles", 12 * m), ("sh", 12 * n * k), ("opacity", 4 * n)):
            if buffers[key].size < nbytes:
                raise ValueError(f"DeviceModel {key}: buffer holds {buffers[key].size} bytes, needs {nbytes}")
        self.ctx = ctx
        self.buffers = {key: buffers[key] for key in self.KEYS}
        self._n, self._m, self._k = n, m, k
        #: optional ``(vertex keys [3M], corner ids [3M])`` u32 buffers: the corners sorted by
        #: vertex (stable), set by an owner that knows them (the backward pass then skips its
        #: sort). The owner must keep it in step with ``triangles``; None: sorted every backward.
        self.corner_order = None
        #: optional ``(spans buffer [N] vec2 u32, longest)``: each vertex's run ``[a, b)`` of
        #: ``corner_order`` and the longest run (:func:`corner_spans`), so the backward sums each
        #: vertex's corners in one invocation (``SegmentGather``); None: the segmented sum.
        self.corner_spans = None

    @classmethod
    def from_model(cls, renderer, model: TriangleModel):
        """Upload a :class:`TriangleModel` (float32 / uint32) through ``renderer``."""
        if not isinstance(model, TriangleModel):
            raise ValueError(f"model: expected tsplus_wgpu.TriangleModel, got {type(model).__name__}")
        return cls(renderer.ctx, renderer.upload_model(model), model.num_vertices, model.num_triangles,
                   model.sh_size)

    @property
    def num_vertices(self):
        return self._n

    @property
    def num_triangles(self):
        return self._m

    @property
    def sh_size(self):
        return self._k

    def to_model(self) -> TriangleModel:
        """Read the buffers back into a :class:`TriangleModel` (float64 / int64)."""
        c, n, m, k = self.ctx, self._n, self._m, self._k
        pos = c.read(self.buffers["positions"], np.float32, 3 * n).reshape(n, 3)
        tri = c.read(self.buffers["triangles"], np.uint32, 3 * m).reshape(m, 3)
        sh = c.read(self.buffers["sh"], np.float32, 3 * n * k).reshape(n, k, 3)
        op = c.read(self.buffers["opacity"], np.float32, n)
        return TriangleModel(pos, tri.astype(np.int64), sh, np.clip(op, 0.0, 1.0))

    def __repr__(self):
        return f"DeviceModel(vertices={self._n}, triangles={self._m}, sh={self._k})"


def corner_order(ctx, triangles):
    """``(vertex keys [3M], corner ids [3M])`` u32 buffers: the corners of ``triangles`` (host,
    ``[M, 3]``) sorted by vertex, stably, as :attr:`DeviceModel.corner_order` takes them (sorted
    once per topology on the host; the backward's per-vertex gather then needs no sort)."""
    tri = np.asarray(triangles, np.int64).reshape(-1)
    order = np.argsort(tri, kind="stable").astype(np.uint32)
    return ctx.upload(tri[order].astype(np.uint32), "corner_order_keys"), ctx.upload(order, "corner_order_index")


def corner_spans(ctx, triangles, num_vertices):
    """``(spans buffer, longest)`` as :attr:`DeviceModel.corner_spans` takes them: each vertex's
    run ``[a, b)`` in :func:`corner_order`'s sorted corners (``[N, 2]`` u32), and the most corners
    one vertex has."""
    from ..kernels.reduce import key_spans
    spans = key_spans(np.asarray(triangles, np.int64).reshape(-1), num_vertices)
    longest = int((spans[:, 1] - spans[:, 0]).max(initial=0))
    return ctx.upload(spans if len(spans) else np.zeros((1, 2), np.uint32), "corner_spans"), longest
