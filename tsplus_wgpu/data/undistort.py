"""Lens undistortion: turn a distorted camera + image into a pinhole camera + image.

Two back ends share one interface, ``undistorter(img, camera) -> (img, camera)``
where ``camera`` is a :class:`~tsplus_wgpu.types.Camera` holding the distorted
camera's pinhole part at the image's actual size:

* :class:`OpenCVUndistorter` for transforms.json distortion (``k1 k2 p1 p2 [k3]``,
  or the ``k1..k4`` fisheye model), through ``cv2.initUndistortRectifyMap``.
* :class:`ColmapUndistorter` for every COLMAP camera model: the undistorted
  pinhole camera comes from ``pycolmap.undistort_camera`` and each output pixel
  is mapped through the model's own ``img_from_cam``.

Pixel centres are at +0.5 in the project's convention (as in COLMAP); OpenCV
puts them at integers, so principal points are shifted by 0.5 on the way in and out.
Remap tables are cached per image size and intrinsics.
"""

from __future__ import annotations

import numpy as np

from ..types import Camera
from .errors import SceneError


def _remap(img, map_x, map_y):
    import cv2  # noqa: PLC0415
    return np.ascontiguousarray(cv2.remap(img, map_x, map_y, interpolation=cv2.INTER_LINEAR,
                                          borderMode=cv2.BORDER_REPLICATE))


class OpenCVUndistorter:
    """OpenCV radial-tangential (or fisheye) undistortion keeping the image size.

    Args:
        coeffs: ``(k1, k2, p1, p2[, k3])`` for the standard model, ``(k1, k2, k3, k4)`` for fisheye.
        fisheye: use OpenCV's equidistant fisheye model.
        source: file name used in error messages.
    """

    def __init__(self, coeffs, fisheye: bool = False, source: str = ""):
        self.coeffs = np.asarray(coeffs, np.float64)
        self.fisheye = bool(fisheye)
        self.source = source
        self._cache = {}

    @property
    def is_identity(self) -> bool:
        return not np.any(self.coeffs)

    def __call__(self, img, camera: Camera):
        import cv2  # noqa: PLC0415
        w, h = camera.width, camera.height
        key = (w, h, camera.fx, camera.fy, camera.cx, camera.cy)
        if key not in self._cache:
            K = np.array([[camera.fx, 0, camera.cx - 0.5], [0, camera.fy, camera.cy - 0.5], [0, 0, 1]])
            try:
                if self.fisheye:
                    D = self.coeffs[:4].reshape(4, 1)
                    newK = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(
                        K, D, (w, h), np.eye(3), balance=0.0)
                    mx, my = cv2.fisheye.initUndistortRectifyMap(K, D, np.eye(3), newK, (w, h), cv2.CV_32FC1)
                else:
                    D = self.coeffs
                    newK, _ = cv2.getOptimalNewCameraMatrix(K, D, (w, h), 0.0, (w, h))
                    mx, my = cv2.initUndistortRectifyMap(K, D, None, newK, (w, h), cv2.CV_32FC1)
            except cv2.error as exc:
                raise SceneError(f"{self.source}: OpenCV cannot undistort with coefficients "
                                 f"{self.coeffs.tolist()} ({str(exc).strip().splitlines()[-1]}); check them") from None
            if not (np.all(np.isfinite(newK)) and newK[0, 0] > 0 and newK[1, 1] > 0):
                raise SceneError(f"{self.source}: distortion coefficients {self.coeffs.tolist()} give no valid "
                                 "undistorted camera; check them")
            cam = Camera(w, h, newK[0, 0], newK[1, 1], newK[0, 2] + 0.5, newK[1, 2] + 0.5,
                         camera.world_to_camera)
            self._cache[key] = (mx, my, cam)
        mx, my, cam = self._cache[key]
        out = _remap(img, mx, my)
        return out, Camera(cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy, camera.world_to_camera)


class ColmapUndistorter:
    """Undistort any COLMAP camera model with pycolmap's camera model code.

    Args:
        colmap_camera: the ``pycolmap.Camera`` of the model (at the model's size).
        source: file name used in error messages.
    """

    def __init__(self, colmap_camera, source: str = ""):
        self.camera = colmap_camera
        self.source = source
        self._cache = {}

    def __call__(self, img, camera: Camera):
        from .long_calls import import_pycolmap  # noqa: PLC0415
        pycolmap = import_pycolmap()
        h, w = img.shape[:2]
        key = (w, h)
        if key not in self._cache:
            cam = pycolmap.Camera(self.camera.todict()) if hasattr(self.camera, "todict") else self.camera
            if (cam.width, cam.height) != (w, h):
                cam.rescale(int(w), int(h))
            try:
                ucam = pycolmap.undistort_camera(pycolmap.UndistortCameraOptions(), cam)
            except Exception as exc:
                raise SceneError(f"{self.source}: pycolmap cannot undistort camera model {cam.model_name} "
                                 f"({exc}); check its parameters") from None
            K = ucam.calibration_matrix()
            uw, uh = int(ucam.width), int(ucam.height)
            jj, ii = np.meshgrid(np.arange(uw, dtype=np.float64) + 0.5, np.arange(uh, dtype=np.float64) + 0.5)
            rays = np.stack([(jj - K[0, 2]) / K[0, 0], (ii - K[1, 2]) / K[1, 1], np.ones_like(jj)], -1)
            src = cam.img_from_cam(rays.reshape(-1, 3), check_cheirality=False)
            src = np.asarray(src, np.float64).reshape(uh, uw, 2) - 0.5
            src = np.where(np.isfinite(src), src, -1.0)
            self._cache[key] = (src[..., 0].astype(np.float32), src[..., 1].astype(np.float32),
                                (uw, uh, K[0, 0], K[1, 1], K[0, 2], K[1, 2]))
        mx, my, (uw, uh, fx, fy, cx, cy) = self._cache[key]
        out = _remap(img, mx, my)
        return out, Camera(uw, uh, fx, fy, cx, cy, camera.world_to_camera)
