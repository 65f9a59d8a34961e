"""The mesh as a collider (:class:`MeshCollider`): closest-point and ray queries against a
triangle mesh, used by the sphere world (:mod:`.physics`) and the viewer's walking mode.

Queries (:class:`MeshCollider`): ``closest_points`` (per point, the nearest point of the mesh
within a radius: exact closest point on each candidate triangle, candidates from a uniform
grid of triangle bounding boxes) and ``raycast`` (first hit: through trimesh's embree
intersector when ``embreex`` is installed, else the same grid with a vectorised
Moller-Trumbore test; trimesh's own non-embree intersector needs ``rtree``, which is not a
dependency).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["MeshCollider", "closest_point_on_triangles", "load_mesh_arrays"]


def load_mesh_arrays(mesh):
    """``(vertices [V, 3] float64, faces [F, 3] int64)`` of a TriangleModel, a trimesh.Trimesh,
    a ``(vertices, faces)`` pair, or a mesh file / run folder (through :func:`~.runs.load_run`)."""
    from ..types import TriangleModel
    if isinstance(mesh, (str, Path)):
        from .runs import load_run
        mesh, _ = load_run(mesh)
    if isinstance(mesh, TriangleModel):
        return np.asarray(mesh.positions, np.float64), np.asarray(mesh.triangles, np.int64)
    if hasattr(mesh, "vertices") and hasattr(mesh, "faces"):
        return np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64).reshape(-1, 3)
    v, f = mesh
    return np.asarray(v, np.float64).reshape(-1, 3), np.asarray(f, np.int64).reshape(-1, 3)


def closest_point_on_triangles(p, a, b, c):
    """Closest points ``[K, 3]`` on triangles (a, b, c) ``[K, 3]`` each to points ``p [K, 3]``
    (by the Voronoi regions of the vertices, edges and face; float64, vectorised)."""
    ab, ac, ap = b - a, c - a, p - a
    d1 = np.einsum("ij,ij->i", ab, ap)
    d2 = np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3 = np.einsum("ij,ij->i", ab, bp)
    d4 = np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5 = np.einsum("ij,ij->i", ab, cp)
    d6 = np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        den = va + vb + vc
        v = vb / den
        w = vc / den
    face = a + ab * v[:, None] + ac * w[:, None]
    conds = [
        (d1 <= 0) & (d2 <= 0),                                  # vertex a
        (d3 >= 0) & (d4 <= d3),                                 # vertex b
        (vc <= 0) & (d1 >= 0) & (d3 <= 0),                      # edge ab
        (d6 >= 0) & (d5 <= d6),                                 # vertex c
        (vb <= 0) & (d2 >= 0) & (d6 <= 0),                      # edge ac
        (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0),            # edge bc
    ]
    choices = [a, b, a + ab * t_ab[:, None], c, a + ac * t_ac[:, None], b + (c - b) * t_bc[:, None]]
    out = face.copy()
    done = np.zeros(len(p), bool)
    for cond, val in zip(conds, choices):
        take = cond & ~done
        out[take] = val[take]
        done |= cond
    return out


class MeshCollider:
    """Closest-point and ray queries against a triangle mesh.

    Args:
        mesh: anything :func:`load_mesh_arrays` takes.
        cell: grid cell size (default: from the triangles' sizes and the mesh's extent).
        backend: ``"auto"`` (embree through trimesh when ``embreex`` imports, else numpy),
            ``"embree"`` or ``"numpy"``; used by :meth:`raycast`.
    """

    MAX_ENTRIES = 4_000_000

    def __init__(self, mesh, cell=None, backend="auto"):
        v, f = load_mesh_arrays(mesh)
        if len(f) == 0:
            raise ValueError("mesh: it has no triangles; nothing to collide with")
        if f.min() < 0 or f.max() >= len(v):
            raise ValueError("mesh: a triangle index is out of range")
        if not np.all(np.isfinite(v)):
            raise ValueError("mesh: non-finite vertex positions")
        tri = v[f]                                                     # [M, 3, 3]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        area2 = np.linalg.norm(n, axis=1)
        scale = float(np.ptp(v, axis=0).max()) or 1.0
        ok = area2 > 1e-14 * scale * scale                             # zero-area triangles collide with nothing
        self.vertices, self.faces = v, f
        self.tri_index = np.nonzero(ok)[0]                             # original index of each kept triangle
        self.a, self.b, self.c = tri[ok, 0], tri[ok, 1], tri[ok, 2]
        self.normals = n[ok] / area2[ok, None]                         # [M', 3] (a, b, c) right-handed
        self.lo = np.minimum(np.minimum(self.a, self.b), self.c)
        self.hi = np.maximum(np.maximum(self.a, self.b), self.c)
        self.bounds = (v.min(0), v.max(0))
        self._build_grid(cell)
        self.backend = self._pick_backend(backend)
        self._embree = None

    # ------------------------------------------------------------------ grid
    def _build_grid(self, cell):
        lo, hi = self.bounds
        extent = max(float(np.ptp(np.stack([lo, hi]), axis=0).max()), 1e-9)
        if cell is None:
            sizes = (self.hi - self.lo).max(axis=1)
            cell = float(np.clip(2.0 * np.median(sizes), extent / 256, extent / 4))
        cell = float(cell)
        while True:
            dims = np.maximum(np.ceil((hi - lo) / cell).astype(np.int64), 1)
            i0 = np.clip(np.floor((self.lo - lo) / cell).astype(np.int64), 0, dims - 1)
            i1 = np.clip(np.floor((self.hi - lo) / cell).astype(np.int64), 0, dims - 1)
            counts = np.prod(i1 - i0 + 1, axis=1)
            if counts.sum() <= self.MAX_ENTRIES or cell >= extent:
                break
            cell *= 1.5
        self.cell, self.origin, self.dims = cell, lo.copy(), dims
        tri = np.repeat(np.arange(len(counts)), counts)
        local = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        span = (i1 - i0 + 1)[tri]
        ix = i0[tri, 0] + local // (span[:, 1] * span[:, 2])
        iy = i0[tri, 1] + (local // span[:, 2]) % span[:, 1]
        iz = i0[tri, 2] + local % span[:, 2]
        keys = (ix * dims[1] + iy) * dims[2] + iz
        order = np.argsort(keys, kind="stable")
        keys, self._cell_tris = keys[order], tri[order]
        self._cell_keys, self._cell_start = np.unique(keys, return_index=True)
        self._cell_end = np.append(self._cell_start[1:], len(keys))

    def candidates(self, lo, hi):
        """Pairs ``(query [K], triangle [K])``, unique, of triangles whose grid cells meet the
        boxes ``[lo, hi]`` ``[Q, 3]`` (a superset of the triangles inside each box)."""
        lo = np.atleast_2d(np.asarray(lo, np.float64))
        hi = np.atleast_2d(np.asarray(hi, np.float64))
        d = self.dims
        blo, bhi = self.bounds
        outside = np.any((hi < blo) | (lo > bhi), axis=1)
        i0 = np.clip(np.floor((lo - self.origin) / self.cell).astype(np.int64), 0, d - 1)
        i1 = np.clip(np.floor((hi - self.origin) / self.cell).astype(np.int64), 0, d - 1)
        span = np.where(outside[:, None], 0, i1 - i0 + 1)
        counts = np.prod(span, axis=1)
        if counts.sum() == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        q = np.repeat(np.arange(len(lo)), counts)
        local = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        s = span[q]
        ix = i0[q, 0] + local // (s[:, 1] * s[:, 2])
        iy = i0[q, 1] + (local // s[:, 2]) % s[:, 1]
        iz = i0[q, 2] + local % s[:, 2]
        keys = (ix * d[1] + iy) * d[2] + iz
        pos = np.searchsorted(self._cell_keys, keys)
        pos = np.minimum(pos, len(self._cell_keys) - 1)
        hit = self._cell_keys[pos] == keys
        q, pos = q[hit], pos[hit]
        n = self._cell_end[pos] - self._cell_start[pos]
        qq = np.repeat(q, n)
        local = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
        tris = self._cell_tris[np.repeat(self._cell_start[pos], n) + local]
        m = len(self.a)
        pairs = np.unique(qq * m + tris)
        return pairs // m, pairs % m

    # ------------------------------------------------------------------ queries
    def closest_points(self, points, radius):
        """The nearest point of the mesh to each of ``points [P, 3]`` within ``radius`` (scalar
        or [P]). Returns ``(closest [P, 3], distance [P] (inf where nothing is within radius),
        triangle [P] (index into the input faces, -1 where none), normal [P, 3] (the triangle's
        unit normal, turned towards the point))``."""
        p = np.atleast_2d(np.asarray(points, np.float64))
        r = np.broadcast_to(np.asarray(radius, np.float64), (len(p),))
        closest = np.zeros_like(p)
        dist = np.full(len(p), np.inf)
        tri = np.full(len(p), -1, np.int64)
        normal = np.zeros_like(p)
        q, t = self.candidates(p - r[:, None], p + r[:, None])
        if len(q) == 0:
            return closest, dist, tri, normal
        cp = closest_point_on_triangles(p[q], self.a[t], self.b[t], self.c[t])
        d = np.linalg.norm(p[q] - cp, axis=1)
        keep = d <= r[q]
        q, t, cp, d = q[keep], t[keep], cp[keep], d[keep]
        if len(q) == 0:
            return closest, dist, tri, normal
        order = np.lexsort((t, d, q))          # per query the nearest (ties: the lowest triangle)
        q, t, cp, d = q[order], t[order], cp[order], d[order]
        first = np.ones(len(q), bool)
        first[1:] = q[1:] != q[:-1]
        q, t, cp, d = q[first], t[first], cp[first], d[first]
        closest[q], dist[q], tri[q] = cp, d, self.tri_index[t]
        nrm = self.normals[t]
        side = np.einsum("ij,ij->i", nrm, p[q] - cp)
        normal[q] = np.where(side[:, None] < 0, -nrm, nrm)
        return closest, dist, tri, normal

    def raycast(self, origins, directions, max_distance=np.inf):
        """First hit of each ray ``origins + s directions`` (directions normalised here), for
        0 <= s <= max_distance. Returns ``(distance [R] (inf: miss), triangle [R] (-1: miss),
        normal [R, 3] (unit, turned against the ray))``."""
        o = np.atleast_2d(np.asarray(origins, np.float64))
        d = np.atleast_2d(np.asarray(directions, np.float64))
        d = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
        o, d = np.broadcast_arrays(o, d)
        tmax = np.broadcast_to(np.asarray(max_distance, np.float64), (len(o),))
        if self.backend == "embree":
            dist, local = self._raycast_embree(o, d, tmax)
        else:
            dist, local = self._raycast_numpy(o, d, tmax)
        tri = np.where(local >= 0, self.tri_index[np.maximum(local, 0)], -1)
        nrm = self.normals[np.maximum(local, 0)]
        nrm = np.where((np.einsum("ij,ij->i", nrm, d) > 0)[:, None], -nrm, nrm)
        nrm[local < 0] = 0.0
        return dist, tri, nrm

    def _raycast_numpy(self, o, d, tmax):
        dist = np.full(len(o), np.inf)
        local = np.full(len(o), -1, np.int64)
        blo, bhi = self.bounds
        span = np.where(np.isfinite(tmax), tmax, 2.0 * float(np.linalg.norm(bhi - blo)) + np.linalg.norm(
            np.maximum(np.abs(o - blo), np.abs(o - bhi)), axis=1))
        end = o + d * span[:, None]
        q, t = self.candidates(np.minimum(o, end), np.maximum(o, end))
        if len(q) == 0:
            return dist, local
        # Moller-Trumbore, two-sided
        e1, e2 = self.b[t] - self.a[t], self.c[t] - self.a[t]
        pv = np.cross(d[q], e2)
        det = np.einsum("ij,ij->i", e1, pv)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / det
            tv = o[q] - self.a[t]
            u = np.einsum("ij,ij->i", tv, pv) * inv
            qv = np.cross(tv, e1)
            v = np.einsum("ij,ij->i", d[q], qv) * inv
            s = np.einsum("ij,ij->i", e2, qv) * inv
            eps = 1e-12
            hit = (np.abs(det) > 1e-300) & (u >= -eps) & (v >= -eps) & (u + v <= 1 + eps) & (s >= 0) & (s <= span[q])
        q, t, s = q[hit], t[hit], s[hit]
        order = np.lexsort((t, s, q))
        q, t, s = q[order], t[order], s[order]
        first = np.ones(len(q), bool)
        first[1:] = q[1:] != q[:-1]
        dist[q[first]], local[q[first]] = s[first], t[first]
        far = dist > tmax
        dist[far], local[far] = np.inf, -1
        return dist, local

    def _raycast_embree(self, o, d, tmax):
        if self._embree is None:
            import trimesh
            from trimesh.ray.ray_pyembree import RayMeshIntersector
            faces = np.arange(3 * len(self.a)).reshape(-1, 3)
            verts = np.stack([self.a, self.b, self.c], 1).reshape(-1, 3)
            self._embree = RayMeshIntersector(trimesh.Trimesh(verts, faces, process=False, validate=False))
        dist = np.full(len(o), np.inf)
        local = np.full(len(o), -1, np.int64)
        tri, ray, loc = self._embree.intersects_id(o, d, multiple_hits=False, return_locations=True)
        if len(tri):
            s = np.einsum("ij,ij->i", loc - o[ray], d[ray])
            ok = s <= tmax[ray]
            dist[ray[ok]], local[ray[ok]] = s[ok], tri[ok]
        return dist, local

    @staticmethod
    def _pick_backend(backend):
        if backend not in ("auto", "embree", "numpy"):
            raise ValueError(f"backend: expected 'auto', 'embree' or 'numpy', got {backend!r}")
        if backend == "numpy":
            return "numpy"
        try:
            import embreex  # noqa: F401
            from trimesh.ray import ray_pyembree  # noqa: F401
            return "embree"
        except ImportError:
            if backend == "embree":
                raise ValueError("backend 'embree': the embreex package is not installed (pip install embreex)") \
                    from None
            return "numpy"
