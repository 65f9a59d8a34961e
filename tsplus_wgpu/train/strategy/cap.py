"""The densification cap: how large topology may grow a model, and which bound sets it
(:func:`vertex_cap`, a :class:`VertexCap` for :class:`~.topology.TopologyStrategy`).

Vertices: three bounds, the smallest applies.

* ``max_vertices`` (method.md: 3M).
* The **vertex budget**: ``ceil(vertex_budget x P)``, with P the mean pixel count of one training
  image at the training resolution. A model should never outgrow what its images can constrain.
  The paper's cap of 3M vertices is about 2 vertices per pixel of its ~1.6k x 1k training
  images (its scenes end near 2M), hence the default 2.0. Without it, lund (29 photos, quick,
  ``--downscale 4``: 237x178, 42k pixels per image) densified from 1,477 to 658,115 vertices by
  iteration 1,100, more than 15 per pixel, and the run died on the storage-binding limit.
* The device's **buffer and binding limits**: the SH, their Adam moments and their gradient
  (``12 K`` bytes a vertex, K = 16 at SH degree 3) are bound a range of vertices at a time
  (``gpu/chunks.py``), so each must fit one *buffer* (2 GiB on llvmpipe: 11.2 M vertices;
  WebGPU's default 256 MiB: 1,398,101); the backward's vertex sums (32 bytes a vertex, written
  by vertex index) must fit one *binding* (4,194,304 vertices at 128 MiB). Until 2026-11-27 the
  SH had to fit one binding: 699,050 vertices at degree 3 and 128 MiB.

Triangles: the device's limits too. The largest per-triangle buffers (the projected triangle
record ``Tri2D`` and the backward's corner gradients, 96 bytes a triangle each) are bound a range
of triangles at a time or read gathered per window of pairs (``gpu/chunks.py``), so they must fit
one *buffer* (22.4 M triangles at 2 GiB); the widest bound whole must fit one *binding*: the
pixel boxes (16 bytes: 8,388,608 triangles at 128 MiB), or with the normal loss its per-corner
values (48 bytes: 2,796,202). A split is never made that would take the triangles past these, so
densification alone can never make the renderer refuse the model. (Until 2026-11-27 ``Tri2D``
had to fit one binding: 1,398,101 triangles at 128 MiB.) The per-pair buffers of a view are not
bounded here: they depend on how many tiles each triangle covers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ...gpu.wgsl import load_wgsl

#: bytes of the backward's gradients per triangle corner (``render/backward.py``: corner_grads)
CORNER_GRAD_BYTES = 32
#: bytes of the backward's per-vertex sums (``render/backward.py``: vertex_sums), the widest
#: per-vertex buffer bound whole
VERTEX_SUM_BYTES = 32
#: bytes a triangle of the widest per-triangle buffer bound whole: the pixel boxes
#: (``render/renderer.py``: pixel_rects); with the normal loss its per-corner values (48)
WHOLE_TRIANGLE_BYTES = 16
NORMAL_TRIANGLE_BYTES = 48


@dataclass(frozen=True)
class VertexCap:
    """The densification cap: ``vertices``, the ``bound`` that sets it (``"max-vertices"``,
    ``"vertex budget"``, ``"buffer-size limit"`` or ``"storage-binding limit"``), ``detail`` (what the cap is, for the
    reason of the pause at the cap; default the number), ``why`` (one sentence for ``tsplus train``),
    ``triangles`` (the most triangles one storage binding holds; None: no bound) and ``inputs``
    (the numbers it came from, for ``log.jsonl``)."""

    vertices: int
    bound: str = "max-vertices"
    detail: str | None = None
    why: str | None = None
    triangles: int | None = None
    inputs: dict = field(default_factory=dict)

    def reached(self, num_vertices):
        """The reason densification pauses at ``num_vertices`` (>= the cap)."""
        return f"{self.bound} reached ({num_vertices:,} >= {self.detail or f'{self.vertices:,}'})"

    def triangles_reached(self, num_triangles):
        """The reason densification pauses when a split (3 more triangles) would pass ``triangles``."""
        return (f"storage-binding limit reached ({num_triangles:,} triangles: a split would pass {self.triangles:,}, "
                f"the most this device's bindings and buffers hold)")

    def record(self):
        """The ``log.jsonl`` record of the cap (``event: vertex_cap``)."""
        return dict(event="vertex_cap", vertices=self.vertices, bound=self.bound,
                    **({"why": self.why} if self.why else {}),
                    **({"triangles": self.triangles} if self.triangles is not None else {}), **self.inputs)


def _mib(nbytes):
    return f"{nbytes / 2**20:,.0f} MiB"


def triangle_bytes():
    """Bytes a triangle of the largest per-triangle buffers: the projected triangle record
    (``Tri2D``, read from the WGSL) and the backward's 3 corner gradients."""
    return max(int(load_wgsl("project_triangles").structs["Tri2D"].itemsize), 3 * CORNER_GRAD_BYTES)


def vertex_cap(config, cameras, limits=None):
    """The densification cap of a run (see the module docstring): ``config`` a
    :class:`~..config.TrainConfig` (``max_vertices``, ``vertex_budget``, ``sh_degree``),
    ``cameras`` the training cameras at the training resolution, ``limits`` the device's
    (:attr:`~tsplus_wgpu.gpu.context.GpuContext.limits`; None: no device bound)."""
    most, budget = int(config.max_vertices), float(config.vertex_budget)
    inputs = dict(max_vertices=most, vertex_budget=budget)
    vertices, bound, detail, why = most, "max-vertices", None, "--max-vertices; no vertex budget"
    if budget > 0:
        pixels = float(np.mean([c.width * c.height for c in cameras]))
        inputs["training_pixels"] = pixels
        per_pixel = f"{budget} x {pixels:,.0f} training pixels"
        allowed = math.ceil(budget * pixels)
        if allowed < most:
            vertices, bound, detail = allowed, "vertex budget", per_pixel
            why = f"vertex budget {per_pixel}, under --max-vertices {most:,}"
        else:
            why = f"--max-vertices, under the vertex budget {per_pixel}"
    if limits is None:
        return VertexCap(vertices, bound, detail, why, None, inputs)
    binding = min(int(limits["max-storage-buffer-binding-size"]), int(limits["max-buffer-size"]))
    buffer = int(limits["max-buffer-size"])
    per_vertex, per_triangle = 12 * (int(config.sh_degree) + 1) ** 2, triangle_bytes()
    fit_sh, fit_sums = buffer // per_vertex, binding // VERTEX_SUM_BYTES
    inputs.update(storage_binding_bytes=binding, buffer_bytes=buffer, sh_bytes_per_vertex=per_vertex,
                  triangle_bytes=per_triangle)
    allows = f"{'the vertex budget' if bound == 'vertex budget' else '--max-vertices'} allows {vertices:,} vertices"
    if vertices > min(fit_sh, fit_sums):
        if fit_sh <= fit_sums:
            why = (f"{allows}, but their SH ({per_vertex} bytes a vertex) would need {_mib(vertices * per_vertex)}, "
                   f"over this device's {_mib(buffer)} buffer-size limit")
            vertices, bound = fit_sh, "buffer-size limit"
            detail = f"{fit_sh:,}, the most vertices whose SH fit one {_mib(buffer)} buffer"
        else:
            why = (f"{allows}, but the backward's vertex sums ({VERTEX_SUM_BYTES} bytes a vertex) would need "
                   f"{_mib(vertices * VERTEX_SUM_BYTES)}, over this device's {_mib(binding)} storage-binding limit")
            vertices, bound = fit_sums, "storage-binding limit"
            detail = f"{fit_sums:,}, the most vertices whose sums fit one {_mib(binding)} binding"
    whole = NORMAL_TRIANGLE_BYTES if getattr(config, "normals", None) else WHOLE_TRIANGLE_BYTES
    triangles = min(binding // whole, buffer // per_triangle)
    return VertexCap(vertices, bound, detail, why, triangles, inputs)


def initial_points_bound(config, cameras):
    """The most initial points a run meshes (None: all): ``config.init_points_share`` of the
    vertex cap (:func:`vertex_cap` without a device bound; ``cameras`` as there)."""
    share = float(getattr(config, "init_points_share", 0.0))
    if share <= 0:
        return None
    return max(3, math.ceil(share * vertex_cap(config, cameras).vertices))


__all__ = ["VertexCap", "vertex_cap", "triangle_bytes", "initial_points_bound"]
