"""The mesh as a collider: closest-point and ray queries against a triangle mesh, and a
small rigid-sphere world that drops spheres onto it.

API::

    from tsplus_wgpu.apps.physics import World
    world = World(mesh, gravity=(0, 0, -9.81))     # TriangleModel, trimesh.Trimesh, (V, F) or a file path
    i = world.add_sphere(center=(0, 0, 2), radius=0.1)
    for _ in range(600):
        world.step(1 / 60)
    world.centers[i], world.velocities[i]

Queries (:class:`~.collider.MeshCollider`, in :mod:`.collider`): ``closest_points`` (per point, the nearest point of the mesh
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
import numpy as np

from .collider import MeshCollider, closest_point_on_triangles, load_mesh_arrays

__all__ = ["MeshCollider", "World", "closest_point_on_triangles", "load_mesh_arrays"]


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
    from ..data.procedural import build_world
    ap = argparse.ArgumentParser(prog="python -m tsplus_wgpu.apps.physics",
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
