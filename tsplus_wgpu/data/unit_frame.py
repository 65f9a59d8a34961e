"""A frame for pycolmap that does not depend on the world's units.

pycolmap's triangulation, its pose refinement and their solvers' stopping rules work in the
numbers they are given: the same photos with a world scaled by 1000 and shifted far from the
origin gave lund 12,473 triangulated points instead of 12,450 (1,683 of them elsewhere by more
than 1e-12 of the scene) and 20.jpg another repaired pose, and so another trained mesh
(docs/measurements.md, "The triangulation in a frame of its own (2026-12-04)"). So the posed photos are
handed to it in a frame of their own: the cameras' mean centre at the origin, their median
distance from it 1 (:func:`camera_frame`); its points and poses are mapped back to the world.
A similarity of the world moves that frame with it, so the same photos give the same points in
any units, to rounding. It is the trainer's :class:`~.frame.WorldFrame` map with another scale
(the median distance, not the largest: one far camera does not shrink the rest) and a division
where that class multiplies by the inverse; the triangulations measured in docs/measurements.md
were made with these exact numbers, so it is kept as it is.
"""

from __future__ import annotations

import numpy as np


def camera_frame(cameras):
    """``(centre [3], scale)``: the mean of the cameras' centres (the trainer's frame centres them
    so too, :mod:`.frame`) and their median distance from it; the scale is 1 when they all stand
    at one point, and the frame the world's when the centres are not finite."""
    centres = np.array([np.asarray(c.center, np.float64) for c in cameras]).reshape(-1, 3)
    if not len(centres) or not np.all(np.isfinite(centres)):
        return np.zeros(3), 1.0
    centre = centres.mean(axis=0)
    scale = float(np.median(np.linalg.norm(centres - centre, axis=1)))
    return centre, (scale if np.isfinite(scale) and scale > 0.0 else 1.0)


def in_frame(camera, frame):
    """``camera`` (a :class:`~tsplus_wgpu.types.Camera`) seen in ``frame`` (:func:`camera_frame`),
    where a world point ``x`` is at ``(x - centre) / scale``: the same rotation and image, its
    translation ``(R centre + t) / scale``."""
    from ..types import Camera  # noqa: PLC0415
    centre, scale = frame
    w2c = np.asarray(camera.world_to_camera, np.float64).copy()
    w2c[:3, 3] = (w2c[:3, :3] @ centre + w2c[:3, 3]) / scale
    return Camera(camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy, w2c)


def pose_to_world(cam_from_frame, frame):
    """``[3, 4]``: a world-to-camera pose of ``frame`` as the world's, ``[R | scale t - R centre]``."""
    centre, scale = frame
    p = np.asarray(cam_from_frame, np.float64)[:3, :4].copy()
    p[:, 3] = scale * p[:, 3] - p[:, :3] @ centre
    return p


def reconstruction_to_world(pycolmap, rec, frame):
    """``rec`` (a pycolmap reconstruction in ``frame``) moved to the world, in place."""
    centre, scale = frame
    if scale != 1.0 or np.any(centre != 0.0):
        rec.transform(pycolmap.Sim3d(scale, pycolmap.Rotation3d(np.array([0.0, 0.0, 0.0, 1.0])),
                                     np.asarray(centre, np.float64)))
    return rec
