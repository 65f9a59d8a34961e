"""Floaters on the cameras' path: surface triangles in the space the training cameras moved
through (:func:`path_floaters`, used by the end of training, :mod:`.final`).

The photographer carried the camera from one viewpoint to the next, so the space along that
path is empty. A trained triangle there is a floater: from the training cameras on either side
it is small and shows, in each of their photos, a patch of the scene far behind it, so the
photo loss keeps it; from a viewpoint between them it fills the image. Lund (a street walked
forwards, training cameras about 0.35 world units apart) ends its default run with such
triangles 0.2-0.6 units in front of held-out cameras: one covers 79 % of held-out view 16 and
at most 23 % of any training view, most of the others under 5 %.

The path is the graph that links every training camera to its :data:`PATH_NEIGHBOURS` nearest
(no link longer than :data:`PATH_MAX_LINK` x the median spacing, so a misregistered camera far
from the others is not linked), plus the camera centres. A surface triangle comes *near* the path
when some point of it lies within :data:`PATH_RADIUS` x the median spacing of a link or centre:
relative to how far apart the photos were taken, so it does not depend on the world's units.
Distances are measured on a barycentric grid of the triangle whose neighbouring points are at
most a quarter of that radius apart (large triangles get a finer grid), so a triangle is found
when a point of it is within 0.75 of the radius, and never when all of it is beyond the radius.
"""

from __future__ import annotations

import numpy as np

from .shell import SURFACE

#: links of the path graph: each training camera to this many nearest others
PATH_NEIGHBOURS = 2
#: no link longer than this many median spacings (the median distance to the nearest camera)
PATH_MAX_LINK = 3.0
#: a triangle is a floater within this many median spacings of the path
PATH_RADIUS = 0.5
#: grid points at most this share of the radius apart
GRID_STEP = 0.25
#: finest grid: this many steps along an edge (the spacing above holds up to 64 radii an edge)
MAX_STEPS = 256
#: grid points measured at once
MAX_POINTS = 1 << 20


def camera_path(centres):
    """``(links [L, 2] into centres, spacing)``: the path graph (module docstring) and the median
    distance from a camera to its nearest other. Fewer than 2 cameras: no links, spacing 0."""
    c = np.asarray(centres, np.float64).reshape(-1, 3)
    if len(c) < 2:
        return np.zeros((0, 2), np.int64), 0.0
    d = np.linalg.norm(c[:, None] - c[None], axis=2)
    np.fill_diagonal(d, np.inf)
    spacing = float(np.median(d.min(axis=1)))
    links = set()
    for i in range(len(c)):
        for j in np.argsort(d[i])[:PATH_NEIGHBOURS]:
            if d[i, j] <= PATH_MAX_LINK * spacing:
                links.add((min(i, int(j)), max(i, int(j))))
    return np.array(sorted(links), np.int64).reshape(-1, 2), spacing


def path_distance(points, centres, links, chunk=4096):
    """``[N]``: each point's distance to the nearest camera centre or link segment."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    c = np.asarray(centres, np.float64).reshape(-1, 3)
    out = np.full(len(p), np.inf)
    a, b = c[links[:, 0]], c[links[:, 1]]
    ab = b - a
    ab2 = np.maximum((ab * ab).sum(axis=1), 1e-300)
    for s in range(0, len(p), chunk):
        q = p[s:s + chunk]
        best = np.linalg.norm(q[:, None] - c[None], axis=2).min(axis=1) if len(c) else out[s:s + chunk]
        if len(links):
            t = np.clip(((q[:, None] - a[None]) * ab[None]).sum(axis=2) / ab2[None], 0.0, 1.0)
            seg = np.linalg.norm(q[:, None] - (a[None] + t[..., None] * ab[None]), axis=2).min(axis=1)
            best = np.minimum(best, seg)
        out[s:s + chunk] = best
    return out


def may_reach(points, centres, links, limit):
    """``[N]`` bool: the points whose distance to the path (:func:`path_distance`) may be under
    ``limit`` [N]. A lower bound rules the rest out without measuring: a point of a link lies
    within half the link's length of one of its ends, so the path is never nearer than the
    nearest centre (a k-d tree) less half the longest link. Exact: nothing it drops is within
    ``limit``; the margin of 1e-9 covers the rounding."""
    from scipy.spatial import cKDTree
    p = np.asarray(points, np.float64).reshape(-1, 3)
    c = np.asarray(centres, np.float64).reshape(-1, 3)
    if not len(c) or not len(p):
        return np.ones(len(p), bool)
    half = 0.5 * float(np.linalg.norm(c[links[:, 1]] - c[links[:, 0]], axis=1).max()) if len(links) else 0.0
    nearest = cKDTree(c).query(p)[0]
    return nearest - half < np.asarray(limit, np.float64) + 1e-9 * (nearest + half + np.abs(limit))


def _grid(steps):
    """Barycentric weights ``[K, 3]`` of the grid with ``steps`` steps along each edge."""
    i, j = np.meshgrid(np.arange(steps + 1), np.arange(steps + 1), indexing="ij")
    keep = (i + j) <= steps
    i, j = i[keep], j[keep]
    return np.column_stack([steps - i - j, i, j]).astype(np.float64) / steps


def near_path(positions, triangles, centres, radius=None):
    """``[F]`` bool: the triangles with a point within ``radius`` (default :data:`PATH_RADIUS`
    x the median camera spacing) of the cameras' path (module docstring)."""
    tri = np.asarray(triangles, np.int64).reshape(-1, 3)
    out = np.zeros(len(tri), bool)
    links, spacing = camera_path(centres)
    if spacing <= 0 or not len(tri):
        return out
    r = PATH_RADIUS * spacing if radius is None else float(radius)
    v = np.asarray(positions, np.float64)[tri]                       # [F, 3, 3]
    cen = v.mean(axis=1)
    reach = np.linalg.norm(v - cen[:, None], axis=2).max(axis=1)      # bounding sphere about the centroid
    maybe = np.flatnonzero(may_reach(cen, centres, links, r + reach))   # most are far: not measured
    cand = maybe[path_distance(cen[maybe], centres, links) < r + reach[maybe]]
    if not len(cand):
        return out
    edge = np.linalg.norm(v[cand] - np.roll(v[cand], 1, axis=1), axis=2).max(axis=1)
    steps = np.clip(np.ceil(edge / (GRID_STEP * r)), 1, MAX_STEPS).astype(np.int64)
    for n in np.unique(steps):
        w = _grid(int(n))                                             # [K, 3]
        group = cand[steps == n]
        per = max(1, MAX_POINTS // len(w))                            # bounded memory for huge triangles
        for s in range(0, len(group), per):
            idx = group[s:s + per]
            pts = np.einsum("kc,fcd->fkd", w, v[idx]).reshape(-1, 3)
            d = path_distance(pts, centres, links).reshape(len(idx), len(w))
            out[idx] = d.min(axis=1) < r
    return out


def path_floaters(positions, triangles, groups, cameras):
    """``[F]`` bool: the surface triangles (``groups`` :data:`~.shell.SURFACE`, or all when None; the shell is far
    beyond the path) near the path of ``cameras`` (the training cameras; their frame)."""
    centres = np.array([c.center for c in cameras], np.float64).reshape(-1, 3)
    tri = np.asarray(triangles, np.int64).reshape(-1, 3)
    is_surface = np.ones(len(tri), bool) if groups is None else np.asarray(groups) == SURFACE
    out = np.zeros(len(tri), bool)
    if is_surface.any():
        out[is_surface] = near_path(positions, tri[is_surface], centres)
    return out


__all__ = ["PATH_NEIGHBOURS", "PATH_MAX_LINK", "PATH_RADIUS", "camera_path", "path_distance", "may_reach",
           "near_path", "path_floaters"]
