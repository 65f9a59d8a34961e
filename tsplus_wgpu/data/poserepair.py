"""A photo whose given pose disagrees with its matches (:mod:`.posecheck`), posed again from them.

Left out, such a photo is a view lost, and its own matches say where it is: the points
triangulated from the other photos (whose poses agree with their matches) are seen in it through
its verified matches to those photos. The shared lund scene's 20.jpg has 329 keypoints that lead
to one such point each; pycolmap's LO-RANSAC PnP with refinement poses it from them (215 within
the threshold), 7.5 units and 110 degrees from where the camera model put it, between 19.jpg and
21.jpg, and with that pose its epipolar error falls from 1.32 % of the image diagonal to the
median photo's 0.04 %.

:func:`correspondences` gathers the 2D-3D pairs (a keypoint whose matches lead to different
points is dropped as ambiguous); :func:`repose` estimates the pose when enough pairs back it
(:data:`MIN_MATCHES`, :data:`MIN_INLIER_SHARE`); :func:`reposed_photos` keeps it only when the
photo's epipolar error with it, judged alone against the photos whose poses agree (every pair, not
only those with points), no longer disagrees by :mod:`.posecheck`'s own rule. Otherwise the photo
stays left out. Measured in docs/measurements.md ("A photo whose pose disagrees, posed again from
its matches").
"""

from __future__ import annotations

import numpy as np

#: the fewest 2D-3D correspondences (distinct keypoints) a photo is posed from
MIN_MATCHES = 12
#: the smallest share of them within the RANSAC threshold of the estimated pose
MIN_INLIER_SHARE = 0.5
#: the RANSAC threshold as a fraction of the image diagonal (6 px at 1200x900) ...
RANSAC_FRACTION = 0.004
#: ... and never under this many pixels (a small image's keypoints are no sharper)
RANSAC_MIN_PX = 2.0


def correspondences(pycolmap, db, rec, image_id) -> tuple:
    """``(points2D [M,2], points3D [M,3])`` of the image ``image_id`` of the open database ``db``:
    each of its keypoints whose verified matches lead (through the other images of ``rec``, the
    triangulated reconstruction without it) to exactly one 3D point, with that point."""
    keys = np.asarray(db.read_keypoints(image_id))[:, :2]
    found: dict = {}
    pair_ids, geoms = db.read_two_view_geometries()
    for pid, g in zip(pair_ids, geoms):
        i1, i2 = pycolmap.pair_id_to_image_pair(pid)
        if image_id not in (i1, i2):
            continue
        other = i2 if i1 == image_id else i1
        if other not in rec.images:
            continue
        m = np.asarray(g.inlier_matches, np.int64).reshape(-1, 2)
        mine, theirs = (m[:, 0], m[:, 1]) if i1 == image_id else (m[:, 1], m[:, 0])
        pts2d = rec.images[other].points2D
        for a, b in zip(mine.tolist(), theirs.tolist()):
            p = pts2d[b]
            if p.has_point3D():
                found.setdefault(a, set()).add(int(p.point3D_id))
    ok = sorted(a for a, ids in found.items() if len(ids) == 1)
    if not ok:
        return np.zeros((0, 2)), np.zeros((0, 3))
    return (keys[ok].astype(np.float64),
            np.array([rec.points3D[next(iter(found[a]))].xyz for a in ok], np.float64))


def repose(pycolmap, points2d, points3d, camera) -> dict | None:
    """The pose of a camera (a pycolmap ``Camera`` at the keypoints' scale) from its 2D-3D
    correspondences: ``{"cam_from_world": [3,4], "inliers": n, "matches": m}``, or None when
    there are too few (:data:`MIN_MATCHES`), the estimate fails or too few agree with it
    (:data:`MIN_INLIER_SHARE`)."""
    m = len(points2d)
    if m < MIN_MATCHES:
        return None
    opts = pycolmap.AbsolutePoseEstimationOptions()
    opts.ransac.max_error = max(RANSAC_MIN_PX, RANSAC_FRACTION * float(np.hypot(camera.width, camera.height)))
    try:
        got = pycolmap.estimate_and_refine_absolute_pose(np.asarray(points2d, np.float64),
                                                         np.asarray(points3d, np.float64), camera, opts)
    except Exception:       # pycolmap refuses the input: the photo stays left out
        return None
    if not got:
        return None
    n = int(got["num_inliers"])
    pose = np.asarray(got["cam_from_world"].matrix(), np.float64)
    if n < MIN_MATCHES or n < MIN_INLIER_SHARE * m or not np.all(np.isfinite(pose)):
        return None
    return {"cam_from_world": pose, "inliers": n, "matches": m}


def moved(old_w2c, new_w2c) -> tuple:
    """``(distance, degrees)``: how far the camera centre moved between two world-to-camera
    poses ([3,4] or [4,4]) and by what angle it turned."""
    a, b = np.asarray(old_w2c, np.float64)[:3], np.asarray(new_w2c, np.float64)[:3]
    ca, cb = -a[:, :3].T @ a[:, 3], -b[:, :3].T @ b[:, 3]
    cos = (np.trace(b[:, :3] @ a[:, :3].T) - 1.0) / 2.0
    return float(np.linalg.norm(cb - ca)), float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def with_pose(cam, cam_from_world):
    """``cam`` (a :class:`~tsplus_wgpu.types.Camera`) with the world-to-camera pose
    ``cam_from_world`` ([3,4] or [4,4])."""
    from ..types import Camera  # noqa: PLC0415
    return Camera(cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy,
                  np.vstack([np.asarray(cam_from_world, np.float64)[:3], [0.0, 0.0, 0.0, 1.0]]))


def reposed_photos(pycolmap, db, rec, posed, cameras, safe, off, errors, posed_reconstruction) -> dict:
    """``{name: repose result + "error"}`` for the left-out photos ``off`` (of the image names
    ``safe``, with ``cameras``) that their matches pose again (:func:`repose`) from the points of
    ``rec``, triangulated without them; ``posed`` is the posed reconstruction of every photo (its
    cameras at the keypoints' scale), ``errors`` :func:`~.posecheck.pose_errors` of it, and
    ``posed_reconstruction`` :func:`~.sfm._posed_reconstruction` (passed in: :mod:`.sfm` imports
    this module). A new pose is kept only when the photo's epipolar error with it (every pair with a photo whose pose agrees) no longer
    disagrees by :mod:`.posecheck`'s rule; each photo is judged alone, never against another
    photo's wrong pose."""
    from .posecheck import FLOOR, RATIO, pose_errors  # noqa: PLC0415
    judged = [e for e, _ in errors.values() if np.isfinite(e)]
    typical = float(np.median(judged)) if judged else float("nan")
    by_name = {im.name: iid for iid, im in posed.images.items()}
    got = {}
    with pycolmap.Database.open(db) as database:
        for s in off:
            iid = by_name.get(s)
            if iid is None:
                continue
            p2, p3 = correspondences(pycolmap, database, rec, iid)
            r = repose(pycolmap, p2, p3, posed.cameras[posed.images[iid].camera_id])
            if r is not None:
                got[s] = r
    if not got or not np.isfinite(typical):
        return {}
    fixed = {}
    for s, r in got.items():
        trial = [with_pose(c, r["cam_from_world"]) if n == s else c for c, n in zip(cameras, safe)]
        e = pose_errors(pycolmap, db, posed_reconstruction(pycolmap, db, trial, safe, skip=set(off) - {s})).get(
            s, (float("nan"), 0))[0]
        if np.isfinite(e) and not (e > RATIO * typical and e > FLOOR):
            fixed[s] = {**r, "error": float(e)}
    return fixed
