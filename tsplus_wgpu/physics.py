"""The mesh as a collider: closest-point and ray queries against a triangle mesh, and a
small rigid-sphere world that drops spheres onto it.

API::

    from tsplus_wgpu.physics import World
    world = World(mesh, gravity=(0, 0, -9.81))     # TriangleModel, trimesh.Trimesh, (V, F) or a file path
    i = world.add_sphere(center=(0, 0, 2), radius=0.1)
    for _ in range(600):
        world.step(1 / 60)
    world.centers[i], world.velocities[i]

Queries (:class:`MeshCollider`): ``closest_points`` (per point, the nearest point of the mesh
within a radius: exact closest point on each candidate triangle, candidates from a uniform
grid of triangle bounding boxes) and ``raycast`` (first hit: through trimesh's embree
intersector when ``embreex`` is installed, else the same grid with a vectorised
Moller-Trumbore test; trimesh's own non-embree intersector needs ``rtree``, which is not a
dependency).

The world (:class:`World`): semi-implicit Euler (velocity from gravity, then position),
sphere-vs-mesh contacts from closest points: spheres touching the mesh get their contact
impulse before they move (restitution, switched off below a resting speed so that spheres
come to rest, and Coulomb friction on the tangential velocity: a sphere held by friction
does not creep), and a sphere that moved into the mesh is pushed out to ``radius`` from the
closest point and gets the same impulse. Continuous collision: every step is cut
into substeps in which no sphere moves more than half its radius, so a centre can never
cross a triangle between two contact checks: no tunnelling through thin, single-sided
sheets, at any speed (the substep count grows with speed). Spheres translate only (no
rotation or rolling) and do not collide with each other.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

__all__ = ["MeshCollider", "World", "closest_point_on_triangles", "load_mesh_arrays"]


def load_mesh_arrays(mesh):
    """``(vertices [V, 3] float64, faces [F, 3] int64)`` of a TriangleModel, a trimesh.Trimesh,
    a ``(vertices, faces)`` pair, or a mesh file / run folder (through :func:`export.load_run`)."""
    from .types import TriangleModel
    if isinstance(mesh, (str, Path)):
        from .export import load_run
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


class World:
    """Rigid spheres falling onto a static triangle mesh.

    Args:
        mesh: a :class:`MeshCollider` or anything :func:`load_mesh_arrays` takes.
        gravity: acceleration vector (scene units / s^2); default -9.81 along z (the procedural
            scene's up).
        restitution: normal bounce factor in [0, 1].
        friction: Coulomb coefficient on the tangential velocity at a contact.
        rest_speed: normal approach speeds below this do not bounce (default: the speed gravity
            adds in 4 substeps), so a sphere settles instead of jittering.
        max_substeps: cap of substeps per :meth:`step` (speeds that would need more are clamped).
    """

    def __init__(self, mesh, gravity=(0.0, 0.0, -9.81), restitution=0.3, friction=0.5, rest_speed=None,
                 max_substeps=10_000, contact_iterations=4):
        self.collider = mesh if isinstance(mesh, MeshCollider) else MeshCollider(mesh)
        self.gravity = np.asarray(gravity, np.float64).reshape(3)
        if not 0.0 <= restitution <= 1.0:
            raise ValueError(f"restitution: expected a value in [0, 1], got {restitution}")
        if friction < 0:
            raise ValueError(f"friction: expected >= 0, got {friction}")
        self.restitution, self.friction = float(restitution), float(friction)
        self.rest_speed = rest_speed
        self.max_substeps = int(max_substeps)
        self.contact_iterations = int(contact_iterations)
        self.centers = np.zeros((0, 3))
        self.velocities = np.zeros((0, 3))
        self.radii = np.zeros(0)
        self.time = 0.0
        self.substeps_taken = 0
        #: per sphere: whether it touched (or hit) the mesh in the last substep
        self.in_contact = np.zeros(0, bool)

    def add_sphere(self, center, radius, velocity=(0.0, 0.0, 0.0)):
        """Add a sphere; returns its index."""
        c = np.asarray(center, np.float64).reshape(3)
        v = np.asarray(velocity, np.float64).reshape(3)
        if not (np.isfinite(radius) and radius > 0):
            raise ValueError(f"radius: expected > 0, got {radius}")
        if not (np.all(np.isfinite(c)) and np.all(np.isfinite(v))):
            raise ValueError("center, velocity: expected finite values")
        self.centers = np.vstack([self.centers, c])
        self.velocities = np.vstack([self.velocities, v])
        self.radii = np.append(self.radii, float(radius))
        self.in_contact = np.append(self.in_contact, False)
        return len(self.radii) - 1

    def substeps_for(self, dt):
        """Substeps that keep every sphere's move per substep within half its radius."""
        if len(self.radii) == 0:
            return 1
        speed = np.linalg.norm(self.velocities, axis=1) + np.linalg.norm(self.gravity) * dt
        n = int(math.ceil(float(np.max(speed * dt / (0.5 * self.radii)))))
        return max(1, min(n, self.max_substeps))

    def step(self, dt):
        """Advance by ``dt`` seconds (semi-implicit Euler in substeps, contacts every substep)."""
        dt = float(dt)
        if not dt > 0:
            raise ValueError(f"dt: expected > 0, got {dt}")
        if len(self.radii) == 0:
            self.time += dt
            return
        n = self.substeps_for(dt)
        h = dt / n
        # speeds the capped substeps cannot carry safely are clamped (only with max_substeps hit)
        vmax = 0.5 * self.radii / h
        for _ in range(n):
            self.velocities += self.gravity * h
            sp = np.linalg.norm(self.velocities, axis=1)
            over = sp > vmax
            if np.any(over):
                self.velocities[over] *= (vmax[over] / sp[over])[:, None]
            touching = self._touching_contacts(h)
            previous = self.centers.copy()
            self.centers = self.centers + self.velocities * h
            self.in_contact = self._resolve(previous, h) | touching
        self.time += dt
        self.substeps_taken += n

    def _rest_speed(self, h):
        return self.rest_speed if self.rest_speed is not None else 4.0 * np.linalg.norm(self.gravity) * h + 1e-9

    def _impulse(self, idx, n, rest):
        """Contact impulse on spheres ``idx`` along outward normals ``n``: the approaching normal
        speed reversed times the restitution (none below ``rest``), Coulomb friction on the rest."""
        v = self.velocities[idx]
        vn = np.einsum("ij,ij->i", v, n)
        approaching = vn < 0
        e = np.where(-vn > rest, self.restitution, 0.0)
        jn = -(1.0 + e) * np.minimum(vn, 0.0)                      # normal impulse per unit mass
        vt = v - vn[:, None] * n
        vt_len = np.linalg.norm(vt, axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            keep = np.where(vt_len > 0, np.maximum(0.0, 1.0 - self.friction * jn / vt_len), 0.0)
        new_v = vt * keep[:, None] + (-e * np.minimum(vn, 0.0))[:, None] * n
        self.velocities[idx] = np.where(approaching[:, None], new_v, v)

    def _touching_contacts(self, h):
        """Velocity-level contacts of spheres resting on the mesh (centre within radius plus a
        hair of the surface), before the position moves: a sphere held by friction does not creep."""
        slop = 1e-7 * np.maximum(self.radii, 1e-3)
        cp, dist, _, _ = self.collider.closest_points(self.centers, self.radii + slop)
        hit = dist <= self.radii + slop
        if not np.any(hit):
            return hit
        idx = np.nonzero(hit)[0]
        with np.errstate(invalid="ignore", divide="ignore"):
            n = (self.centers[idx] - cp[hit]) / dist[hit, None]
        ok = dist[hit] > 1e-12
        if np.any(ok):
            self._impulse(idx[ok], n[ok], self._rest_speed(h))
        return hit

    def _resolve(self, previous, h):
        rest = self._rest_speed(h)
        touched = np.zeros(len(self.radii), bool)
        active = np.arange(len(self.radii))
        for _ in range(self.contact_iterations):
            cp, dist, tri, nrm = self.collider.closest_points(self.centers[active], self.radii[active])
            hit = dist < self.radii[active]
            if not np.any(hit):
                break
            idx = active[hit]
            cp, dist, nrm = cp[hit], dist[hit], nrm[hit]
            # direction out of the surface: from the closest point to the centre; when the
            # centre lies on the surface, the triangle normal on the side the sphere came from
            with np.errstate(invalid="ignore", divide="ignore"):
                n = (self.centers[idx] - cp) / dist[:, None]
            flat = dist < 1e-9 * np.maximum(self.radii[idx], 1.0)
            if np.any(flat):
                side = np.einsum("ij,ij->i", nrm[flat], previous[idx[flat]] - cp[flat])
                n[flat] = np.where(side[:, None] < 0, -nrm[flat], nrm[flat])
            self.centers[idx] = cp + n * self.radii[idx, None]
            self._impulse(idx, n, rest)
            touched[idx] = True
            active = idx
        return touched


# ----------------------------------------------------------------------------- measurement

def _drop(mesh, center, radius, velocity=(0.0, 0.0, 0.0), steps=1000, dt=1 / 60, floor=0.0, **kw):
    """Drop one sphere; returns (lowest centre - floor, final rest error |z - floor - r|, first step
    from which it stays at rest, ms per step, substeps)."""
    import time
    world = World(mesh, **kw)
    i = world.add_sphere(center, radius, velocity)
    low, rest_from, times = np.inf, None, []
    for k in range(steps):
        t = time.perf_counter()
        world.step(dt)
        times.append(time.perf_counter() - t)
        low = min(low, world.centers[i, 2] - floor)
        still = np.linalg.norm(world.velocities[i]) < 1e-6
        rest_from = (k + 1 if rest_from is None else rest_from) if still else None
    return low, abs(world.centers[i, 2] - floor - radius), rest_from, 1e3 * float(np.mean(times)), \
        world.substeps_taken


def _main(argv=None):
    import argparse
    import time
    from .data.procedural import build_world
    ap = argparse.ArgumentParser(prog="python -m tsplus_wgpu.physics",
                                 description="Spheres dropped onto the procedural room and a thin sheet: rest error, "
                                             "steps to rest, ms per step.")
    ap.add_argument("--backend", default="auto", choices=["auto", "embree", "numpy"])
    args = ap.parse_args(argv)
    v, f, _, _ = build_world(0)
    room = MeshCollider((v, f), backend=args.backend)
    sheet = (np.array([[-50, -50, 0], [50, -50, 0], [50, 50, 0], [-50, 50, 0]], float), np.array([[0, 1, 2], [0, 2, 3]]))
    print(f"ray backend: {room.backend}; room: {len(f)} triangles, grid {room.dims.tolist()} cells of {room.cell:.3g}")
    print(f"{'case (1000 steps of 1/60 s)':<52}{'lowest-r':>10}{'rest err':>10}{'at rest':>9}{'ms/step':>9}"
          f"{'substeps':>9}")
    sheet = MeshCollider(sheet, backend=args.backend)
    cases = [("room floor, r 0.1 from 2 m, e 0.5", room, (0.0, -1.8, 2.0), 0.1, (0, 0, 0), dict(restitution=0.5)),
             ("thin sheet (2 triangles), r 0.05 from 1 m", sheet, (0.1, 0.2, 1.0), 0.05, (0, 0, 0), {}),
             ("thin sheet, r 0.02 thrown down at 500 m/s", sheet, (0.0, 0.0, 10.0), 0.02, (0.3, 0, -500.0),
              dict(restitution=0.0))]
    for name, mesh, c, r, vel, kw in cases:
        low, err, rest, ms, sub = _drop(mesh, c, r, vel, **kw)
        print(f"{name:<52}{low - r:>10.2e}{err:>10.2e}{rest if rest else '-':>9}{ms:>9.3f}{sub:>9}")
    world = World(room)
    rng = np.random.default_rng(3)
    for _ in range(20):
        world.add_sphere(rng.uniform([-2.5, -2.0, 1.5], [2.5, 2.0, 2.4]), rng.uniform(0.05, 0.15))
    t = time.perf_counter()
    for _ in range(600):
        world.step(1 / 60)
    print(f"20 spheres in the room, 600 steps: {1e3 * (time.perf_counter() - t) / 600:.3f} ms/step, all at rest: "
          f"{bool(np.all(np.linalg.norm(world.velocities, axis=1) < 1e-3))}")


if __name__ == "__main__":
    _main()
