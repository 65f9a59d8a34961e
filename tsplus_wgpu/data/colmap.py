"""COLMAP sparse models (binary or text), read through pycolmap.

Every COLMAP camera model is accepted: ``SIMPLE_PINHOLE`` and ``PINHOLE`` are used
as they are, any other model is undistorted to a pinhole camera
(:class:`~tsplus_wgpu.data.undistort.ColmapUndistorter`).
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from ..types import Camera
from .errors import SceneError
from .scene import FrameSpec, check_pose
from .undistort import ColmapUndistorter

PINHOLE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE")
MODEL_FILES = ("cameras", "images", "points3D")


def _pycolmap():
    try:
        import pycolmap  # noqa: PLC0415
    except ImportError:  # pragma: no cover
        raise SceneError("pycolmap is missing: install it with `pip install pycolmap`") from None
    return pycolmap


def find_model_dir(root: Path):
    """The folder holding ``cameras/images/points3D`` (.bin or .txt): ``sparse/0``, ``sparse`` or ``root``."""
    for cand in (root / "sparse" / "0", root / "sparse", root):
        for ext in (".bin", ".txt"):
            if (cand / f"cameras{ext}").is_file() or (cand / f"images{ext}").is_file():
                return cand
    return None


def _known_models():
    pycolmap = _pycolmap()
    return {k for k in pycolmap.CameraModelId.__members__ if k != "INVALID"}, \
        {int(v): k for k, v in pycolmap.CameraModelId.__members__.items() if k != "INVALID"}


def _precheck(model_dir: Path):
    """Raise a clear SceneError for missing files and unknown camera models before pycolmap sees them."""
    ext = ".bin" if (model_dir / "cameras.bin").is_file() else ".txt"
    for stem in MODEL_FILES:
        f = model_dir / f"{stem}{ext}"
        if not f.is_file():
            raise SceneError(f"{f}: missing from the COLMAP model; export the complete model "
                             "(cameras, images, points3D) again")
    names, ids = _known_models()
    if ext == ".txt":
        _precheck_images_txt(model_dir / "images.txt")
    cam_file = model_dir / f"cameras{ext}"
    if ext == ".txt":
        for ln, line in enumerate(cam_file.read_text(errors="replace").splitlines(), 1):
            parts = line.split()
            if not parts or parts[0].startswith("#"):
                continue
            if len(parts) < 4:
                raise SceneError(f"{cam_file}:{ln}: malformed camera line; expected "
                                 "'CAMERA_ID MODEL WIDTH HEIGHT PARAMS...'")
            if parts[1] not in names:
                raise SceneError(f"{cam_file}:{ln}: unknown camera model {parts[1]!r}; use one of "
                                 f"{', '.join(sorted(names))}")
    else:
        data = cam_file.read_bytes()
        if len(data) >= 8 + 24:
            n = struct.unpack_from("<Q", data, 0)[0]
            if n:
                _, model_id = struct.unpack_from("<ii", data, 8)
                if model_id not in ids:
                    raise SceneError(f"{cam_file}: unknown camera model id {model_id}; "
                                     "re-export the model with a current COLMAP")


def _precheck_images_txt(img_file: Path):
    """COLMAP cannot parse 'nan'/'inf' in images.txt: report the image and line instead."""
    lines = [ln for ln in img_file.read_text(errors="replace").splitlines() if not ln.startswith("#")]
    nums = img_file.read_text(errors="replace").splitlines()
    k = 0
    physical = [i for i, ln in enumerate(nums, 1) if not ln.startswith("#")]
    while k < len(lines):
        parts = lines[k].split()
        if parts:
            name = parts[9] if len(parts) > 9 else "?"
            try:
                vals = [float(v) for v in parts[1:8]]
            except ValueError:
                raise SceneError(f"{img_file}:{physical[k]} (image {name!r}): malformed pose; expected "
                                 "'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME'") from None
            if len(vals) < 7 or not all(np.isfinite(vals)):
                raise SceneError(f"{img_file}:{physical[k]} (image {name!r}): pose contains non-finite values "
                                 "(NaN or Inf); fix or remove this image from the model")
            k += 2  # skip the POINTS2D line
        else:
            k += 1


def read_model(model_dir: Path):
    """Read a COLMAP model with pycolmap, turning its failures into SceneError."""
    pycolmap = _pycolmap()
    _precheck(model_dir)
    try:
        rec = pycolmap.Reconstruction(str(model_dir))
    except Exception as exc:  # pycolmap raises ValueError/RuntimeError with C++ messages
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise SceneError(f"{model_dir}: cannot read the COLMAP model ({msg}); re-export it from COLMAP") from None
    return rec


def colmap_frames(root: Path, model_dir: Path, image_dir: Path, warnings: list):
    """FrameSpecs (sorted by image name), SfM points and colours of a COLMAP model.

    Returns:
        ``(frames, points [P,3] or None, colors [P,3] or None, models Counter, rec)``.
    """
    rec = read_model(model_dir)
    ext = ".bin" if (model_dir / "images.bin").is_file() else ".txt"
    img_file = model_dir / f"images{ext}"
    reg = [im for im in rec.images.values() if im.has_pose]
    if not reg:
        raise SceneError(f"{img_file}: the model has no registered images; re-run COLMAP mapping "
                         "(or give the photos alone to run SfM here)")
    if len(reg) < len(rec.images):
        warnings.append(f"{len(rec.images) - len(reg)} image(s) in {img_file.name} have no pose and are ignored")
    frames, models = [], {}
    undistorters = {}
    for im in sorted(reg, key=lambda x: x.name):
        cam = rec.cameras[im.camera_id]
        where = f"{img_file} (image {im.name!r})"
        m = np.eye(4)
        m[:3, :4] = np.asarray(im.cam_from_world().matrix(), np.float64)
        check_pose(m, where)
        model = cam.model_name if hasattr(cam, "model_name") else str(cam.model).split(".")[-1]
        models[model] = models.get(model, 0) + 1
        K = np.asarray(cam.calibration_matrix(), np.float64)
        if not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
            raise SceneError(f"{model_dir / ('cameras' + ext)} (camera {im.camera_id}): invalid intrinsics "
                             f"{list(cam.params)}; fix the camera")
        try:
            pin = Camera(cam.width, cam.height, K[0, 0], K[1, 1], K[0, 2], K[1, 2], m)
        except ValueError as exc:
            raise SceneError(f"{where}: {exc}") from None
        und = None
        if model not in PINHOLE_MODELS:
            if im.camera_id not in undistorters:
                undistorters[im.camera_id] = ColmapUndistorter(cam, source=str(model_dir / f"cameras{ext}"))
            und = undistorters[im.camera_id]
        frames.append(FrameSpec(name=im.name, path=image_dir / im.name, camera=pin, group=im.camera_id,
                                undistort=und, source=f"{model_dir / ('cameras' + ext)} camera {im.camera_id}",
                                model=model))
    pts = rec.points3D
    if len(pts) == 0:
        warnings.append(f"{model_dir / ('points3D' + ext)} has no points: initial points are made from the "
                        "known poses instead")
        return frames, None, None, models, rec
    xyz = np.array([p.xyz for p in pts.values()], np.float64)
    rgb = np.array([p.color for p in pts.values()], np.float64) / 255.0
    ok = np.all(np.isfinite(xyz), axis=1)
    if not np.all(ok):
        warnings.append(f"dropped {int((~ok).sum())} non-finite point(s) from {model_dir / ('points3D' + ext)}")
        xyz, rgb = xyz[ok], rgb[ok]
    return frames, xyz, rgb, models, rec
