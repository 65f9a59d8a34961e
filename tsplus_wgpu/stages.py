"""One small class per WGSL stage (``shaders/<stage>.wgsl`` <-> ``CamelCase``), each owning
its pipeline and recording its dispatch with buffers bound by name; plus the two
multi-dispatch primitives built from them, :class:`PrefixSum` and :class:`RadixSort`.
"""

from __future__ import annotations

import numpy as np
import wgpu

from .gpu import GpuContext, Stage

SCAN_BLOCK = 1024
SORT_BLOCK = 2048
SORT_BITS_PER_PASS = 4
#: Pairs per tile that one blend dispatch handles at most: lavapipe ends loops after
#: 65535 iterations per invocation, and the blend spends about 1 + 1/128 per pair.
BLEND_PASS_PAIRS = 256 * 128


def _groups(n, per):
    return max(1, (int(n) + per - 1) // per)


class ShToColor(Stage):
    stage = "sh_to_color"

    def __call__(self, enc, params, positions, sh, colors, num_vertices, profiler=None):
        self.dispatch(enc, _groups(num_vertices, 256),
                      dict(params=params, positions=positions, sh_coeffs=sh, colors=colors), profiler)


class ProjectTriangles(Stage):
    stage = "project_triangles"

    def __call__(self, enc, params, positions, triangles, opacities, colors, tris, pixel_rects, depth_keys,
                 tri_ids, num_triangles, profiler=None):
        self.dispatch(enc, _groups(num_triangles, 256),
                      dict(params=params, positions=positions, triangles=triangles, opacities=opacities,
                           colors=colors, tris=tris, pixel_rects=pixel_rects, depth_keys=depth_keys,
                           tri_ids=tri_ids), profiler)


class BinRows(Stage):
    stage = "bin_rows"

    def __call__(self, enc, params, pixel_rects, tri_from_rank, rows, num_triangles, profiler=None):
        self.dispatch(enc, _groups(num_triangles, 256),
                      dict(params=params, pixel_rects=pixel_rects, tri_from_rank=tri_from_rank, rows=rows),
                      profiler)


class BinItems(Stage):
    stage = "bin_items"

    def __call__(self, enc, params, pixel_rects, tri_from_rank, row_offsets, item_rank, num_triangles,
                 profiler=None):
        self.dispatch(enc, _groups(num_triangles, 256),
                      dict(params=params, pixel_rects=pixel_rects, tri_from_rank=tri_from_rank,
                           row_offsets=row_offsets, item_rank=item_rank), profiler)


class BinCount(Stage):
    stage = "bin_count"

    def __call__(self, enc, params, tris, pixel_rects, tri_from_rank, row_offsets, item_rank, counts, tile_counts,
                 num_rows, profiler=None):
        enc.clear_buffer(tile_counts)
        self.dispatch(enc, _groups(num_rows, 256),
                      dict(params=params, tris=tris, pixel_rects=pixel_rects, tri_from_rank=tri_from_rank,
                           row_offsets=row_offsets, item_rank=item_rank, counts=counts, tile_counts=tile_counts),
                      profiler)


class BinEmit(Stage):
    stage = "bin_emit"

    def __call__(self, enc, params, tris, pixel_rects, tri_from_rank, row_offsets, item_rank, offsets, pair_tiles,
                 pair_tris, num_rows, profiler=None):
        self.dispatch(enc, _groups(num_rows, 256),
                      dict(params=params, tris=tris, pixel_rects=pixel_rects, tri_from_rank=tri_from_rank,
                           row_offsets=row_offsets, item_rank=item_rank, offsets=offsets, pair_tiles=pair_tiles,
                           pair_tris=pair_tris), profiler)


class MaxReduce(Stage):
    stage = "max_reduce"

    def __call__(self, enc, values, result, n, profiler=None, label=None):
        rp = self.uniform("ReduceParams", n=n)
        self.dispatch(enc, 1, dict(rp=rp, values=values, result=result), profiler, label)


class TileRanges(Stage):
    stage = "tile_ranges"

    def __call__(self, enc, pair_tiles, ranges, num_pairs, profiler=None):
        enc.clear_buffer(ranges)
        rp = self.uniform("RangeParams", num_pairs=num_pairs)
        self.dispatch(enc, _groups(num_pairs, 256), dict(rp=rp, pair_tiles=pair_tiles, ranges=ranges), profiler)


class RasterizeForward(Stage):
    stage = "rasterize_forward"

    def __call__(self, enc, params, ranges, pair_tris, tris, image, final_t, n_contrib, max_weight, work,
                 tiles_x, tiles_y, max_tile_pairs, profiler=None):
        """Blends in ceil(max_tile_pairs / BLEND_PASS_PAIRS) dispatches (one in practice)."""
        enc.clear_buffer(max_weight)
        enc.clear_buffer(work)
        passes = max(1, -(-int(max_tile_pairs) // BLEND_PASS_PAIRS))
        for i in range(passes):
            bp = self.uniform("BlendPass", begin=i * BLEND_PASS_PAIRS, end=(i + 1) * BLEND_PASS_PAIRS,
                              first=int(i == 0), last=int(i == passes - 1))
            self.dispatch(enc, (tiles_x, tiles_y, 1),
                          dict(params=params, ranges=ranges, pair_tris=pair_tris, tris=tris, image=image,
                               final_t=final_t, n_contrib=n_contrib, max_weight=max_weight, pass_=bp,
                               work=work), profiler)


class RasterizeIds(Stage):
    stage = "rasterize_ids"

    def __call__(self, enc, params, ranges, pair_tris, tris, id_state, triangle_ids, tiles_x, tiles_y,
                 max_tile_pairs, profiler=None):
        """Per pixel the triangle of largest alpha * T (0xFFFFFFFF: none), over the same sorted
        tile lists as :class:`RasterizeForward`, in as many passes."""
        passes = max(1, -(-int(max_tile_pairs) // BLEND_PASS_PAIRS))
        for i in range(passes):
            bp = self.uniform("BlendPass", begin=i * BLEND_PASS_PAIRS, end=(i + 1) * BLEND_PASS_PAIRS,
                              first=int(i == 0), last=int(i == passes - 1))
            self.dispatch(enc, (tiles_x, tiles_y, 1),
                          dict(params=params, ranges=ranges, pair_tris=pair_tris, tris=tris, id_state=id_state,
                               triangle_ids=triangle_ids, pass_=bp), profiler)


class ScanBlock(Stage):
    stage = "scan_block"


class ScanAdd(Stage):
    stage = "scan_add"


class RadixCount(Stage):
    stage = "radix_count"


class RadixScatter(Stage):
    stage = "radix_scatter"


class PeakFma(Stage):
    stage = "peak_fma"


class Scratch:
    """Named device buffers that grow on demand and are reused between calls."""

    def __init__(self, ctx: GpuContext):
        self.ctx = ctx
        self.buffers = {}

    def get(self, name, nbytes):
        nbytes = max(16, int(nbytes))
        buf = self.buffers.get(name)
        if buf is None or buf.size < nbytes:
            cap = nbytes if buf is None else max(nbytes, min(buf.size * 3 // 2, self.ctx.limits["max-storage-buffer-binding-size"]))
            cap = (cap + 255) // 256 * 256
            buf = self.ctx.buffer(cap, label=name)
            self.buffers[name] = buf
        return buf


class PrefixSum:
    """Exclusive prefix sum of u32 in place, any length: 1024 per workgroup, block sums
    scanned recursively and added back. ``record`` returns a buffer whose first element
    is the grand total."""

    def __init__(self, ctx: GpuContext, scratch: Scratch):
        self.ctx = ctx
        self.scratch = scratch
        self.block = ScanBlock(ctx)
        self.add = ScanAdd(ctx)

    def record(self, enc, data, n, level=0, profiler=None, label="scan"):
        nb = _groups(n, SCAN_BLOCK)
        sums = self.scratch.get(f"scan_sums_{level}", 4 * nb)
        sp = self.block.uniform("ScanParams", n=n)
        self.block.dispatch(enc, nb, dict(sp=sp, data=data, block_sums=sums), profiler, label)
        if nb == 1:
            return sums
        total = self.record(enc, sums, nb, level + 1, profiler, label)
        self.add.dispatch(enc, nb, dict(sp=sp, data=data, block_offsets=sums), profiler, label)
        return total


class RadixSort:
    """Stable LSD radix sort of u32 keys with u32 values, 4 bits per pass, portable
    (no subgroups, no waiting on other workgroups). Only the low ``bits`` bits are sorted."""

    def __init__(self, ctx: GpuContext, scratch: Scratch, name="sort"):
        self.ctx = ctx
        self.scratch = scratch
        self.name = name
        self.count = RadixCount(ctx)
        self.scatter = RadixScatter(ctx)
        self.scan = PrefixSum(ctx, scratch)

    def record(self, enc, keys, vals, n, bits=32, profiler=None):
        """Sorts (keys, vals) of length ``n``. Returns the (keys, vals) buffers holding the
        result: the inputs themselves after an even number of passes, else scratch."""
        passes = (int(bits) + SORT_BITS_PER_PASS - 1) // SORT_BITS_PER_PASS
        if n <= 1 or passes == 0:
            return keys, vals
        nb = _groups(n, SORT_BLOCK)
        counts = self.scratch.get(f"{self.name}_counts", 4 * 16 * nb)
        k_alt = self.scratch.get(f"{self.name}_keys_alt", 4 * n)
        v_alt = self.scratch.get(f"{self.name}_vals_alt", 4 * n)
        src = (keys, vals)
        dst = (k_alt, v_alt)
        for p in range(passes):
            sp = self.count.uniform("SortParams", n=n, shift=SORT_BITS_PER_PASS * p, num_blocks=nb)
            self.count.dispatch(enc, nb, dict(sp=sp, keys=src[0], counts=counts), profiler, self.name)
            self.scan.record(enc, counts, 16 * nb, profiler=profiler, label=self.name)
            self.scatter.dispatch(enc, nb, dict(sp=sp, keys_in=src[0], vals_in=src[1], offsets=counts,
                                                keys_out=dst[0], vals_out=dst[1]), profiler, self.name)
            src, dst = dst, src
        return src

    def sort(self, keys, vals=None, bits=32):
        """Convenience for tests and tools: sort numpy arrays, return numpy arrays."""
        keys = np.ascontiguousarray(keys, dtype=np.uint32)
        n = keys.shape[0]
        vals = np.arange(n, dtype=np.uint32) if vals is None else np.ascontiguousarray(vals, dtype=np.uint32)
        kb = self.ctx.upload(keys, "sort_keys")
        vb = self.ctx.upload(vals, "sort_vals")
        enc = self.ctx.device.create_command_encoder()
        ko, vo = self.record(enc, kb, vb, n, bits)
        self.ctx.queue.submit([enc.finish()])
        return self.ctx.read(ko, np.uint32, n), self.ctx.read(vo, np.uint32, n)


def scan_numpy(ctx: GpuContext, values):
    """Run :class:`PrefixSum` on a numpy array (tests); returns (exclusive scan, total)."""
    values = np.ascontiguousarray(values, dtype=np.uint32)
    n = values.shape[0]
    buf = ctx.upload(values, "scan_data")
    scan = PrefixSum(ctx, Scratch(ctx))
    enc = ctx.device.create_command_encoder()
    total = scan.record(enc, buf, n)
    ctx.queue.submit([enc.finish()])
    return ctx.read(buf, np.uint32, n), int(ctx.read(total, np.uint32, 1)[0])


__all__ = ["ShToColor", "ProjectTriangles", "BinRows", "BinItems", "BinCount", "BinEmit", "MaxReduce", "BLEND_PASS_PAIRS", "TileRanges", "RasterizeForward", "RasterizeIds",
           "PrefixSum", "RadixSort", "Scratch", "PeakFma", "scan_numpy", "wgpu"]
