"""Photos whose given pose disagrees with their own feature matches.

A camera model can hold a wrong pose. The shared lund scene's COLMAP model puts 20.jpg 4.7 units
off the street its neighbours follow 0.3-0.6 apart, turned 110 degrees from them, and its 110
points still reproject at 1.0 px: nothing in the model itself gives it away. Trained on, such a
photo paints its colours where the others see something else, and guided matching along its
wrong epipolar lines (:mod:`.guided`) adds points where nothing is.

The triangulation of posed photos has what shows it: the unguided matches between photos,
verified by COLMAP's two-view geometry, which estimates each pair's geometry from the matches
themselves and never from the poses. With correct poses those matches lie on the epipolar lines
the poses give, within a pixel or so. Per photo, :func:`pose_errors` takes the median Sampson
distance of each verified pair's matches (the first-order distance of a match from satisfying the
poses' epipolar constraint) and the median of those over its pairs, each pair weighted by its
matches: pairs of few matches, which repeated texture can verify with a wrong geometry, count
for little. :func:`disagreeing` picks the photos whose error is both over :data:`RATIO` times the
median photo's and over :data:`FLOOR` of the image diagonal.

Measured in docs/measurements.md ("A photo whose pose disagrees with its matches").
"""

from __future__ import annotations

import numpy as np

from .guided import fundamental

#: a pair counts when its verified matches are at least this many
MIN_INLIERS = 15
#: a photo is judged when it has at least this many such pairs
MIN_PAIRS = 2
#: a photo's error must exceed this many times the median photo's ...
RATIO = 5.0
#: ... and this fraction of the image diagonal (0.2 %: 2.5 px at 1000x750)
FLOOR = 0.002
#: at most this share of the photos is left out: past it the poses are not the odd ones out
MAX_SHARE = 1.0 / 3.0


def sampson(F, x1, x2) -> np.ndarray:
    """Sampson distances (pixels) of the matches ``x1[i] <-> x2[i]`` ([M,2] each) from
    ``x2^T F x1 = 0``."""
    h1 = np.c_[np.asarray(x1, np.float64), np.ones(len(x1))]
    h2 = np.c_[np.asarray(x2, np.float64), np.ones(len(x2))]
    fx1, ftx2 = h1 @ F.T, h2 @ F
    num = np.einsum("ij,ij->i", h2, fx1) ** 2
    den = fx1[:, 0] ** 2 + fx1[:, 1] ** 2 + ftx2[:, 0] ** 2 + ftx2[:, 1] ** 2
    return np.sqrt(num / np.maximum(den, 1e-300))


def _posed(rec):
    """``{image_id: (name, K, 3x4 world-to-camera, diagonal px, centre)}`` of a pycolmap Reconstruction."""
    out = {}
    for iid, im in rec.images.items():
        pose = im.cam_from_world() if callable(im.cam_from_world) else im.cam_from_world
        cam = rec.cameras[im.camera_id]
        t = np.asarray(pose.matrix(), np.float64)
        out[iid] = (im.name, np.asarray(cam.calibration_matrix(), np.float64), t, float(np.hypot(cam.width, cam.height)),
                    -t[:, :3].T @ t[:, 3])
    return out


def pose_errors(pycolmap, db_path, rec) -> dict:
    """``{name: (error, pairs)}`` for the photos of the posed reconstruction ``rec`` (cameras at
    the database's keypoint scale): over its verified pairs of at least :data:`MIN_INLIERS`
    matches (pairs whose cameras share a centre left aside), the median of their median Sampson
    distance from the poses' epipolar constraint, each pair weighted by its matches
    (:func:`weighted_median`), as a fraction of the image diagonal (NaN with fewer than
    :data:`MIN_PAIRS` pairs), and how many pairs that was."""
    posed = _posed(rec)
    per = {iid: [] for iid in posed}
    with pycolmap.Database.open(db_path) as db:
        pair_ids, geoms = db.read_two_view_geometries()
        keys = {}
        for pid, g in zip(pair_ids, geoms):
            i1, i2 = pycolmap.pair_id_to_image_pair(pid)
            m = np.asarray(g.inlier_matches)
            if i1 not in posed or i2 not in posed or len(m) < MIN_INLIERS:
                continue
            for i in (i1, i2):
                if i not in keys:
                    keys[i] = np.asarray(db.read_keypoints(i))[:, :2]
            (_, k1, t1, d1, c1), (_, k2, t2, d2, c2) = posed[i1], posed[i2]
            if np.linalg.norm(c1 - c2) <= 1e-9 * max(np.linalg.norm(c1), np.linalg.norm(c2), 1e-300):
                continue                    # one centre for both: no epipolar line to hold matches to
            f = fundamental(k1, t1, k2, t2)
            med = float(np.median(sampson(f, keys[i1][m[:, 0]], keys[i2][m[:, 1]])))
            per[i1].append((med / d1, len(m)))
            per[i2].append((med / d2, len(m)))
    return {posed[i][0]: (weighted_median(v) if len(v) >= MIN_PAIRS else float("nan"), len(v))
            for i, v in per.items()}


def weighted_median(values) -> float:
    """The median of ``(value, weight)`` pairs: the smallest value with at least half the weight
    at or below it."""
    v = sorted(values)
    w = np.cumsum([b for _, b in v], dtype=np.float64)
    return float(v[int(np.searchsorted(w, w[-1] / 2))][0])


def disagreeing(errors: dict) -> tuple:
    """``(names, typical)``: :func:`pose_errors`'s photos whose pose disagrees with their
    matches (over :data:`RATIO` x the median photo's error and over :data:`FLOOR`), worst first,
    and the median photo's error."""
    judged = {n: e for n, (e, _) in errors.items() if np.isfinite(e)}
    if len(judged) < 3:
        return [], float("nan")
    typical = float(np.median(list(judged.values())))
    return sorted((n for n, e in judged.items() if e > RATIO * typical and e > FLOOR), key=lambda n: -judged[n]), typical


def left_out(errors: dict) -> list:
    """The photos to leave out of the triangulation and of training: :func:`disagreeing`'s,
    unless they are more than :data:`MAX_SHARE` of the judged photos (then the poses or the
    camera model are wrong as a whole, not a few photos, and none is left out)."""
    bad, _ = disagreeing(errors)
    judged = sum(np.isfinite(e) for e, _ in errors.values())
    return bad if len(bad) <= MAX_SHARE * judged else []
