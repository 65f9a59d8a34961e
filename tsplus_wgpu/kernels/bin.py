"""Host classes of shaders/bin/: (tile, triangle) pairs from the projected rectangles, and each tile's range of sorted pairs."""

from __future__ import annotations

from ..gpu import Stage
from ..gpu.chunks import pages


class BinRows(Stage):
    """Per triangle in depth order: the number of tile rows its pixel box spans (0 when culled)."""
    stage = "bin_rows"

    def __call__(self, enc, params, pixel_rects, tri_from_rank, rows, num_triangles, profiler=None):
        self.dispatch(enc, self.groups(num_triangles),
                      dict(params=params, pixel_rects=pixel_rects, tri_from_rank=tri_from_rank, rows=rows),
                      profiler)


class BinItems(Stage):
    """Every (triangle, tile row) item learns its triangle's depth rank."""
    stage = "bin_items"

    def __call__(self, enc, params, pixel_rects, tri_from_rank, row_offsets, item_rank, num_triangles,
                 profiler=None):
        self.dispatch(enc, self.groups(num_triangles),
                      dict(params=params, pixel_rects=pixel_rects, tri_from_rank=tri_from_rank,
                           row_offsets=row_offsets, item_rank=item_rank), profiler)


def _pages(stage, tris, m):
    """``[(ItemRange uniform, binding)]``: the ``m`` projected triangles ``tris`` (``Tri2D``
    records) a binding's page at a time where they outgrow one (``gpu/chunks.py``), else one
    page of all."""
    size = int(stage.src.structs["Tri2D"].itemsize)
    return [(stage.uniform("ItemRange", count=hi - lo, first=lo), page) for lo, hi, page in pages(stage.ctx, tris, m, size)]


class BinCount(Stage):
    """Per item the tiles of its row that the triangle meets; per tile the number of triangles."""
    stage = "bin_count"

    def __call__(self, enc, params, tris, pixel_rects, tri_from_rank, row_offsets, item_rank, counts, tile_counts,
                 num_rows, profiler=None, num_triangles=None):
        """``num_triangles``: how many records ``tris`` holds (default: as many as fit in it)."""
        enc.clear_buffer(tile_counts)
        m = tris.size // int(self.src.structs["Tri2D"].itemsize) if num_triangles is None else num_triangles
        for page, tri_page in _pages(self, tris, m):
            self.dispatch(enc, self.groups(num_rows),
                          dict(params=params, tris=tri_page, pixel_rects=pixel_rects, tri_from_rank=tri_from_rank,
                               row_offsets=row_offsets, item_rank=item_rank, counts=counts, tile_counts=tile_counts,
                               page=page), profiler)


class BinEmit(Stage):
    """Per item its (tile, triangle) pairs, written at its scanned offset."""
    stage = "bin_emit"

    def __call__(self, enc, params, tris, pixel_rects, tri_from_rank, row_offsets, item_rank, offsets, pair_tiles,
                 pair_tris, num_rows, profiler=None, num_triangles=None):
        """``num_triangles``: as in :class:`BinCount`."""
        m = tris.size // int(self.src.structs["Tri2D"].itemsize) if num_triangles is None else num_triangles
        for page, tri_page in _pages(self, tris, m):
            self.dispatch(enc, self.groups(num_rows),
                          dict(params=params, tris=tri_page, pixel_rects=pixel_rects, tri_from_rank=tri_from_rank,
                               row_offsets=row_offsets, item_rank=item_rank, offsets=offsets, pair_tiles=pair_tiles,
                               pair_tris=pair_tris, page=page), profiler)


class TileRanges(Stage):
    """Per tile the range [first, last + 1) of the pairs sorted by tile."""
    stage = "tile_ranges"

    def __call__(self, enc, pair_tiles, ranges, num_pairs, profiler=None):
        enc.clear_buffer(ranges)
        rp = self.uniform("RangeParams", num_pairs=num_pairs)
        self.dispatch(enc, self.groups(num_pairs), dict(rp=rp, pair_tiles=pair_tiles, ranges=ranges), profiler)
