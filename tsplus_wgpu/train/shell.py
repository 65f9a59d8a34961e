"""The background shell: triangles that cover what the SfM points do not.

SfM finds points only where the images have texture it can match. White walls, a clear sky,
the floor at the image borders get none, so the Delaunay mesh of the points leaves those
pixels uncovered (black in the exported mesh; the cup's held-out views were 6 % uncovered
after 3000 quick iterations) or the optimiser stretches shards across free space to fill them.
The shell is the far proxy the issue asks for: a geodesic sphere around the cameras, cut to
the part some training view sees, coloured from the photos. It is trained like every other
triangle (positions, colours, opacity), so it can move towards walls and floor; the
topology's opacity and weight prunes leave it alone (:data:`SHELL`: a triangle group), so
pixels stay covered while the surface triangles in front of it are still transparent. The
final mesh keeps the shell triangles that some training view sees with a weight above 0.5,
like any other (method.md's end of training).

Everything here works in the trainer's normalised frame (:mod:`tsplus_wgpu.data.frame`: the
camera centres within radius 1 of the origin), so the constants below are relative to the
camera radius and the shell does not depend on the world's units.

* Centre: the origin of the frame (the mean camera centre).
* Radius: ``max(SHELL_MIN_RADIUS, SHELL_POINT_FACTOR x the 99th percentile of the points'
  distances)``: beyond nearly every point, so it lies behind the reconstructed surfaces, and
  at least 5 camera radii, so its parallax between the views (at most 1/R rad for a point
  at infinity) is small for sky and far background.
* Resolution: an icosphere of the level whose edges are about :data:`SHELL_EDGE_PX` pixels
  at the median focal length, seen from the centre (levels 3..6: 642..40,962 vertices).
  Densification refines what the views need.
* Colour: each vertex takes the mean of the pixels it projects to in the training views
  (nearest pixel, occlusion ignored), the mean image colour where no view sees it.
* Opacity :data:`SHELL_OPACITY` (0.9): it is the backdrop; nothing is behind it but the
  background colour.
"""

from __future__ import annotations

import math

import numpy as np

from ..types import SH_C0, TriangleModel

#: triangle groups (``VertexState.groups``): ordinary triangles, and the background shell
SURFACE, SHELL = 0, 1
SHELL_MIN_RADIUS = 5.0
SHELL_POINT_FACTOR = 2.0
SHELL_EDGE_PX = 8.0
SHELL_OPACITY = 0.9
SHELL_LEVELS = (3, 6)
#: a shell triangle is kept when a vertex projects within this many image sizes of a view
SHELL_MARGIN = 0.5


def icosphere(level):
    """A geodesic unit sphere: the icosahedron with every face split into 4, ``level`` times.
    Returns ``(vertices [10 * 4**level + 2, 3], faces [20 * 4**level, 3])``, faces wound
    outwards."""
    level = int(level)
    if level < 0:
        raise ValueError(f"level: expected >= 0, got {level}")
    g = (1.0 + math.sqrt(5.0)) / 2.0
    v = np.array([[-1, g, 0], [1, g, 0], [-1, -g, 0], [1, -g, 0], [0, -1, g], [0, 1, g], [0, -1, -g], [0, 1, -g],
                  [g, 0, -1], [g, 0, 1], [-g, 0, -1], [-g, 0, 1]], np.float64)
    f = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
                  [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5],
                  [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]], np.int64)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    for _ in range(level):
        a, b, c = f[:, 0], f[:, 1], f[:, 2]
        edges = np.concatenate([np.stack([a, b], 1), np.stack([b, c], 1), np.stack([c, a], 1)])
        edges.sort(axis=1)
        uniq, inv = np.unique(edges, axis=0, return_inverse=True)
        mid = v[uniq[:, 0]] + v[uniq[:, 1]]
        mid /= np.linalg.norm(mid, axis=1, keepdims=True)
        m = len(v) + inv.ravel().reshape(3, -1)           # midpoints of ab, bc, ca per face
        v = np.concatenate([v, mid])
        f = np.concatenate([np.stack([a, m[0], m[2]], 1), np.stack([m[0], b, m[1]], 1),
                            np.stack([m[2], m[1], c], 1), np.stack([m[0], m[1], m[2]], 1)])
    return v, f


def shell_radius(points=None):
    """The shell's radius in frame units (camera radius 1): see the module docstring."""
    r = SHELL_MIN_RADIUS
    if points is not None and len(points):
        d = np.linalg.norm(np.asarray(points, np.float64), axis=1)
        d = d[np.isfinite(d)]
        if len(d):
            r = max(r, SHELL_POINT_FACTOR * float(np.percentile(d, 99)))
    return r


def shell_level(cameras):
    """The icosphere level whose edge is about :data:`SHELL_EDGE_PX` pixels at the median
    focal length (seen from the centre), within :data:`SHELL_LEVELS`."""
    f = float(np.median([0.5 * (c.fx + c.fy) for c in cameras]))
    edge0 = 1.1071487177940904                      # the icosahedron's edge angle (rad)
    level = int(round(math.log2(max(edge0 * f / SHELL_EDGE_PX, 1.0))))
    return min(max(level, SHELL_LEVELS[0]), SHELL_LEVELS[1])


def background_shell(cameras, images, points=None, radius=None, level=None, opacity=SHELL_OPACITY, sh_degree=0):
    """The shell as a :class:`~tsplus_wgpu.TriangleModel` in the frame of ``cameras``
    (normalised: see the module docstring), or None when no view sees any of it.

    Args:
        cameras, images: the training views (``images[i]`` float ``[H, W, 3]`` in [0, 1]).
        points: the initial points (frame units), for the radius.
        radius, level: override :func:`shell_radius` / :func:`shell_level`.
    """
    radius = shell_radius(points) if radius is None else float(radius)
    level = shell_level(cameras) if level is None else int(level)
    unit, faces = icosphere(level)
    pos = unit * radius
    total = np.zeros((len(pos), 3))
    count = np.zeros(len(pos))
    near_view = np.zeros(len(pos), bool)
    mean_colour = np.zeros(3)
    for cam, img in zip(cameras, images):
        img = np.asarray(img, np.float64)
        h, w = img.shape[:2]
        uv, z = cam.project(pos)
        u, v, front = uv[:, 0], uv[:, 1], z > 1e-9
        inside = front & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        mu, mv = SHELL_MARGIN * w, SHELL_MARGIN * h
        near_view |= front & (u >= -mu) & (u < w + mu) & (v >= -mv) & (v < h + mv)
        iu = np.clip(np.floor(u[inside]).astype(np.int64), 0, w - 1)
        iv = np.clip(np.floor(v[inside]).astype(np.int64), 0, h - 1)
        total[inside] += img[iv, iu]
        count[inside] += 1
        mean_colour += img.reshape(-1, 3).mean(axis=0)
    mean_colour /= max(len(images), 1)
    keep = near_view[faces].any(axis=1)
    if not keep.any():
        return None
    faces = faces[keep]
    used = np.zeros(len(pos), bool)
    used[faces.ravel()] = True
    new_from_old = np.cumsum(used) - 1
    colour = np.where(count[:, None] > 0, total / np.maximum(count, 1)[:, None], mean_colour)
    k = (int(sh_degree) + 1) ** 2
    sh = np.zeros((int(used.sum()), k, 3))
    sh[:, 0] = (colour[used] - 0.5) / SH_C0
    return TriangleModel(pos[used], new_from_old[faces], sh, np.full(int(used.sum()), float(opacity)))


def with_shell(model, shell):
    """``(model and shell in one TriangleModel, groups [M])``: the shell's vertices and
    triangles appended, ``groups`` :data:`SURFACE` for the model's triangles and :data:`SHELL`
    for the shell's. ``shell`` None: the model and all-:data:`SURFACE` groups."""
    groups = np.full(model.num_triangles, SURFACE, np.int8)
    if shell is None:
        return model, groups
    k = max(model.sh.shape[1], shell.sh.shape[1])

    def pad(sh):
        out = np.zeros((sh.shape[0], k, 3))
        out[:, :sh.shape[1]] = sh
        return out

    n = model.num_vertices
    merged = TriangleModel(np.concatenate([model.positions, shell.positions]),
                           np.concatenate([model.triangles, shell.triangles + n]),
                           np.concatenate([pad(model.sh), pad(shell.sh)]),
                           np.concatenate([model.opacity, shell.opacity]))
    return merged, np.concatenate([groups, np.full(shell.num_triangles, SHELL, np.int8)])


__all__ = ["SURFACE", "SHELL", "icosphere", "shell_radius", "shell_level", "background_shell", "with_shell"]


def beyond_views(groups, positions, triangles, cameras, near):
    """``[M]`` bool: the shell triangles that none of ``cameras`` can show (outside every image
    or behind every camera; :func:`.strategy.ops.in_views`). No training view constrains them,
    so the final cleanup keeps them as the backdrop of other viewpoints. All False without groups."""
    out = np.zeros(len(triangles), bool)
    if groups is None:
        return out
    from .strategy.ops import in_views
    shell = np.flatnonzero(np.asarray(groups) == SHELL)
    out[shell] = ~in_views(positions, np.asarray(triangles)[shell], cameras, near)
    return out

