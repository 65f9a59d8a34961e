"""Initial points without SfM: random points inside the volume most cameras see, coloured
from the images (:func:`frusta_points`; the loader's fallback when pycolmap cannot triangulate)."""

from __future__ import annotations

import numpy as np


def frusta_points(cameras: list, images: list, n: int = 20000, bounds=None, seed: int = 0):
    """Points in the volume that the cameras look at, coloured from the images.

    Depth range: from ``bounds`` ([N, 2] near/far per camera, LLFF) when given, else around the
    point nearest to all optical axes.  A candidate (random pixel of a random view at a random
    depth) is kept when at least half of the cameras (and at least 2) see it.

    Returns:
        ``(points [P,3], colors [P,3])``.
    """
    rng = np.random.default_rng(seed)
    C = np.stack([c.center for c in cameras])                       # [N, 3]
    D = np.stack([c.R[2] for c in cameras])                         # [N, 3] optical axes
    if bounds is not None:
        near = np.full(len(cameras), float(np.percentile(bounds[:, 0], 10)))
        far = np.full(len(cameras), float(np.percentile(bounds[:, 1], 90)))
    else:
        A = np.zeros((3, 3))
        b = np.zeros(3)
        for c, d in zip(C, D):
            P = np.eye(3) - np.outer(d, d)
            A += P
            b += P @ c
        try:
            focus = np.linalg.solve(A + 1e-9 * np.eye(3), b)
        except np.linalg.LinAlgError:
            focus = C.mean(0) + D.mean(0)
        dist = np.einsum("nj,nj->n", focus - C, D)
        dist = np.where(dist > 0, dist, np.median(np.linalg.norm(focus - C, axis=1)))
        near, far = 0.3 * dist, 1.7 * dist
    need = max(2, int(np.ceil(0.5 * len(cameras)))) if len(cameras) > 1 else 1
    pts, cols = [], []
    total = 0
    for _ in range(20):
        m = 4 * n
        vi = rng.integers(0, len(cameras), m)
        u = rng.random(m)
        v = rng.random(m)
        s = rng.random(m)
        out = np.empty((m, 3))
        col = np.empty((m, 3))
        for k in np.unique(vi):
            sel = vi == k
            cam = cameras[k]
            px = u[sel] * cam.width
            py = v[sel] * cam.height
            z = near[k] + s[sel] * (far[k] - near[k])
            xc = np.stack([(px - cam.cx) / cam.fx * z, (py - cam.cy) / cam.fy * z, z], 1)
            out[sel] = (xc - cam.t) @ cam.R
            img = images[k]
            col[sel] = img[np.minimum((py).astype(int), img.shape[0] - 1), np.minimum(px.astype(int), img.shape[1] - 1)]
        seen = np.zeros(m, int)
        for cam in cameras:
            xc = out @ cam.R.T + cam.t
            z = xc[:, 2]
            with np.errstate(divide="ignore", invalid="ignore"):
                uu = cam.fx * xc[:, 0] / z + cam.cx
                vv = cam.fy * xc[:, 1] / z + cam.cy
            seen += (z > 1e-6) & (uu >= 0) & (uu < cam.width) & (vv >= 0) & (vv < cam.height)
        keep = seen >= need
        pts.append(out[keep])
        cols.append(col[keep])
        total += int(keep.sum())
        if total >= n:
            break
    P = np.concatenate(pts)[:n]
    Cc = np.concatenate(cols)[:n]
    return P, np.clip(Cc, 0, 1).astype(np.float64)
