"""Track tables: which views observed each initial point (SfM tracks).

A track table is a tuple ``(offsets, views)`` in compressed-row form:

* ``offsets``: int64 ``[P + 1]``, ``offsets[0] == 0``, nondecreasing, ``offsets[-1] == len(views)``;
* ``views``: int32 ``[K]``, one entry per observation.

The views observing point ``p`` are ``views[offsets[p]:offsets[p + 1]]``; in a
:class:`~tsplus_wgpu.data.scene.Scene` (``point_tracks``) each is an index into ``scene.cameras``.
A point may have an empty track.
"""

from __future__ import annotations

import itertools

import numpy as np

__all__ = ["check", "counts", "from_lists", "from_mask", "of_pycolmap_points", "rays", "remap", "subset"]


def _table(offsets, views):
    return np.ascontiguousarray(offsets, np.int64), np.ascontiguousarray(views, np.int32)


def _offsets_of(lengths) -> np.ndarray:
    offsets = np.zeros(len(lengths) + 1, np.int64)
    np.cumsum(lengths, out=offsets[1:])
    return offsets


def from_lists(lists) -> tuple:
    """The table of ``lists``: one sequence of view ids per point, kept in the given order."""
    lists = [np.asarray(v, np.int64).ravel() for v in lists]
    offsets = _offsets_of(np.array([len(v) for v in lists], np.int64))
    views = np.fromiter(itertools.chain.from_iterable(lists), np.int64, count=int(offsets[-1]))
    return _table(offsets, views)


def from_mask(mask) -> tuple:
    """The table of a ``[P, N]`` bool visibility matrix (point p seen by view v), views ascending."""
    mask = np.asarray(mask, bool)
    if mask.ndim != 2:
        raise ValueError(f"mask: expected a [P, N] bool array, got shape {mask.shape}")
    _, views = np.nonzero(mask)   # row-major: grouped by point, views ascending
    return _table(_offsets_of(mask.sum(1)), views)


def of_pycolmap_points(rec, points, view_of_name: dict) -> tuple:
    """The table of ``points`` (pycolmap ``Point3D`` objects of the reconstruction ``rec``): per
    point the views whose images observe it, ascending and once each (an image can observe a
    point twice); ``view_of_name`` maps an image name of ``rec`` to its view id, and observations
    of images it does not name are dropped."""
    view_of_image = {int(iid): view_of_name.get(im.name, -1) for iid, im in rec.images.items()}
    lists = []
    for p in points:
        seen = {view_of_image.get(el.image_id, -1) for el in p.track.elements}
        seen.discard(-1)
        lists.append(sorted(seen))
    return from_lists(lists)


def counts(table) -> np.ndarray:
    """int64 ``[P]``: the number of observations of each point."""
    return np.diff(table[0])


def subset(table, keep) -> tuple:
    """The table of the kept points, in the given order.

    Args:
        keep: bool mask ``[P]``, or an array of point indices (repeats allowed).
    """
    offsets, views = table
    num = len(offsets) - 1
    keep = np.asarray(keep)
    if keep.dtype == bool:
        if keep.shape != (num,):
            raise ValueError(f"keep: bool mask of shape {keep.shape} for {num} points")
        idx = np.flatnonzero(keep)
    else:
        if keep.size and not np.issubdtype(keep.dtype, np.integer):
            raise ValueError(f"keep: expected a bool mask or integer indices, got dtype {keep.dtype}")
        idx = keep.astype(np.int64).ravel()
        if idx.size and (idx.min() < 0 or idx.max() >= num):
            raise ValueError(f"keep: point indices must lie in [0, {num}), got {idx.min()}..{idx.max()}")
    starts = offsets[idx]
    lengths = offsets[idx + 1] - starts
    new_offsets = _offsets_of(lengths)
    pos = np.repeat(starts - new_offsets[:-1], lengths) + np.arange(new_offsets[-1], dtype=np.int64)
    return _table(new_offsets, views[pos])


def remap(table, mapping) -> tuple:
    """Every view id ``v`` becomes ``mapping[v]``; ids mapped to -1 (any negative) are dropped.

    Points keep their place even when their track becomes empty.

    Args:
        mapping: integer array with an entry for every view id in the table.
    """
    offsets, views = table
    mapping = np.asarray(mapping, np.int64).ravel()
    if views.size and (views.min() < 0 or views.max() >= len(mapping)):
        raise ValueError(f"mapping: {len(mapping)} entries, but the table has view ids "
                         f"{views.min()}..{views.max()}")
    new = mapping[views]
    ok = new >= 0
    point = np.repeat(np.arange(len(offsets) - 1, dtype=np.int64), np.diff(offsets))
    lengths = np.bincount(point[ok], minlength=len(offsets) - 1)
    return _table(_offsets_of(lengths), new[ok])


def check(table, num_points: int, num_views: int) -> None:
    """Raise ValueError naming what is wrong unless ``table`` is a valid track table for
    ``num_points`` points and ``num_views`` views."""
    if not isinstance(table, tuple) or len(table) != 2:
        raise ValueError(f"track table: expected a tuple (offsets, views), got {type(table).__name__}"
                         + (f" of length {len(table)}" if isinstance(table, (tuple, list)) else ""))
    offsets, views = table
    for name, arr, dtype in (("offsets", offsets, np.int64), ("views", views, np.int32)):
        if not isinstance(arr, np.ndarray):
            raise ValueError(f"track table {name}: expected a numpy array, got {type(arr).__name__}")
        if arr.ndim != 1:
            raise ValueError(f"track table {name}: expected a 1-D array, got shape {arr.shape}")
        if arr.dtype != dtype:
            raise ValueError(f"track table {name}: expected dtype {np.dtype(dtype).name}, got {arr.dtype}")
    if len(offsets) != num_points + 1:
        raise ValueError(f"track table offsets: expected {num_points + 1} entries for {num_points} points, "
                         f"got {len(offsets)}")
    if offsets[0] != 0:
        raise ValueError(f"track table offsets: must start at 0, got {offsets[0]}")
    if np.any(np.diff(offsets) < 0):
        bad = int(np.flatnonzero(np.diff(offsets) < 0)[0])
        raise ValueError(f"track table offsets: must be nondecreasing, but offsets[{bad + 1}] = "
                         f"{offsets[bad + 1]} < offsets[{bad}] = {offsets[bad]}")
    if offsets[-1] != len(views):
        raise ValueError(f"track table offsets: last entry {offsets[-1]} != number of views {len(views)}")
    if views.size and (views.min() < 0 or views.max() >= num_views):
        raise ValueError(f"track table views: ids must lie in [0, {num_views}), got {views.min()}..{views.max()}")


def rays(table) -> tuple:
    """One row per observation: ``(point index int64 [K], view int32 [K])``."""
    offsets, views = table
    return np.repeat(np.arange(len(offsets) - 1, dtype=np.int64), np.diff(offsets)), views
