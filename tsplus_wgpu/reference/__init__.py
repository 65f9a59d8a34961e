"""Float64 NumPy twins: one module per ``shaders/<group>/`` with one function per kernel,
named like it (``reference.<group>.<kernel>``), and the whole passes: :func:`render`
(forward) and ``render_backward.backward`` / ``render_backward.loss``.

No name of this package's namespace is also the name of one of its modules, so
``reference.<group>`` is always the module, whatever was imported before."""

from ..sh import sh_basis, vertex_colors
from ..types import SH_C0
from . import (backward, bench, bin, blend, forward, loss, mesh, normals, optim, project, reduce, render_backward, sort,
               topology)
from .bin import bin_count, bin_emit, bin_items, bin_pairs, bin_rows, tile_overlaps, tile_ranges
from .blend import IdResult, RenderResult, gather_tris, rasterize_forward, rasterize_ids, triangle_ids
from .forward import render
from .project import (ALPHA_MAX, ALPHA_MIN, BIN_MARGIN, MIN_THINNESS, T_MIN, TILE, TRI2D, Projection, project_triangles,
                      projection, projection_from_records, sh_to_color)
from .sort import depth_order, prefix_sum, radix_count, radix_scatter, radix_sort, scan_add, scan_block

__all__ = ["backward", "bench", "bin", "blend", "forward", "loss", "mesh", "normals", "optim", "project", "reduce",
           "render_backward", "sort", "topology",
           "sh_basis", "vertex_colors", "SH_C0", "bin_count", "bin_emit", "bin_items", "bin_pairs", "bin_rows",
           "tile_overlaps", "tile_ranges", "IdResult", "RenderResult", "rasterize_forward", "rasterize_ids",
           "triangle_ids", "gather_tris", "render", "ALPHA_MAX", "ALPHA_MIN", "BIN_MARGIN", "MIN_THINNESS", "T_MIN", "TILE", "TRI2D",
           "Projection", "project_triangles", "projection", "projection_from_records", "sh_to_color", "depth_order",
           "prefix_sum", "radix_count", "radix_scatter", "radix_sort", "scan_add", "scan_block"]
