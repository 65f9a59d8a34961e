"""Which way is up in a scene, from its cameras alone.

A reconstruction's world has no up: COLMAP's is the frame of whichever camera it started from,
transforms.json worlds are often z-up, LLFF's y-down. An engine wants +Y up. People hold a
camera level far more tightly than they aim it: its horizontal image axis lies in the ground
plane (little roll), while its viewing direction tilts up or down freely. So up is the direction
most nearly perpendicular to every camera's horizontal image axis.

* :func:`exif_up_axis`: the camera-frame axis that is up in a photo as displayed, from its EXIF
  orientation (a phone's portrait photo is stored sideways with orientation 6).
* :func:`estimate_up`: up and a forward direction from the cameras' rotations. Photos without
  EXIF that were stored sideways (the shared cup) are recognised: each camera's horizontal axis
  is whichever of its image axes is nearer level. When every camera faces one way (a walk down
  a street, a forward-facing capture) the horizontal axes are nearly parallel and cannot tell
  pitch from up; the cameras' mean up, stripped of their common roll, decides then, with a smooth
  blend between the two regimes.
* :func:`engine_rotation`: the rotation taking the world to an engine's frame (+Y up, -Z the
  cameras' mean viewing direction).

Everything is float64 NumPy and deterministic.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: the EXIF tag of a photo's orientation
EXIF_ORIENTATION = 0x0112
#: EXIF orientation -> the camera-frame axis (x right, y down) pointing up in the displayed photo
_EXIF_UP = {1: (0, -1, 0), 2: (0, -1, 0), 3: (0, 1, 0), 4: (0, 1, 0),
            5: (-1, 0, 0), 6: (-1, 0, 0), 7: (1, 0, 0), 8: (1, 0, 0)}
#: below this ratio of the horizontal axes' two largest spreads they are one direction (the
#: cameras' mean up decides); above ``_SPREAD_HI`` their common perpendicular alone; a blend between
_SPREAD_LO, _SPREAD_HI = 0.05, 0.15
#: residual (sine of the roll) past which a camera's weight falls off in the reweighted fit
_ROLL_SCALE = float(np.sin(np.radians(5.0)))


@dataclass
class Upright:
    """``up`` and ``forward`` (unit world vectors, perpendicular), ``how`` (which rule decided),
    ``rms_roll_deg`` (the cameras' roll about their view against this up: small for a
    trustworthy estimate) and ``sideways`` (cameras whose photo's up is an image x axis)."""
    up: np.ndarray
    forward: np.ndarray
    how: str
    rms_roll_deg: float
    sideways: int
    cameras: int

    def as_dict(self) -> dict:
        return dict(up=[round(float(v), 6) for v in self.up], forward=[round(float(v), 6) for v in self.forward],
                    how=self.how, rms_roll_deg=round(self.rms_roll_deg, 2), sideways=self.sideways,
                    cameras=self.cameras)

    @classmethod
    def from_dict(cls, d) -> "Upright | None":
        """The inverse of :meth:`as_dict`; None for anything malformed."""
        try:
            up, fwd = np.asarray(d["up"], np.float64), np.asarray(d["forward"], np.float64)
            if up.shape != (3,) or fwd.shape != (3,) or not np.all(np.isfinite(up)) or not np.all(np.isfinite(fwd)):
                return None
            if np.linalg.norm(up) < 1e-6:
                return None
            up = up / np.linalg.norm(up)
            fwd = fwd - (fwd @ up) * up
            if np.linalg.norm(fwd) < 1e-6:
                return None
            return cls(up, fwd / np.linalg.norm(fwd), str(d.get("how", "")), float(d.get("rms_roll_deg", 0.0)),
                       int(d.get("sideways", 0)), int(d.get("cameras", 0)))
        except (KeyError, TypeError, ValueError, ZeroDivisionError):
            return None


def exif_up_axis(path) -> np.ndarray | None:
    """The camera-frame up axis of ``path`` as displayed (EXIF orientation; [0, -1, 0] for
    orientation 1), or None when the file has no readable orientation."""
    try:
        from PIL import Image  # noqa: PLC0415
        with Image.open(Path(path)) as im:
            o = im.getexif().get(EXIF_ORIENTATION)
    except Exception:
        return None
    axis = _EXIF_UP.get(int(o)) if isinstance(o, int) else None
    return None if axis is None else np.array(axis, np.float64)


def _unit(v):
    n = float(np.linalg.norm(v))
    return v / n if n > 1e-12 else None


def _fit(h, ups):
    """Up from each camera's horizontal image axis ``h`` [N, 3] and up axis ``ups`` [N, 3], both
    in world coordinates: the reweighted common perpendicular of ``h``, blended towards the mean
    of ``ups`` (less their common roll) as the ``h`` close into one direction. Returns ``(up,
    blend, rms roll in degrees)``; blend 1 is the perpendicular alone."""
    w = np.ones(len(h))
    u = None
    for _ in range(50):
        m = (h * w[:, None]).T @ h / w.sum()
        ev, vec = np.linalg.eigh(m)
        mean_up = (ups * w[:, None]).sum(0)
        null = vec[:, 0] * (1.0 if vec[:, 0] @ mean_up >= 0 else -1.0)
        main = vec[:, 2]
        level = _unit(mean_up - (mean_up @ main) * main)
        s = float(np.clip((ev[1] / max(ev[2], 1e-300) - _SPREAD_LO) / (_SPREAD_HI - _SPREAD_LO), 0.0, 1.0))
        new = _unit(s * null + (1.0 - s) * level) if level is not None else None
        new = null if new is None else new
        w = 1.0 / np.maximum(np.abs(h @ new), _ROLL_SCALE)
        done = u is not None and float(new @ u) > 1.0 - 1e-14
        u = new
        if done:
            break
    roll = np.degrees(np.arcsin(np.clip(h @ u, -1.0, 1.0)))
    return u, s, float(np.sqrt(np.mean(roll ** 2)))


def estimate_up(rotations, up_axes=None) -> Upright | None:
    """Up and forward of a scene from its world-to-camera ``rotations`` ([N, 3, 3] or a list of
    cameras with ``.R``), OpenCV convention (x right, y down, z forward).

    ``up_axes``: per camera, the camera-frame axis that is up in its displayed photo
    (:func:`exif_up_axis`) or None where unknown. The unknown ones are taken to share one
    orientation: upright, or a phone's usual portrait stored sideways (EXIF orientation 6: up is
    -x) where that fits the cameras with less than half the roll and they face many ways (cameras
    that all face one way fit either reading, so upright is kept unless the fit says otherwise).
    Returns None without cameras.
    """
    R = np.asarray([getattr(c, "R", c) for c in rotations], np.float64).reshape(-1, 3, 3)
    n = len(R)
    if n == 0 or not np.all(np.isfinite(R)):
        return None
    z = R[:, 2]                                              # the viewing directions in the world
    axes = list(up_axes) if up_axes is not None else [None] * n
    if len(axes) != n:
        raise ValueError(f"up_axes: {len(axes)} axes for {n} cameras")
    known = np.array([a is not None for a in axes])
    up_cam = np.array([a if a is not None else (0.0, -1.0, 0.0) for a in axes], np.float64)
    ups = np.einsum("nji,nj->ni", R, up_cam)                # R^T a: the display up in the world
    fits = [(_fit(np.cross(ups, z), ups), 0)]
    if not known.all():
        side = np.where(known[:, None], up_cam, (-1.0, 0.0, 0.0))
        ups_s = np.einsum("nji,nj->ni", R, side)
        fit_s = _fit(np.cross(ups_s, z), ups_s)
        # only cameras facing many ways can say so: facing one way, either reading fits equally
        if fit_s[1] > 0.5 and fit_s[2] < 0.5 * fits[0][0][2]:
            fits = [(fit_s, int((~known).sum()))]
    (u, s, rms), sideways = fits[0]
    how = ("the cameras' horizontal image axes" if s >= 1.0 else
           "the cameras' mean up (they all face one way)" if s <= 0.0 else
           "the cameras' horizontal image axes and mean up")
    return Upright(u, _forward(z, u), how, rms, sideways, n)


def _forward(z, up):
    """The cameras' mean viewing direction in the ground plane; for cameras all around an object
    (their directions cancel), the first camera's."""
    flat = z - np.outer(z @ up, up)
    f = _unit(flat.sum(0))
    if f is None or np.linalg.norm(flat.sum(0)) < 0.25 * len(z):
        f = next((_unit(v) for v in flat if np.linalg.norm(v) > 0.1), None)
    if f is None:                                                        # every camera looks straight up or down
        f = _unit(np.cross(up, [1.0, 0.0, 0.0])) if abs(up[0]) < 0.9 else _unit(np.cross(up, [0.0, 1.0, 0.0]))
    return f


def engine_rotation(upright: Upright) -> np.ndarray:
    """The rotation ``A`` ([3, 3], det +1) with ``A @ p`` a world point in an engine's frame:
    +Y is ``upright.up``, -Z ``upright.forward`` (so an engine camera looking down -Z sees what
    the photos saw), +X their cross product."""
    yax = upright.up
    zax = -upright.forward
    xax = np.cross(yax, zax)
    return np.stack([xax, yax, zax])


def scene_upright(scene) -> Upright | None:
    """:func:`estimate_up` of a loaded scene's cameras, with each photo's EXIF orientation where
    its file in ``scene.image_dir`` has one."""
    if not getattr(scene, "image_dir", None):
        return estimate_up(scene.cameras)
    return files_upright(scene.cameras, [Path(scene.image_dir) / name for name in scene.image_names])


def files_upright(cameras, files) -> Upright | None:
    """:func:`estimate_up` of ``cameras`` with the EXIF orientation of their photos ``files``
    (where a file has one): the up of a scene from its cameras alone
    (:func:`~tsplus_wgpu.data.loader.scene_cameras`), no pixel read."""
    return estimate_up(cameras, [exif_up_axis(f) for f in files])
