"""Float64 twins of shaders/bin/: :func:`bin_rows`, :func:`bin_items`, :func:`bin_count`,
:func:`bin_emit`, :func:`tile_ranges`; :func:`tile_overlaps` (shaders/common/triangle.wgsl)
and :func:`bin_pairs`, the whole binning (count, emit, stable sort by tile) for one view.

Work items are (triangle, tile row) pairs: triangle of depth rank j owns items
``row_offsets[j] .. row_offsets[j] + rows[j] - 1``, one per tile row of its pixel box.
Integer divisions truncate toward zero, as WGSL's i32 division does."""

from __future__ import annotations

import numpy as np

from .project import BIN_MARGIN, TILE


def _div(a, b):
    """WGSL i32 division: truncates toward zero."""
    a = np.asarray(a, np.int64)
    return np.sign(a) * (np.abs(a) // b)


def _valid(rect):
    return (rect[..., 0] <= rect[..., 2]) & (rect[..., 1] <= rect[..., 3])


def tile_overlaps(s, g, tau, rect, tx, ty):
    """Vectorised twin of shaders/common/triangle.wgsl:tile_overlaps for one triangle
    over arrays of tile coordinates."""
    x0 = np.maximum(rect[0], tx * TILE)
    y0 = np.maximum(rect[1], ty * TILE)
    x1 = np.minimum(rect[2], tx * TILE + TILE - 1)
    y1 = np.minimum(rect[3], ty * TILE + TILE - 1)
    ok = (x0 <= x1) & (y0 <= y1)
    lo = np.stack([x0, y0], -1) + 0.5
    hi = np.stack([x1, y1], -1) + 0.5
    thr = tau - BIN_MARGIN
    for k in range(3):
        corner = np.where(g[k][None, :] > 0, hi, lo)
        e = 1.0 + (corner - s[None, :]) @ g[k]
        ok &= e >= thr
    return ok


def _overlaps(s, g, tau, rect, tx, ty):
    """tile_overlaps for arrays of (triangle, tile) candidates: s [K, 2], g [K, 3, 2], tau [K],
    rect [K, 4], tx [K], ty [K]."""
    x0 = np.maximum(rect[:, 0], tx * TILE)
    y0 = np.maximum(rect[:, 1], ty * TILE)
    x1 = np.minimum(rect[:, 2], tx * TILE + TILE - 1)
    y1 = np.minimum(rect[:, 3], ty * TILE + TILE - 1)
    ok = (x0 <= x1) & (y0 <= y1)
    lo = np.stack([x0, y0], -1) + 0.5
    hi = np.stack([x1, y1], -1) + 0.5
    thr = tau - BIN_MARGIN
    for k in range(3):
        corner = np.where(g[:, k] > 0, hi, lo)
        ok &= 1.0 + np.einsum("ki,ki->k", g[:, k], corner - s) >= thr
    return ok


def bin_rows(pixel_rects, tri_from_rank):
    """Twin of bin_rows: ``rows [M]`` uint32, the tile rows of the pixel box of the triangle of
    each depth rank (0 for an empty box)."""
    rect = np.asarray(pixel_rects, np.int64)[np.asarray(tri_from_rank, np.int64)]     # [M, 4]
    n = _div(rect[:, 3], TILE) - _div(rect[:, 1], TILE) + 1
    return np.where(_valid(rect), n, 0).astype(np.uint32)


def bin_items(pixel_rects, tri_from_rank, row_offsets, num_rows):
    """Twin of bin_items: ``item_rank [num_rows]`` uint32, ``item_rank[row_offsets[j] + r] = j``
    for each row r of rank j (slots no rank writes stay 0)."""
    rows = bin_rows(pixel_rects, tri_from_rank).astype(np.int64)
    rank = np.repeat(np.arange(rows.shape[0]), rows)                 # [sum rows]
    first = np.cumsum(rows) - rows                                   # where each rank's rows start in `rank`
    r = np.arange(rank.shape[0]) - first[rank]
    item_rank = np.zeros(num_rows, np.uint32)
    item_rank[np.asarray(row_offsets, np.int64)[rank] + r] = rank
    return item_rank


def _item_tiles(tris, pixel_rects, tri_from_rank, row_offsets, item_rank, tiles_x):
    """Every (item, tile of its row) candidate, item-major then by tile x:
    (item q [K], triangle t [K], tile index [K], overlaps [K] bool)."""
    rank = np.asarray(item_rank, np.int64)
    t = np.asarray(tri_from_rank, np.int64)[rank]                    # [R]
    rect = np.asarray(pixel_rects, np.int64)[t]                      # [R, 4]
    ty = _div(rect[:, 1], TILE) + (np.arange(rank.shape[0]) - np.asarray(row_offsets, np.int64)[rank])
    tx0, tx1 = _div(rect[:, 0], TILE), _div(rect[:, 2], TILE)
    ntx = np.maximum(tx1 - tx0 + 1, 0)
    q = np.repeat(np.arange(rank.shape[0]), ntx)                     # [K]
    tx = tx0[q] + (np.arange(q.shape[0]) - (np.cumsum(ntx) - ntx)[q])
    f = lambda name: np.asarray(tris[name], np.float64)[t[q]]
    g = np.stack([f("g0"), f("g1"), f("g2")], axis=1)
    ok = _overlaps(f("s"), g, f("tau"), rect[q], tx, ty[q])
    return q, t[q], ty[q] * tiles_x + tx, ok


def bin_count(tris, pixel_rects, tri_from_rank, row_offsets, item_rank, tiles_x, num_tiles):
    """Twin of bin_count.

    Args:
        tris: Tri2D records [M] (fields s, g0, g1, g2, tau are read); pixel_rects [M, 4];
        tri_from_rank [M]; row_offsets [M] (by rank); item_rank [R]; the uniform's tiles_x; the tile count.

    Returns:
        ``(counts [R], tile_counts [num_tiles])`` uint32: the tiles each item's row meets, and
        the triangles each tile meets.
    """
    q, _, tile, ok = _item_tiles(tris, pixel_rects, tri_from_rank, row_offsets, item_rank, tiles_x)
    counts = np.bincount(q[ok], minlength=len(item_rank)).astype(np.uint32)
    tile_counts = np.bincount(tile[ok], minlength=num_tiles).astype(np.uint32)
    return counts, tile_counts


def bin_emit(tris, pixel_rects, tri_from_rank, row_offsets, item_rank, offsets, tiles_x, num_pairs):
    """Twin of bin_emit: ``(pair_tiles [P], pair_tris [P])`` uint32, item q's pairs written from
    ``offsets[q]`` on (those at or past ``num_pairs`` dropped; slots nobody writes stay 0)."""
    q, t, tile, ok = _item_tiles(tris, pixel_rects, tri_from_rank, row_offsets, item_rank, tiles_x)
    q, t, tile = q[ok], t[ok], tile[ok]
    start = np.searchsorted(q, q, side="left")                       # q is sorted: the item's first pair
    dst = np.asarray(offsets, np.int64)[q] + (np.arange(q.shape[0]) - start)
    keep = dst < num_pairs
    pair_tiles = np.zeros(num_pairs, np.uint32)
    pair_tris = np.zeros(num_pairs, np.uint32)
    pair_tiles[dst[keep]] = tile[keep]
    pair_tris[dst[keep]] = t[keep]
    return pair_tiles, pair_tris


def tile_ranges(pair_tiles, num_tiles):
    """Twin of tile_ranges: ``ranges [num_tiles, 2]`` uint32, [first, last + 1) of each tile's
    run in ``pair_tiles`` (sorted), zero for a tile without pairs."""
    tiles = np.asarray(pair_tiles, np.int64)
    i = np.arange(tiles.shape[0])
    ranges = np.zeros((num_tiles, 2), np.uint32)
    first = np.ones(tiles.shape[0], bool)
    first[1:] = tiles[1:] != tiles[:-1]
    last = np.ones(tiles.shape[0], bool)
    last[:-1] = tiles[:-1] != tiles[1:]
    ranges[tiles[first], 0] = i[first]
    ranges[tiles[last], 1] = i[last] + 1
    return ranges


def bin_pairs(s, g, tau, rect, order, width, height):
    """Twin of bin_count/bin_emit + the stable sort by tile: (pair_tiles, pair_tris)
    ordered by tile, then depth rank. Inputs are per-triangle arrays (any float type)."""
    tiles_x = (width + TILE - 1) // TILE
    all_tiles, all_tris = [], []
    for t in order:
        r = rect[t]
        if r[0] > r[2] or r[1] > r[3]:
            continue
        ty, tx = np.meshgrid(np.arange(r[1] // TILE, r[3] // TILE + 1), np.arange(r[0] // TILE, r[2] // TILE + 1),
                             indexing="ij")
        tx, ty = tx.ravel(), ty.ravel()
        ok = tile_overlaps(np.asarray(s[t], np.float64), np.asarray(g[t], np.float64), float(tau[t]), r, tx, ty)
        all_tiles.append((ty[ok] * tiles_x + tx[ok]).astype(np.int64))
        all_tris.append(np.full(int(ok.sum()), t, np.int64))
    if not all_tiles:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    tiles = np.concatenate(all_tiles)
    tris = np.concatenate(all_tris)
    idx = np.argsort(tiles, kind="stable")
    return tiles[idx], tris[idx]
