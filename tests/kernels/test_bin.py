"""shaders/bin/: bin_rows, bin_items, bin_count, bin_emit, tile_ranges, each alone, against
their twins, exactly. Each kernel's inputs are made by the twins of the stages before it
(project_triangles' records rounded to float32, as the kernel would have written them)."""

import numpy as np
import pytest
from scenes import f32_exact, random_scene

from tsplus_wgpu.kernels.bin import BinCount, BinEmit, BinItems, BinRows, TileRanges
from tsplus_wgpu.kernels.project import frame_params
from tsplus_wgpu.reference import bin as twin
from tsplus_wgpu.reference.project import TRI2D, project_triangles, sh_to_color
from tsplus_wgpu.reference.sort import prefix_sum, radix_sort
from scenes import submit as run

F32 = lambda a: np.asarray(a, np.float64).astype(np.float32)


# name: (seed, width, height, sheets, points per sheet, spread)
SCENES = {"1x1-no-pair": (1, 1, 1, 1, 3, 1.3), "1x1-one-pair": (2, 1, 1, 1, 3, 1.3),
          "17x33": (2, 17, 33, 3, 8, 1.3), "256x192": (3, 256, 192, 4, 10, 1.3),
          "640x480-many": (4, 640, 480, 3, 90, 1.3), "1200x800-big": (5, 1200, 800, 2, 4, 3.0)}


class Inputs:
    """One view's binning inputs from the twins: Tri2D records (float32 for the kernel, the same
    numbers in float64 for the twin), pixel boxes, the depth order, tile counts."""

    def __init__(self, ctx, scene, sigma):
        seed, w, h, sheets, pts, spread = SCENES[scene]
        model, cam = f32_exact(*random_scene(seed, w, h, sheets=sheets, points_per_sheet=pts, spread=spread))
        colors = F32(sh_to_color(model.positions, model.sh, cam.center))
        tris, self.rects, keys, _ = project_triangles(model.positions, model.triangles, model.opacity, colors, cam.R,
                                                      cam.t, cam.fx, cam.fy, cam.cx, cam.cy, 0.01, sigma, w, h)
        self.tris32 = np.zeros(len(tris), BinCount(ctx).src.structs["Tri2D"])
        self.tris = np.zeros(len(tris), TRI2D)
        for name in TRI2D.names:
            self.tris32[name] = tris[name]
            self.tris[name] = self.tris32[name]
        self.order = np.argsort(keys, kind="stable").astype(np.uint32)      # the depth sort
        self.cam, self.sigma, self.m = cam, sigma, len(tris)
        self.tiles_x, self.tiles_y = -(-w // 16), -(-h // 16)
        self.num_tiles = self.tiles_x * self.tiles_y
        self.row_offsets, self.num_rows = prefix_sum(twin.bin_rows(self.rects, self.order))
        self.item_rank = twin.bin_items(self.rects, self.order, self.row_offsets, self.num_rows)
        self.counts, _ = twin.bin_count(self.tris, self.rects, self.order, self.row_offsets, self.item_rank,
                                        self.tiles_x, self.num_tiles)
        self.offsets, self.num_pairs = prefix_sum(self.counts)

    def params(self, stage, num_pairs=None):
        return frame_params(stage, self.cam, self.sigma, num_triangles=self.m, num_rows=self.num_rows,
                            num_pairs=self.num_pairs if num_pairs is None else num_pairs)

    def upload(self, ctx):
        return dict(tris=ctx.upload(self.tris32), pixel_rects=ctx.upload(self.rects.astype(np.int32)),
                    tri_from_rank=ctx.upload(self.order), row_offsets=ctx.upload(self.row_offsets),
                    item_rank=ctx.upload(self.item_rank))


@pytest.fixture(params=[(s, sigma) for s in SCENES for sigma in (1.0, 1e-4)], ids=lambda p: f"{p[0]}-{p[1]:g}")
def inputs(request, ctx):
    scene, sigma = request.param
    return Inputs(ctx, scene, sigma)


def test_tile_matches_the_wgsl(ctx):
    assert BinRows(ctx).const("TILE") == twin.TILE == 16


def test_bin_rows(ctx, max_dim, inputs):
    stage, b = BinRows(ctx), inputs.upload(ctx)
    rows = ctx.buffer(4 * inputs.m)
    run(ctx, lambda enc: stage(enc, inputs.params(stage), b["pixel_rects"], b["tri_from_rank"], rows, inputs.m))
    ref = twin.bin_rows(inputs.rects, inputs.order)
    np.testing.assert_array_equal(ctx.read(rows, np.uint32, inputs.m), ref)
    assert ref.sum() == inputs.num_rows > 0
    assert inputs.num_pairs > 0 or inputs.m == 1      # (one scene whose only row meets no tile)


def test_bin_items(ctx, max_dim, inputs):
    stage, b = BinItems(ctx), inputs.upload(ctx)
    item_rank = ctx.buffer(4 * inputs.num_rows)
    run(ctx, lambda enc: stage(enc, inputs.params(stage), b["pixel_rects"], b["tri_from_rank"], b["row_offsets"],
                               item_rank, inputs.m))
    ref = twin.bin_items(inputs.rects, inputs.order, inputs.row_offsets, inputs.num_rows)
    np.testing.assert_array_equal(ctx.read(item_rank, np.uint32, inputs.num_rows), ref)
    assert np.all(np.diff(ref.astype(np.int64)) >= 0)        # items come in depth-rank order


def test_bin_count(ctx, max_dim, inputs):
    stage, b = BinCount(ctx), inputs.upload(ctx)
    counts, tile_counts = ctx.buffer(4 * inputs.num_rows), ctx.buffer(4 * inputs.num_tiles)
    run(ctx, lambda enc: stage(enc, inputs.params(stage), b["tris"], b["pixel_rects"], b["tri_from_rank"],
                               b["row_offsets"], b["item_rank"], counts, tile_counts, inputs.num_rows))
    ref_counts, ref_tiles = twin.bin_count(inputs.tris, inputs.rects, inputs.order, inputs.row_offsets,
                                           inputs.item_rank, inputs.tiles_x, inputs.num_tiles)
    np.testing.assert_array_equal(ctx.read(counts, np.uint32, inputs.num_rows), ref_counts)
    np.testing.assert_array_equal(ctx.read(tile_counts, np.uint32, inputs.num_tiles), ref_tiles)
    assert ref_tiles.sum() == ref_counts.sum() == inputs.num_pairs


@pytest.mark.parametrize("drop", [0, 3], ids=["all", "num_pairs-3"])
def test_bin_emit(ctx, max_dim, inputs, drop):
    """All pairs; and with num_pairs 3 short (the kernel drops writes past it)."""
    if inputs.num_pairs <= drop:
        pytest.skip("no pairs to write")
    stage, b = BinEmit(ctx), inputs.upload(ctx)
    p = inputs.num_pairs - drop
    pair_tiles, pair_tris = ctx.buffer(4 * p), ctx.buffer(4 * p)
    run(ctx, lambda enc: stage(enc, inputs.params(stage, p), b["tris"], b["pixel_rects"], b["tri_from_rank"],
                               b["row_offsets"], b["item_rank"], ctx.upload(inputs.offsets), pair_tiles, pair_tris,
                               inputs.num_rows))
    ref_tiles, ref_tris = twin.bin_emit(inputs.tris, inputs.rects, inputs.order, inputs.row_offsets,
                                        inputs.item_rank, inputs.offsets, inputs.tiles_x, p)
    np.testing.assert_array_equal(ctx.read(pair_tiles, np.uint32, p), ref_tiles)
    np.testing.assert_array_equal(ctx.read(pair_tris, np.uint32, p), ref_tris)
    if not drop:   # the twins composed, sorted by tile: the whole binning twin
        bits = max(1, int(inputs.num_tiles - 1).bit_length())
        tiles, tris = radix_sort(ref_tiles, ref_tris, bits)
        t = inputs.tris
        want = twin.bin_pairs(t["s"], np.stack([t["g0"], t["g1"], t["g2"]], 1), t["tau"], inputs.rects,
                              inputs.order, inputs.cam.width, inputs.cam.height)
        np.testing.assert_array_equal(tiles, want[0])
        np.testing.assert_array_equal(tris, want[1])


def _tile_ranges(ctx, pair_tiles, num_tiles):
    stage = TileRanges(ctx)
    ranges = ctx.buffer(8 * num_tiles)
    run(ctx, lambda enc: stage(enc, ctx.upload(pair_tiles.astype(np.uint32)), ranges, len(pair_tiles)))
    return ctx.read(ranges, np.uint32, 2 * num_tiles).reshape(-1, 2)


def test_tile_ranges(ctx, max_dim, inputs):
    tiles, _ = twin.bin_emit(inputs.tris, inputs.rects, inputs.order, inputs.row_offsets, inputs.item_rank,
                             inputs.offsets, inputs.tiles_x, inputs.num_pairs)
    tiles = np.sort(tiles)
    np.testing.assert_array_equal(_tile_ranges(ctx, tiles, inputs.num_tiles), twin.tile_ranges(tiles, inputs.num_tiles))


@pytest.mark.parametrize("n", [1, 2, 257, 65535 * 256 + 1001], ids=["1", "2", "257", "over-65535-groups"])
def test_tile_ranges_sizes(ctx, n):
    """Synthetic sorted tiles, incl. more than 65535 workgroups (a real 2-D grid) and empty tiles."""
    rng = np.random.default_rng(n)
    num_tiles = 5003
    tiles = np.sort(rng.integers(0, num_tiles, n) // 2 * 2)      # odd tiles stay empty
    ref = twin.tile_ranges(tiles, num_tiles)
    np.testing.assert_array_equal(_tile_ranges(ctx, tiles, num_tiles), ref)
    assert np.all(ref[1::2] == 0) and (ref[:, 1] - ref[:, 0]).sum() == n
