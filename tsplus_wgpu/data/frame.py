"""The normalised frame training works in: :class:`WorldFrame`.

A capture's units are arbitrary: COLMAP's are whatever the reconstruction picked, a survey's
are metres in UTM coordinates (offsets near 1e6), a CAD export's may be millimetres. Every
length the trainer uses (the position learning rate, the near plane, the densification's area
threshold, the size prune's near plane) is a constant, so without normalisation a scene in
millimetres trains differently from the same scene in metres, and a large offset costs the
device's float32 positions most of their precision. The trainer therefore works in a frame
where the camera centres lie within radius 1 of the origin::

    normalised = (world - offset) * scale

with ``offset`` the mean camera centre and ``scale`` the inverse of the largest centre's
distance from it (:meth:`WorldFrame.for_cameras`). The map is a similarity without rotation,
so a camera keeps its rotation and intrinsics and sees exactly the same image
(:meth:`WorldFrame.camera`): only lengths change, by ``scale``. Everything a user reads back
(``mesh.ply``, checkpoint positions, ``current_model``) is in world units again
(:meth:`WorldFrame.to_world`), and a world-unit mesh rendered outside the trainer takes its
near plane from the frame (:meth:`WorldFrame.near_world`) so a scene in kilometres is not
clipped either.

The math is float64 NumPy and deterministic: the same cameras give the same frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..types import Camera, TriangleModel

#: the near plane in frame units (a fraction of the camera radius): TrainConfig.near's default,
#: and the near plane the apps draw a world-unit mesh with (through :meth:`WorldFrame.near_world`)
NEAR = 0.01


@dataclass(frozen=True)
class WorldFrame:
    """A similarity without rotation: ``normalised = (world - offset) * scale``.

    Attributes:
        scale: frame units per world unit (finite, > 0).
        offset: the world point that becomes the origin, three floats.
    """

    scale: float
    offset: tuple

    def __post_init__(self):
        scale = float(self.scale)
        offset = tuple(float(v) for v in np.asarray(self.offset, np.float64).ravel())
        if not (np.isfinite(scale) and scale > 0):
            raise ValueError(f"WorldFrame scale: expected a finite number > 0, got {self.scale!r}")
        if len(offset) != 3 or not all(np.isfinite(offset)):
            raise ValueError(f"WorldFrame offset: expected 3 finite numbers, got {self.offset!r}")
        object.__setattr__(self, "scale", scale)
        object.__setattr__(self, "offset", offset)

    # ------------------------------------------------------------------ construction
    @classmethod
    def identity(cls) -> "WorldFrame":
        """The frame that is the world (scale 1, no offset)."""
        return cls(1.0, (0.0, 0.0, 0.0))

    @classmethod
    def for_cameras(cls, cameras, points=None) -> "WorldFrame":
        """The frame of a capture: offset = the mean camera centre, scale = 1 / the largest
        distance of a centre from it. When the centres coincide (one camera, or a turntable
        whose poses are all the same; radius below ``1e-9 (1 + |offset|)``) the radius is the
        90th percentile of the ``points``' distances from the offset instead, and 1 when that
        is unusable too."""
        cameras = list(cameras)
        if not cameras:
            raise ValueError("WorldFrame.for_cameras: no cameras")
        centres = np.stack([np.asarray(c.center, np.float64) for c in cameras])    # [C, 3]
        offset = centres.mean(axis=0)
        tiny = 1e-9 * (1.0 + float(np.linalg.norm(offset)))
        radius = float(np.max(np.linalg.norm(centres - offset, axis=1)))
        if not radius >= tiny and points is not None and len(points):
            d = np.linalg.norm(np.asarray(points, np.float64).reshape(-1, 3) - offset, axis=1)
            radius = float(np.percentile(d, 90))
        if not (np.isfinite(radius) and radius >= tiny):
            radius = 1.0
        return cls(1.0 / radius, tuple(offset))

    # ------------------------------------------------------------------ maps
    def to_frame(self, points) -> np.ndarray:
        """World points ``[N, 3]`` in the frame (float64)."""
        return (np.asarray(points, np.float64) - np.asarray(self.offset)) * self.scale

    def to_world(self, points) -> np.ndarray:
        """Frame points ``[N, 3]`` in world units (float64)."""
        return np.asarray(points, np.float64) / self.scale + np.asarray(self.offset)

    def model_to_frame(self, model: TriangleModel) -> TriangleModel:
        """A world-unit ``model`` with its positions in the frame."""
        return TriangleModel(self.to_frame(model.positions), model.triangles, model.sh, model.opacity)

    def model_to_world(self, model: TriangleModel) -> TriangleModel:
        """A frame-unit ``model`` with its positions in world units."""
        return TriangleModel(self.to_world(model.positions), model.triangles, model.sh, model.opacity)

    def camera(self, cam: Camera) -> Camera:
        """``cam`` seen in the frame: the same rotation and intrinsics, world-to-camera
        translation ``scale (R offset + t)``. Camera-space coordinates are ``scale`` times the
        world camera's, so every point projects to the same pixel."""
        m = np.array(cam.world_to_camera, np.float64)
        m[:3, 3] = self.scale * (cam.R @ np.asarray(self.offset) + cam.t)
        return Camera(cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy, m)

    def near_world(self, near: float = NEAR) -> float:
        """A near plane given in frame units (default :data:`NEAR`), in world units."""
        return float(near) / self.scale

    # ------------------------------------------------------------------ JSON
    def to_json(self) -> dict:
        """``{"scale": float, "offset": [x, y, z]}`` (floats round-trip exactly through JSON)."""
        return dict(scale=self.scale, offset=list(self.offset))

    @classmethod
    def from_json(cls, data) -> "WorldFrame":
        """The frame :meth:`to_json` wrote; ValueError when ``data`` is not one."""
        if not isinstance(data, dict) or set(data) != {"scale", "offset"}:
            raise ValueError(f"not a WorldFrame: expected {{'scale', 'offset'}}, got {data!r}")
        return cls(data["scale"], data["offset"])
