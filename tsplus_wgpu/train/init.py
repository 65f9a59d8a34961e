"""Initial triangle model from SfM points: de-duplicate, 3D Delaunay (scipy/Qhull), keep all
unique faces of all tetrahedra; colours become SH DC, opacity 0.28.

Degenerate inputs (handled, never a hang or crash):

* non-finite points or colours: ``ValueError`` naming the count.
* duplicate points (within ``MERGE_TOL`` of the points' extent, so the same in any world
  units): merged before triangulating; their colours are averaged.
* fewer than 3 distinct points, or all distinct points on one line: ``ValueError``
  (no triangle can be formed).
* exactly 3 distinct non-collinear points: the single triangle.
* all points on one plane, or so nearly on one plane that the thickness is below
  ``flat_tol`` times the extent (smallest / largest singular value of the centred points):
  a 2-D Delaunay triangulation in that plane (points projected on its two principal
  axes); the 3-D positions are kept as they are.
* otherwise 3-D Delaunay with scipy's default Qhull options; if Qhull fails (e.g. a nearly
  flat cloud just above ``flat_tol``), once more with ``QJ`` (joggled input: every
  simplex is a real tetrahedron; the original, unjoggled positions are kept), and if that
  fails too the 2-D route above.
* faces of zero area (degenerate tetrahedra from co-spherical points) are dropped, and
  points that end in no face (Qhull's "coplanar" interior points) are removed.

Shards (``max_edge_ratio``, ``TrainConfig.init_max_edge``): a Delaunay tetrahedralisation
fills the convex hull of the points, so besides faces between neighbouring points on a
surface it has faces that span free space between distant points (the cup's: median edge
0.03, 99th percentile 0.6 camera radii). Trained, those become the flat shards across the
scene that real captures showed. A face is kept only when its longest edge is at most
``max_edge_ratio`` times the local point spacing of its vertices (the median of their three
distances to the 8th nearest point: one isolated vertex does not license a long face). With
3 it keeps 87 % of the cup's faces and 76 % of lund's (the rest are the faces through the
volume and across free space). What they covered is left to the background shell (:mod:`.shell`) and
to densification.

View faces (``view_faces``, ``TrainConfig.view_faces``): a tetrahedralisation's faces are chosen
by the points' 3-D positions alone, so where the points are sparse (a wall seen at a grazing
angle, a street's repeating cobbles) the surface between them is often no face of it, only
faces through the volume. A photo shows which points are neighbours on what it sees: each
training view's 2-D Delaunay triangulation of the points it observed (their pixels) joins the
points next to each other in that photo, a surface as that view sees it.
:func:`view_faces` adds those faces to the tetrahedralisation's. Faces across a depth edge (a
roof point and the sky beyond it) are long in 3-D and go with the long faces above. Off by
default: lund's forward walk gains 0.18 dB, the other shared scenes nothing or less
(docs/measurements.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import Delaunay, QhullError, cKDTree

from ..types import TriangleModel
from .schedules import INIT_OPACITY

SH_C0 = 0.28209479177387814
FLAT_TOL = 1e-6
AREA_TOL = 1e-12   # relative to extent^2
SPACING_NEIGHBOUR = 8


@dataclass
class InitInfo:
    """How the triangulation was obtained."""
    method: str            # "delaunay3d", "delaunay3d-QJ", "delaunay2d", "single"
    num_input: int         # points given
    num_unique: int        # after de-duplication
    num_dropped: int       # unique points in no face (removed)
    num_degenerate_faces: int
    num_long_faces: int = 0    # dropped by ``max_edge_ratio``
    num_carved_faces: int = 0  # crossed by camera-to-point rays (``visibility``)
    num_bounded: int = 0       # scene points left out before meshing (train.initial.bounded_points)
    num_path_faces: int = 0    # on the training cameras' path (train.initial, train.floaters)
    num_view_faces: int = 0    # added by ``view_faces`` (not faces of the tetrahedralisation)


#: points closer than this share of their extent are one point (:func:`_unique_points`)
MERGE_TOL = 1e-9


def _check(name, arr, cols):
    arr = np.asarray(arr, np.float64)
    if arr.ndim != 2 or arr.shape[1] != cols:
        raise ValueError(f"{name}: expected shape [N, {cols}], got {arr.shape}")
    bad = arr.shape[0] - int(np.count_nonzero(np.all(np.isfinite(arr), axis=1)))
    if bad:
        raise ValueError(f"{name}: {bad} point(s) with NaN or Inf coordinates; remove them first")
    return arr


def _faces_of_tets(tets):
    """All unique faces of the tetrahedra, as sorted index triples in lexicographic order."""
    tets = np.asarray(tets, np.int64)
    f = np.concatenate([tets[:, [0, 1, 2]], tets[:, [0, 1, 3]], tets[:, [0, 2, 3]], tets[:, [1, 2, 3]]])
    f.sort(axis=1)
    return np.unique(f, axis=0)


def _plane_axes(pts):
    centre = pts.mean(axis=0)
    _, s, vt = np.linalg.svd(pts - centre, full_matrices=False)
    return centre, s, vt


def _delaunay2d(pts, vt, centre):
    uv = (pts - centre) @ vt[:2].T
    tri = Delaunay(uv, qhull_options="Qbb Qc Qz")
    return np.sort(np.asarray(tri.simplices, np.int64), axis=1)


def delaunay_faces(points, flat_tol=FLAT_TOL, return_delaunay=False):
    """Triangles of the Delaunay tetrahedralisation of distinct ``points`` [N, 3].

    Returns ``(faces [M, 3] int64, method)``, plus scipy's ``Delaunay`` (None on the 2-D and
    single-triangle routes) with ``return_delaunay``; see the module docstring for the
    degenerate cases.
    """
    faces, method, tri = _delaunay_faces(points, flat_tol)
    return (faces, method, tri) if return_delaunay else (faces, method)


def _delaunay_faces(points, flat_tol):
    pts = np.asarray(points, np.float64)
    n = pts.shape[0]
    if n < 3:
        raise ValueError(f"points: need at least 3 distinct points to form a triangle, got {n}")
    centre, s, vt = _plane_axes(pts)
    if s[0] == 0 or s[1] <= flat_tol * s[0]:
        raise ValueError(f"points: all {n} distinct points lie on one line; no triangle can be formed")
    if n == 3:
        return np.array([[0, 1, 2]], np.int64), "single", None
    if s[2] <= flat_tol * s[0]:
        return _delaunay2d(pts, vt, centre), "delaunay2d", None
    for opts, method in (("Qbb Qc Qz Q12", "delaunay3d"), ("QJ Qbb Qz", "delaunay3d-QJ")):
        try:
            tri = Delaunay(pts, qhull_options=opts)
        except QhullError:
            continue
        if len(tri.simplices):
            return _faces_of_tets(tri.simplices), method, tri
    return _delaunay2d(pts, vt, centre), "delaunay2d", None


def local_spacing(points, k=SPACING_NEIGHBOUR):
    """Distance of every point to its ``k``-th nearest other point (fewer points: the farthest)."""
    pts = np.asarray(points, np.float64)
    k = min(int(k), len(pts) - 1)
    if k < 1:
        return np.zeros(len(pts))
    dist, _ = cKDTree(pts).query(pts, k=k + 1)
    return dist[:, k]


def long_faces(points, faces, max_edge_ratio):
    """Mask of the faces whose longest edge exceeds ``max_edge_ratio`` x the median local
    spacing (:func:`local_spacing`) of their three vertices."""
    p = np.asarray(points, np.float64)
    f = np.asarray(faces, np.int64)
    edge = np.max([np.linalg.norm(p[f[:, i]] - p[f[:, (i + 1) % 3]], axis=1) for i in range(3)], axis=0)
    return edge > float(max_edge_ratio) * np.median(local_spacing(p)[f], axis=1)


def view_faces(points, observed):
    """The faces of each view's 2-D Delaunay triangulation of the points it observed (module
    docstring): ``observed`` is a sequence of ``(camera, rows)``, a :class:`~tsplus_wgpu.Camera`
    and the rows of ``points`` [P, 3] it observed. Returns ``[F, 3]`` int64 rows of ``points``,
    each sorted, in lexicographic order, unique. Points behind a camera are left out of its
    triangulation; a view with fewer than 3 points, or all of them on one line, gives none."""
    pts = np.asarray(points, np.float64)
    out = [np.zeros((0, 3), np.int64)]
    for camera, rows in observed:
        rows = np.unique(np.asarray(rows, np.int64))
        if len(rows) < 3:
            continue
        uv, z = camera.project(pts[rows])
        front = z > 0
        rows, uv = rows[front], uv[front]
        if len(rows) < 3:
            continue
        try:
            tri = Delaunay(uv)
        except QhullError:   # fewer than 3 distinct pixels, or all on one line
            continue
        out.append(rows[np.asarray(tri.simplices, np.int64)])
    faces = np.sort(np.concatenate(out), axis=1)
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2])]
    return np.unique(faces, axis=0)


def _with_view_faces(faces, extra, inverse):
    """``(faces, number added)``: ``faces`` (sorted rows, lexicographic, unique) and the rows of
    ``extra`` (rows of the input points, mapped to the de-duplicated ones by ``inverse``) that
    are not among them, in lexicographic order."""
    if extra is None or not len(extra):
        return faces, 0
    f = np.sort(inverse[np.asarray(extra, np.int64)], axis=1)
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2])]
    both = np.unique(np.concatenate([faces, f]), axis=0)
    return both, len(both) - len(faces)


def _carve(uniq, faces, tri, inverse, visibility):
    """``(faces, number carved)``: ``faces`` less those the observations cross (:mod:`.carve`);
    none carved without a 3-D tetrahedralisation or rays, and never every face."""
    if visibility is None or tri is None or not len(visibility[0]):
        return faces, 0
    from .carve import carve_mask
    ray_pt, origins = visibility
    cfaces, carved, _ = carve_mask(uniq, tri, inverse[np.asarray(ray_pt, np.int64)], origins)
    if cfaces.shape != faces.shape or not np.array_equal(cfaces, faces):
        raise RuntimeError("carve: the tetrahedralisation's faces do not match")   # same construction
    if carved.all():
        return faces, 0
    return faces[~carved], int(np.count_nonzero(carved))


def _merged(pts):
    """``pts`` with every group of points within :data:`MERGE_TOL` x the extent of each other
    (chained) given the coordinates of its first point."""
    extent = float(np.ptp(pts, axis=0).max()) if len(pts) else 0.0
    if len(pts) < 2 or extent <= 0.0:
        return pts
    pairs = cKDTree(pts).query_pairs(MERGE_TOL * extent, output_type="ndarray")
    if not len(pairs):
        return pts
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    n = len(pts)
    _, label = connected_components(coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n)),
                                    directed=False)
    first = np.full(label.max() + 1, n)
    np.minimum.at(first, label, np.arange(n))
    return pts[first[label]]


def _own_frame(points, origins=None):
    """``(points, origins)`` centred on the points' mean and divided by their extent (the
    largest side of their bounding box; 1 when they coincide); ``origins`` None stays None. In
    the world's numbers Qhull's round-off is another (docs/measurements.md, "The triangulation in
    a frame of its own (2026-12-04)")."""
    if not len(points):
        return points, origins
    centre, extent = points.mean(axis=0), float(np.ptp(points, axis=0).max())
    extent = extent if extent > 0.0 else 1.0
    moved = None if origins is None else (np.asarray(origins, np.float64).reshape(-1, 3) - centre) / extent
    return (points - centre) / extent, moved


def _unique_points(pts, cols):
    """``(unique points, inverse [P], their colours)``: copies merged (points within
    :data:`MERGE_TOL` of the points' extent of each other: each takes the coordinates of the
    first of its group), their colours averaged. Exact equality would depend on the world's
    numbers: lund's 12,450 triangulated points hold 8 pairs about 1e-12 of the scene apart that
    became exact copies once the world was scaled by 1000 and shifted."""
    pts = _merged(pts)
    uniq, inverse = np.unique(pts, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    counts = np.bincount(inverse, minlength=len(uniq)).astype(np.float64)
    ucol = np.stack([np.bincount(inverse, weights=cols[:, c], minlength=len(uniq)) for c in range(3)], 1).astype(np.float64)
    ucol /= np.maximum(counts, 1.0)[:, None]
    return uniq, inverse, ucol


def init_from_points(points, colors=None, sh_degree=3, opacity=INIT_OPACITY, flat_tol=FLAT_TOL,
                     return_info=False, max_edge_ratio=None, visibility=None, extra_faces=None):
    """The initial :class:`~tsplus_wgpu.TriangleModel` from SfM points.

    Args:
        points: ``[P, 3]`` positions (NaN/Inf rejected with a ValueError).
        colors: ``[P, 3]`` RGB in [0, 1] (floats) or 0..255 (uint8); None gives grey (0.5).
        sh_degree: SH degree of the model's storage (0..3); coefficients above DC are 0.
        opacity: activated opacity of every vertex (0.28).
        flat_tol: relative thickness below which the cloud is treated as planar.
        return_info: also return an :class:`InitInfo`.
        max_edge_ratio: drop faces longer than this many local point spacings (see the module
            docstring; None or 0: keep every face). Never drops every face: if it would, the
            filter is not applied.
        visibility: ``(ray_pt [R], origins [R, 3])``: observations (a row of ``points``, the
            observing camera's centre); faces the segments cross are carved (:mod:`.carve`).
        extra_faces: ``[F, 3]`` rows of ``points`` (:func:`view_faces`) added to the Delaunay
            faces (after the carving, before the degenerate and long faces are dropped).

    Returns:
        a TriangleModel whose vertices are the distinct points used by a face and whose
        triangles are all unique faces of all Delaunay tetrahedra (or the 2-D fallback).
    """
    pts = _check("points", points, 3)
    if colors is None:
        cols = np.full_like(pts, 0.5)
    else:
        raw = np.asarray(colors)
        cols = _check("colors", raw, 3)
        if cols.shape[0] != pts.shape[0]:
            raise ValueError(f"colors: expected {pts.shape[0]} rows (one per point), got {cols.shape[0]}")
        if raw.dtype == np.uint8:
            cols = cols / 255.0
    if not 0 <= int(sh_degree) <= 3:
        raise ValueError(f"sh_degree: expected 0..3, got {sh_degree!r}")
    if not 0.0 <= float(opacity) <= 1.0:
        raise ValueError(f"opacity: expected a value in [0, 1], got {opacity!r}")

    uniq, inverse, ucol = _unique_points(pts, cols)

    # Qhull and the carving's walk in the points' own frame: any world units give one mesh (:func:`_own_frame`)
    own, origins_own = _own_frame(uniq, None if visibility is None else visibility[1])
    faces, method, tri = delaunay_faces(own, flat_tol, return_delaunay=True)
    faces, num_carved = _carve(own, faces, tri, inverse, None if visibility is None else (visibility[0], origins_own))
    faces, num_view = _with_view_faces(faces, extra_faces, inverse)

    # Drop zero-area faces.
    a, b, c = uniq[faces[:, 0]], uniq[faces[:, 1]], uniq[faces[:, 2]]
    area2 = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    extent = float(np.ptp(uniq, axis=0).max())
    keep = area2 > 2.0 * AREA_TOL * extent * extent
    num_degenerate = int(np.count_nonzero(~keep))
    faces = faces[keep]
    if len(faces) == 0:
        raise ValueError("points: every candidate triangle is degenerate (zero area); no triangle can be formed")
    num_long = 0
    if max_edge_ratio:
        long = long_faces(uniq, faces, max_edge_ratio)
        if not long.all():
            num_long = int(np.count_nonzero(long))
            faces = faces[~long]

    # Keep only the vertices some face uses, renumbered in their sorted order.
    used = np.zeros(len(uniq), bool)
    used[faces.ravel()] = True
    new_from_old = np.cumsum(used) - 1
    positions = uniq[used]
    tris = new_from_old[faces]

    k = (int(sh_degree) + 1) ** 2
    sh = np.zeros((len(positions), k, 3))
    sh[:, 0] = (ucol[used] - 0.5) / SH_C0
    model = TriangleModel(positions, tris, sh, np.full(len(positions), float(opacity)))
    if return_info:
        info = InitInfo(method=method, num_input=len(pts), num_unique=len(uniq),
                        num_dropped=int(np.count_nonzero(~used)), num_degenerate_faces=num_degenerate,
                        num_long_faces=num_long, num_carved_faces=num_carved, num_view_faces=num_view)
        return model, info
    return model
