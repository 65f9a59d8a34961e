"""Host classes of shaders/project/: per-vertex SH -> colour and per-triangle projection;
and :func:`frame_params`, the ``FrameParams`` uniform (``shaders/common/frame.wgsl``) that
the project, bin and blend kernels read."""

from __future__ import annotations

from ..gpu import Stage
from ..gpu.wgsl import constant


def frame_params(stage, camera, sigma, background=(0.0, 0.0, 0.0), near=0.01, num_vertices=0, num_triangles=0,
                 sh_k=0, num_pairs=0, num_rows=0):
    """The ``FrameParams`` uniform buffer of one view, built through ``stage`` (any kernel
    that imports ``frame``); tiles are ``TILE`` (frame.wgsl) pixels square."""
    tile = constant("TILE", "frame")
    R, t = camera.R, camera.t
    return stage.uniform(
        "FrameParams",
        rot0=[*R[0], t[0]], rot1=[*R[1], t[1]], rot2=[*R[2], t[2]],
        cam_center=[*camera.center, 0.0], background=[*background, 0.0],
        fx=camera.fx, fy=camera.fy, cx=camera.cx, cy=camera.cy, near=near, sigma=sigma,
        width=camera.width, height=camera.height,
        tiles_x=(camera.width + tile - 1) // tile, tiles_y=(camera.height + tile - 1) // tile,
        num_vertices=num_vertices, num_triangles=num_triangles, sh_k=sh_k, num_pairs=num_pairs, num_rows=num_rows)


class ShToColor(Stage):
    """Per vertex: ``colors[v] = (max(0, SH(dir_v) + 0.5), 1)``; in chunks of vertices where the
    SH ``[N, K, 3]`` are larger than one storage binding (:mod:`tsplus_wgpu.gpu.chunks`)."""
    stage = "sh_to_color"

    def __call__(self, enc, params, positions, sh, colors, num_vertices, profiler=None, sh_size=None):
        """``sh_size``: K (default: from the buffer's size, ``sh.size // (12 N)``)."""
        n = int(num_vertices)
        k = int(sh_size) if sh_size is not None else max(1, sh.size // max(12 * n, 1))
        per_item(self, enc, n, dict(positions=(positions, 12), sh_coeffs=(sh, 12 * k), colors=(colors, 16)),
                   dict(params=params), profiler)


def per_item(stage, enc, n, arrays, fixed, profiler=None):
    """:meth:`~tsplus_wgpu.gpu.Stage.dispatch_ranges` for the per-vertex and per-triangle kernels, whose uniform
    ``items`` is the range (``ItemRange``)."""
    stage.dispatch_ranges(enc, n, arrays, fixed, lambda s, c: dict(items=stage.uniform("ItemRange", count=c, first=s)),
                          profiler)


class ProjectTriangles(Stage):
    """Per triangle: the ``Tri2D`` record, pixel box, depth key and identity index."""
    stage = "project_triangles"

    def __call__(self, enc, params, positions, triangles, opacities, colors, tris, pixel_rects, depth_keys,
                 tri_ids, num_triangles, profiler=None):
        """In ranges of triangles where ``tris`` outgrows one binding (``gpu/chunks.py``)."""
        per_item(self, enc, num_triangles, dict(tris=(tris, int(self.src.structs["Tri2D"].itemsize))),
                   dict(params=params, positions=positions, triangles=triangles, opacities=opacities, colors=colors,
                        pixel_rects=pixel_rects, depth_keys=depth_keys, tri_ids=tri_ids), profiler)
