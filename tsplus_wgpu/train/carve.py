"""Visibility carving of the initial Delaunay mesh (free-space faces out before training).

A Delaunay tetrahedralisation of SfM points fills their convex hull: besides the faces that
lie on the captured surfaces it has faces across the empty space between them and the
cameras. Trained, those faces turn into the shards real captures show (and they are most of
the initial triangles, so they also cost most of the first iterations' time).

SfM says which cameras observed each point (its *track*, :mod:`tsplus_wgpu.data.tracks`). A
camera that saw a point saw it through empty space: the segment from the camera centre to
the point crosses no surface. Every face that segment crosses is in free space. The segments
are walked through the tetrahedralisation (all rays at once, one tetrahedron per step):

* start: among the tetrahedra around the point, the one the direction towards the camera
  enters (all barycentric rates of the other three vertices >= 0);
* step: in tetrahedron ``t`` at ray parameter ``s`` (0 at the point, 1 at the camera), the
  ray leaves through the face opposite the vertex whose barycentric coordinate reaches 0
  first; that face is counted as crossed, and the walk goes on in the neighbour across it;
* stop: the camera lies in the current tetrahedron (exit parameter >= 1), or the ray leaves
  the convex hull (no neighbour), or ``max_steps``.

Crossings closer to the point than ``margin`` of its distance to the camera are not counted:
a point is a noisy sample of the surface, and the faces right around it are the surface. A
face crossed by at least ``min_votes`` rays is removed (:func:`carve_mask`). The float64 walk
is the whole implementation (NumPy, host side, once per run before training; no kernel).
"""

from __future__ import annotations

import numpy as np

#: local vertex indices of the face opposite local vertex i of a tetrahedron
OPPOSITE = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])
MARGIN = 0.02
MIN_VOTES = 1
MAX_STEPS = 20000
CHUNK = 1 << 15


def tet_faces(tets):
    """``(faces [F, 3], tet_face [T, 4])``: the unique faces of the tetrahedra as sorted index
    triples in lexicographic order, and the id of the face opposite each local vertex."""
    tets = np.asarray(tets, np.int64)
    f = tets[:, OPPOSITE].reshape(-1, 3)
    f.sort(axis=1)
    faces, inverse = np.unique(f, axis=0, return_inverse=True)
    return faces, inverse.reshape(len(tets), 4)


def _incidence(tets, num_points):
    """``(start [P+1], tet [4T], local [4T])``: the tetrahedra around each vertex (CSR)."""
    flat = np.asarray(tets, np.int64).ravel()
    order = np.argsort(flat, kind="stable")
    start = np.zeros(num_points + 1, np.int64)
    np.cumsum(np.bincount(flat, minlength=num_points), out=start[1:])
    return start, order // 4, order % 4


def _bary_rate(transform, tet, d):
    """Rates of change of the 4 barycentric coordinates along direction(s) ``d`` [N, 3]."""
    r3 = np.einsum("nij,nj->ni", transform[tet, :3, :], d)
    return np.concatenate([r3, -r3.sum(axis=1, keepdims=True)], axis=1)


def _bary(transform, tet, x):
    """The 4 barycentric coordinates of ``x`` [N, 3] in tetrahedra ``tet``."""
    b3 = np.einsum("nij,nj->ni", transform[tet, :3, :], x - transform[tet, 3, :])
    return np.concatenate([b3, 1.0 - b3.sum(axis=1, keepdims=True)], axis=1)


def _start_tets(transform, tets, incidence, ray_pt, d):
    """For every ray, the tetrahedron around its point that the ray enters, or -1 (it leaves
    the hull right away)."""
    start, inc_tet, inc_local = incidence
    deg = start[ray_pt + 1] - start[ray_pt]
    rows = np.repeat(np.arange(len(ray_pt)), deg)
    pos = np.arange(len(rows)) - np.repeat(np.cumsum(deg) - deg, deg) + np.repeat(start[ray_pt], deg)
    tet, local = inc_tet[pos], inc_local[pos]
    rate = _bary_rate(transform, tet, d[rows])
    scale = np.abs(rate).max(axis=1) + 1e-300
    rate[np.arange(len(rows)), local] = np.inf          # the point's own coordinate is free to fall
    score = rate.min(axis=1) / scale
    best = np.full(len(ray_pt), -np.inf)
    np.maximum.at(best, rows, score)
    win = score >= best[rows]
    out = np.full(len(ray_pt), -1, np.int64)
    # the first winner per ray (rows are grouped, so reversed assignment keeps the first)
    out[rows[win][::-1]] = tet[win][::-1]
    out[best < -1e-9] = -1
    return out


def crossing_counts(points, tets, neighbors, transform, ray_pt, origins, margin=MARGIN, max_steps=MAX_STEPS):
    """How many rays cross each face of the tetrahedralisation.

    Args:
        points: ``[P, 3]`` float64 vertices of the tetrahedralisation.
        tets, neighbors, transform: scipy ``Delaunay``'s ``simplices``, ``neighbors`` and
            ``transform`` for ``points``.
        ray_pt: ``[R]`` the point each ray ends at (its vertex index).
        origins: ``[R, 3]`` the camera centre each ray starts from.
        margin: crossings within this fraction of the point-to-camera distance of the point
            are not counted.
    Returns:
        ``(faces [F, 3], counts [F] int64, info dict)``; ``faces`` as :func:`tet_faces`.
    """
    pts = np.asarray(points, np.float64)
    tets = np.asarray(tets, np.int64)
    neighbors = np.asarray(neighbors, np.int64)
    transform = np.asarray(transform, np.float64)
    faces, tet_face = tet_faces(tets)
    counts = np.zeros(len(faces), np.int64)
    incidence = _incidence(tets, len(pts))
    ray_pt = np.asarray(ray_pt, np.int64)
    origins = np.asarray(origins, np.float64).reshape(-1, 3)
    info = dict(rays=int(len(ray_pt)), steps=0, unfinished=0, left_hull=0, reached_camera=0)
    for lo in range(0, len(ray_pt), CHUNK):
        rp, org = ray_pt[lo:lo + CHUNK], origins[lo:lo + CHUNK]
        p = pts[rp]
        d = org - p
        tet = _start_tets(transform, tets, incidence, rp, d)
        live = tet >= 0
        info["left_hull"] += int(np.count_nonzero(~live))
        p, d, tet = p[live], d[live], tet[live]
        s = np.zeros(len(tet))
        for _ in range(max_steps):
            if len(tet) == 0:
                break
            info["steps"] += 1
            lam = _bary(transform, tet, p + s[:, None] * d)
            rate = _bary_rate(transform, tet, d)
            with np.errstate(divide="ignore", invalid="ignore"):
                t_exit = np.where(rate < 0, s[:, None] + np.maximum(lam, 0.0) / -rate, np.inf)
            i = np.argmin(t_exit, axis=1)
            s_exit = t_exit[np.arange(len(tet)), i]
            inside = s_exit >= 1.0                 # the camera is in this tetrahedron
            info["reached_camera"] += int(np.count_nonzero(inside))
            go = ~inside
            face = tet_face[tet[go], i[go]]
            far = s_exit[go] >= margin
            counts += np.bincount(face[far], minlength=len(faces))
            nxt = neighbors[tet[go], i[go]]
            out = nxt < 0
            info["left_hull"] += int(np.count_nonzero(out))
            keep = np.flatnonzero(go)[~out]
            tet, s = nxt[~out], np.maximum(s_exit[go][~out], s[keep])
            p, d = p[keep], d[keep]
        info["unfinished"] += int(len(tet))
    return faces, counts, info


def carve_mask(points, delaunay, ray_pt, origins, margin=MARGIN, min_votes=MIN_VOTES):
    """Free-space faces of a tetrahedralisation, seen from SfM tracks.

    Args:
        points: ``[P, 3]`` the tetrahedralisation's vertices.
        delaunay: a scipy ``Delaunay`` of ``points`` (its simplices, neighbors, transform).
        ray_pt, origins: one row per observation (:func:`tsplus_wgpu.data.tracks.rays`): the
            observed point's index and the centre of the camera that observed it.
    Returns:
        ``(faces [F, 3], carved [F] bool, info dict)``; ``faces`` as :func:`tet_faces`.
    """
    faces, counts, info = crossing_counts(points, delaunay.simplices, delaunay.neighbors, delaunay.transform,
                                          ray_pt, origins, margin=margin)
    carved = counts >= int(min_votes)
    info.update(faces=int(len(faces)), carved=int(np.count_nonzero(carved)))
    return faces, carved, info
