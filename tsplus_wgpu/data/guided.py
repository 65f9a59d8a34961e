"""Feature matching guided by known poses, for the triangulation of posed images.

The unguided matcher pairs SIFT features by descriptor alone, with a ratio test over the whole
other image. On repeated structure (cobbles, windows, roof tiles) and across wide baselines the
ratio test rejects most true matches: the second-best candidate anywhere in the image is as close
as the best. When the poses are known, the true match of a feature lies on its epipolar line, so
the ratio test can be run among the features near that line only, which keeps many of them.

* :func:`fundamental`: the fundamental matrix of two posed pinhole cameras.
* :func:`epipolar_matches`: mutual nearest neighbours among the features within ``max_px`` of
  each other's epipolar lines, with the ratio test among those candidates (NumPy; the uint8
  descriptors' dot products exact, so the matches are the same on any CPU).
* :func:`add_guided_matches`: runs it on image pairs of a pycolmap database and adds the
  matches to the pairs' verified matches, which the point triangulator reads.

COLMAP's own guided matching does the same with a fundamental matrix estimated from the
unguided matches; here the known poses give it exactly, also for pairs whose unguided matches were
too few to estimate one. Measured in docs/measurements.md ("Initial points: matching guided by
the known poses").
"""

from __future__ import annotations

import numpy as np

#: a candidate must lie within this many pixels (at the matcher's image size) of the epipolar line
EPIPOLAR_PX = 1.5
#: Lowe's ratio, as COLMAP's matcher uses it (its default, 0.8), between the angles of the best
#: and the second-best candidate's descriptors
RATIO = 0.8
#: COLMAP's largest descriptor angle for a match (its default max_distance 0.7, as an angle)
MAX_ANGLE = 0.7
#: rows of the similarity matrix computed at a time (memory: BLOCK x features of the other image)
BLOCK = 1024


def _skew(t):
    return np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])


def fundamental(K1, T1, K2, T2) -> np.ndarray:
    """Fundamental matrix F with ``x2^T F x1 = 0`` for pixels x1 of camera 1 and x2 of camera 2.

    Args:
        K1, K2: 3x3 intrinsics; T1, T2: 3x4 (or 4x4) world-to-camera transforms.
    """
    T1 = np.asarray(T1, np.float64)[:3]
    T2 = np.asarray(T2, np.float64)[:3]
    R = T2[:, :3] @ T1[:, :3].T
    t = T2[:, 3] - R @ T1[:, 3]
    F = np.linalg.inv(np.asarray(K2, np.float64)).T @ _skew(t) @ R @ np.linalg.inv(np.asarray(K1, np.float64))
    n = np.linalg.norm(F)
    return F / n if n > 0 else F


def _lines(F, h):
    """Normalised lines ``F x`` of the points ``h`` [M,3], term by term (see :func:`_line_dist`)."""
    out = np.stack([_line_dist(np.broadcast_to(F[k], h.shape), h) for k in range(3)], axis=1)
    return out / np.maximum(np.hypot(out[:, 0], out[:, 1]), 1e-300)[:, None]


def _line_dist(lines, pts):
    """Signed distances of points ``pts`` [M,3] (homogeneous, w = 1) from normalised lines, term
    by term in a fixed order (no summation order that differs between CPUs)."""
    return lines[:, 0] * pts[:, 0] + lines[:, 1] * pts[:, 1] + lines[:, 2] * pts[:, 2]


def epipolar_matches(xy1, xy2, desc1, desc2, F, max_px: float = EPIPOLAR_PX, ratio: float = RATIO,
                     max_angle: float = MAX_ANGLE) -> np.ndarray:
    """Matches between two images' features, searched only near the epipolar lines.

    A candidate pair (a, b) is one whose feature b lies within ``max_px`` of the epipolar line of
    a and a within ``max_px`` of that of b. Among its candidates, a's best descriptor (smallest
    angle) must beat the second best by ``ratio``, be within ``max_angle``, and pick a back in
    turn (the same test from b's side).

    Args:
        xy1 [N1,2], xy2 [N2,2]: pixel positions; desc1 [N1,D], desc2 [N2,D]: descriptors.
        F: the fundamental matrix (:func:`fundamental`).

    Returns:
        [M,2] int64 index pairs (a, b), sorted by a.
    """
    n1, n2 = len(xy1), len(xy2)
    if n1 == 0 or n2 == 0:
        return np.zeros((0, 2), np.int64)
    F = np.asarray(F, np.float64)
    h1 = np.c_[np.asarray(xy1, np.float64), np.ones(n1)]
    h2 = np.c_[np.asarray(xy2, np.float64), np.ones(n2)]
    l2 = _lines(F, h1)                                     # lines in image 2 of the features of 1
    l1 = _lines(F.T, h2)                                   # lines in image 1 of the features of 2
    # COLMAP's descriptors are uint8: their dot products are integers below 2^24 (128 x 255^2),
    # so float32 sums them exactly in any order: the same matches on any CPU
    exact32 = np.asarray(desc1).dtype == np.uint8 and np.asarray(desc1).shape[1] * 255 ** 2 < 2 ** 24
    g1 = np.asarray(desc1).astype(np.float32 if exact32 else np.float64)
    g2 = np.asarray(desc2).astype(g1.dtype)
    n1d = np.sqrt((g1.astype(np.float64) ** 2).sum(1))
    n2d = np.sqrt((g2.astype(np.float64) ** 2).sum(1))
    n1d[n1d == 0] = 1.0
    n2d[n2d == 0] = 1.0
    # candidates by the distance in image 2 (float32, the bulk), then both distances in float64
    l2f = l2.astype(np.float32)
    x2f, y2f = h2[:, 0].astype(np.float32), h2[:, 1].astype(np.float32)
    rows, cols, sims = [], [], []
    for s in range(0, n1, BLOCK):
        e = min(s + BLOCK, n1)
        d = l2f[s:e, 0:1] * x2f
        d += l2f[s:e, 1:2] * y2f
        d += l2f[s:e, 2:3]
        np.abs(d, out=d)
        r, c = np.divmod(np.flatnonzero(d <= max_px * 1.001 + 1e-3), n2)   # faster than 2-D nonzero
        r += s
        near = (np.abs(_line_dist(l2[r], h2[c])) <= max_px) & (np.abs(_line_dist(l1[c], h1[r])) <= max_px)
        r, c = r[near], c[near]
        rows.append(r)
        cols.append(c)
        dots = np.einsum("ij,ij->i", g1[r], g2[c]).astype(np.float64)   # exact (see above)
        sims.append(dots / (n1d[r] * n2d[c]))
    a = np.concatenate(rows)
    b = np.concatenate(cols)
    sim = np.concatenate(sims)
    if len(a) == 0:
        return np.zeros((0, 2), np.int64)
    best_b, ok_a = _top_two(a, b, sim, n1, ratio, max_angle)
    best_a, ok_b = _top_two(b, a, sim, n2, ratio, max_angle)
    ia = np.nonzero(ok_a)[0]
    ib = best_b[ia]
    keep = ok_b[ib] & (best_a[ib] == ia)
    return np.stack([ia[keep], ib[keep]], axis=1).astype(np.int64)


def _top_two(key, other, sim, n, ratio, max_angle):
    """For each of ``n`` features, its best candidate (``other`` of its highest ``sim`` among the
    candidate pairs with that ``key``; -1 if none) and whether that best one is a match."""
    order = np.lexsort((other, -sim, key))       # by key, best first (ties: lower index first)
    k, o, v = key[order], other[order], sim[order]
    first = np.r_[True, k[1:] != k[:-1]]
    idx = np.nonzero(first)[0]
    best = np.full(n, -1, np.int64)
    top = np.full(n, -np.inf)
    second = np.full(n, -np.inf)
    best[k[idx]] = o[idx]
    top[k[idx]] = v[idx]
    has2 = idx + 1 < len(k)
    nxt = idx[has2] + 1
    same = k[nxt] == k[idx[has2]]
    second[k[idx[has2]][same]] = v[nxt[same]]
    return best, _passes(top, second, ratio, max_angle)


def _passes(top, second, ratio, max_angle):
    """Whether the best similarity ``top`` is a match: within ``max_angle`` and beating the
    second best's angle by ``ratio`` (a lone candidate passes the ratio test)."""
    ang = np.arccos(np.clip(top, -1.0, 1.0))
    ang2 = np.where(np.isfinite(second), np.arccos(np.clip(second, -1.0, 1.0)), np.pi)
    return np.isfinite(top) & (ang <= max_angle) & (ang < ratio * ang2)


def add_guided_matches(pycolmap, db_path, rec, pairs, max_px: float = EPIPOLAR_PX, on_pair=None) -> dict:
    """Add matches guided by the known poses to the verified matches of image ``pairs``.

    Args:
        pycolmap: the module; db_path: the database; rec: the posed reconstruction whose cameras
            are at the database's keypoint scale (``_posed_reconstruction``).
        pairs: image-name pairs to match.
        on_pair: called as ``on_pair(k, n)`` before the k-th of n pairs (progress), or None.

    Returns:
        ``{"pairs": n, "added": matches added}``.
    """
    added = 0
    with pycolmap.Database.open(db_path) as db:
        by_name = {im.name: im for im in db.read_all_images()}
        feats = {}

        def features(image_id):
            if image_id not in feats:
                feats[image_id] = (np.asarray(db.read_keypoints(image_id))[:, :2],
                                   np.asarray(db.read_descriptors(image_id).data))
            return feats[image_id]

        for k, (na, nb) in enumerate(pairs):
            if on_pair is not None:
                on_pair(k + 1, len(pairs))
            if na not in by_name or nb not in by_name:
                continue
            i1, i2 = by_name[na].image_id, by_name[nb].image_id
            if i1 > i2:
                i1, i2 = i2, i1
            im1, im2 = rec.images[i1], rec.images[i2]
            K1 = rec.cameras[im1.camera_id].calibration_matrix()
            K2 = rec.cameras[im2.camera_id].calibration_matrix()
            F = fundamental(K1, im1.cam_from_world().matrix(), K2, im2.cam_from_world().matrix())
            (x1, d1), (x2, d2) = features(i1), features(i2)
            new = epipolar_matches(x1, x2, d1, d2, F, max_px=max_px)
            if db.exists_two_view_geometry(i1, i2):
                geo = db.read_two_view_geometry(i1, i2)
                old = np.asarray(geo.inlier_matches, np.int64).reshape(-1, 2)
                db.delete_two_view_geometry(i1, i2)
            else:
                geo = pycolmap.TwoViewGeometry()
                old = np.zeros((0, 2), np.int64)
            # a feature keeps its unguided partner; the guided one is added where it has none
            taken1, taken2 = set(old[:, 0].tolist()), set(old[:, 1].tolist())
            extra = np.array([m for m in new.tolist() if m[0] not in taken1 and m[1] not in taken2],
                             np.int64).reshape(-1, 2)
            geo.inlier_matches = np.concatenate([old, extra]).astype(np.uint32)
            if len(old) == 0:   # no verified geometry before: the known poses are one
                geo.config = pycolmap.TwoViewGeometryConfiguration.CALIBRATED
            db.write_two_view_geometry(i1, i2, geo)
            added += len(extra)
    return {"pairs": len(pairs), "added": added}
