"""``transforms.json`` scenes: NeRF-synthetic (Blender) and instant-ngp / nerfstudio variants.

Intrinsics come from ``fl_x/fl_y/cx/cy`` or ``camera_angle_x`` (and ``_y``), globally or
per frame; lens distortion (``k1 k2 p1 p2 [k3]``, or ``k1..k4`` with a fisheye model) is
undistorted with OpenCV.  Poses are camera-to-world in the OpenGL convention (camera
looks down -z, y up) and are turned into OpenCV world-to-camera matrices.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..types import Camera
from .errors import SceneError
from .images import read_image_size
from .plausible import check_angle, check_distortion, check_focal, check_size
from .scene import FrameSpec, check_pose
from .undistort import OpenCVUndistorter

# camera_model values (nerfstudio) understood here
PINHOLE_MODELS = {"PINHOLE", "SIMPLE_PINHOLE", "OPENCV", "RADIAL", "SIMPLE_RADIAL"}
FISHEYE_MODELS = {"OPENCV_FISHEYE"}

OPENGL_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])


def find_transforms(root: Path):
    """``(files, variant)``: the transforms file(s) of a scene folder, or ``([], None)``."""
    if (root / "transforms_train.json").is_file():
        files = [root / "transforms_train.json"]
        if (root / "transforms_test.json").is_file():
            files.append(root / "transforms_test.json")
        return files, "nerf-synthetic"
    if (root / "transforms.json").is_file():
        return [root / "transforms.json"], "transforms"
    return [], None


def _read_json(path: Path) -> dict:
    try:
        data = json.loads(path.read_text())
    except UnicodeDecodeError:
        raise SceneError(f"{path}: not a text file; expected a transforms JSON") from None
    except json.JSONDecodeError as exc:
        raise SceneError(f"{path}: invalid JSON at line {exc.lineno} column {exc.colno} ({exc.msg}); fix the file") from None
    if not isinstance(data, dict) or not isinstance(data.get("frames"), list):
        raise SceneError(f"{path}: no 'frames' list; expected a NeRF/instant-ngp transforms file")
    if not data["frames"]:
        raise SceneError(f"{path}: 'frames' is empty; add the camera poses of the images")
    return data


def _resolve_image(root: Path, file_path: str) -> Path:
    p = (root / file_path).resolve() if not Path(file_path).is_absolute() else Path(file_path)
    if p.suffix and p.is_file():
        return p
    for ext in (".png", ".jpg", ".jpeg", ".PNG", ".JPG"):
        q = p.with_name(p.name + ext)
        if q.is_file():
            return q
    return p if p.suffix else p.with_name(p.name + ".png")


def _num(d: dict, key: str, where: str):
    v = d.get(key)
    if v is None:
        return None
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise SceneError(f"{where}: '{key}' is {v!r}, expected a number; fix the file") from None
    if not math.isfinite(f):
        raise SceneError(f"{where}: '{key}' is not finite; fix the file")
    return f


def _world_to_camera(matrix, where):
    """The world-to-camera matrix (OpenCV axes) of a camera-to-world ``transform_matrix``
    (OpenGL axes; 3x4 or 4x4; a uniformly scaled rotation block is normalised)."""
    try:
        c2w = np.asarray(matrix, dtype=np.float64)
    except (TypeError, ValueError):
        raise SceneError(f"{where}: 'transform_matrix' is not a numeric 4x4 matrix; fix the file") from None
    if c2w.shape == (3, 4):
        c2w = np.vstack([c2w, [0, 0, 0, 1]])
    if c2w.shape != (4, 4):
        raise SceneError(f"{where}: 'transform_matrix' has shape {c2w.shape}, expected 4x4; fix the file")
    if not np.all(np.isfinite(c2w)):
        raise SceneError(f"{where}: pose contains non-finite values (NaN or Inf); fix or remove this frame")
    c2w = c2w @ OPENGL_TO_OPENCV
    # allow a uniformly scaled rotation block (some exporters) by normalising columns
    R = c2w[:3, :3]
    norms = np.linalg.norm(R, axis=0)
    if np.all(norms > 0) and np.allclose(norms, norms.mean(), rtol=1e-3):
        c2w[:3, :3] = R / norms
    try:
        w2c = np.linalg.inv(c2w)
    except np.linalg.LinAlgError:
        raise SceneError(f"{where}: 'transform_matrix' is singular; fix or remove this frame") from None
    check_pose(w2c, where)
    return w2c


def _intrinsics(merged, path, where):
    """``(w, h, fl_x, fl_y, cx, cy)`` of a frame (its keys override the file's)."""
    w = _num(merged, "w", where)
    h = _num(merged, "h", where)
    for key, v in (("w", w), ("h", h)):
        if v is not None:
            check_size(v, where, key)
    if w is None or h is None:
        if not path.is_file():
            w, h = None, None
        else:
            try:
                w, h = read_image_size(path)
            except SceneError:
                w, h = None, None
    if w is None or h is None:
        # image missing or unreadable and no 'w'/'h': placeholder size; the image loader
        # skips this frame (or raises in strict mode) before the camera is ever used
        w, h = 800.0, 800.0
    fl_x, fl_y = _num(merged, "fl_x", where), _num(merged, "fl_y", where)
    ax, ay = _num(merged, "camera_angle_x", where), _num(merged, "camera_angle_y", where)
    if fl_x is None and ax is not None:
        fl_x = 0.5 * w / math.tan(0.5 * check_angle(ax, where, "camera_angle_x"))
    if fl_y is None and ay is not None and fl_x is None:
        fl_y = 0.5 * h / math.tan(0.5 * check_angle(ay, where, "camera_angle_y"))
    if fl_x is None and fl_y is None:
        raise SceneError(f"{where}: no focal length ('fl_x' or 'camera_angle_x'); add it to the file")
    fl_x = fl_x if fl_x is not None else fl_y
    fl_y = fl_y if fl_y is not None else fl_x
    check_focal(fl_x, w, where, "fl_x")
    check_focal(fl_y, h, where, "fl_y")
    cx = _num(merged, "cx", where)
    cy = _num(merged, "cy", where)
    cx = w / 2 if cx is None else cx
    cy = h / 2 if cy is None else cy
    return w, h, fl_x, fl_y, cx, cy


def transforms_frames(root: Path, files: list, variant: str, warnings: list):
    """FrameSpecs for every frame of ``files`` (train file first); ``is_test`` set for test files.

    Returns:
        ``(frames, models)`` with models = camera model name -> count.
    """
    frames, models = [], {}
    undistorters = {}
    for fpath in files:
        data = _read_json(fpath)
        is_test = fpath.name == "transforms_test.json"
        cam_model = str(data.get("camera_model", "OPENCV")).upper()
        for k, fr in enumerate(data["frames"]):
            where = f"{fpath} (frame {k})"
            if not isinstance(fr, dict) or "file_path" not in fr or "transform_matrix" not in fr:
                raise SceneError(f"{where}: needs 'file_path' and 'transform_matrix'; fix the file")
            merged = dict(data)
            merged.update({kk: vv for kk, vv in fr.items() if kk != "frames"})
            model = str(merged.get("camera_model", cam_model)).upper()
            fisheye = bool(merged.get("is_fisheye", False)) or model in FISHEYE_MODELS
            if model not in PINHOLE_MODELS | FISHEYE_MODELS:
                raise SceneError(f"{where}: unknown camera_model {model!r}; supported: "
                                 f"{', '.join(sorted(PINHOLE_MODELS | FISHEYE_MODELS))}")
            if not isinstance(fr["file_path"], str) or not fr["file_path"].strip():
                raise SceneError(f"{where}: 'file_path' is {fr['file_path']!r}, expected the image's path as a "
                                 "string (e.g. \"images/0001.png\"); fix the file")
            path = _resolve_image(fpath.parent, str(fr["file_path"]))
            name = str(Path(fr["file_path"]).as_posix()).lstrip("./") or path.name
            if path.suffix and not Path(name).suffix:
                name += path.suffix
            w2c = _world_to_camera(fr["transform_matrix"], where)
            w, h, fl_x, fl_y, cx, cy = _intrinsics(merged, path, where)
            try:
                cam = Camera(int(round(w)), int(round(h)), fl_x, fl_y, cx, cy, w2c)
            except ValueError as exc:
                raise SceneError(f"{where}: {exc}; fix the file") from None
            keys = ("k1", "k2", "k3", "k4") if fisheye else ("k1", "k2", "p1", "p2", "k3")
            raw = {k: _num(merged, k, where) for k in keys}
            check_distortion(raw, where)
            coeffs = tuple(raw[k] or 0.0 for k in keys)
            und = None
            if any(coeffs):
                key = (coeffs, fisheye)
                if key not in undistorters:
                    undistorters[key] = OpenCVUndistorter(coeffs, fisheye=fisheye, source=str(fpath))
                und = undistorters[key]
            label = ("OPENCV_FISHEYE" if fisheye else "OPENCV") if any(coeffs) else "PINHOLE"
            models[label] = models.get(label, 0) + 1
            group = (str(fpath), cam.width, cam.height) if ("w" in fr or "h" in fr) else "shared"
            frames.append(FrameSpec(name=name, path=path, camera=cam, group=group, undistort=und,
                                    is_test=is_test, source=str(fpath), model=label))
    return frames, models
