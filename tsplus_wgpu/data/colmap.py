"""COLMAP sparse models (binary or text), read through pycolmap.

Every COLMAP camera model is accepted: ``SIMPLE_PINHOLE`` and ``PINHOLE`` are used
as they are, any other model is undistorted to a pinhole camera
(:class:`~tsplus_wgpu.data.undistort.ColmapUndistorter`).
"""

from __future__ import annotations

import re
import shutil
import tempfile
from pathlib import Path

import numpy as np

from ..types import Camera
from .colmap_check import MODEL_FILES, check_model
from .errors import SceneError
from .long_calls import import_pycolmap
from .plausible import MAX_COORD, MAX_DISTORTION, check_focal
from .scene import FrameSpec, check_pose
from .tracks import of_pycolmap_points
from .undistort import ColmapUndistorter

PINHOLE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE")
__all__ = ["MODEL_FILES", "PINHOLE_MODELS", "colmap_frames", "colmap_tracks", "find_model_dir", "read_model"]


def find_model_dir(root: Path):
    """The folder holding ``cameras/images/points3D`` (.bin or .txt): ``sparse/0``, ``sparse`` or ``root``."""
    for cand in (root / "sparse" / "0", root / "sparse", root):
        for ext in (".bin", ".txt"):
            if (cand / f"cameras{ext}").is_file() or (cand / f"images{ext}").is_file():
                return cand
    return None


def read_model(model_dir: Path, warnings=None):
    """Read a COLMAP model with pycolmap after checking its files (:mod:`.colmap_check`),
    turning every failure into a one-line SceneError; points with non-finite coordinates in
    ``points3D.txt`` are left out with a warning."""
    pycolmap = import_pycolmap()
    model_dir = Path(model_dir)
    _, bad_lines = check_model(model_dir)
    src, tmp = model_dir, None
    if bad_lines:
        tmp = Path(tempfile.mkdtemp(prefix="tsplus-colmap-"))
        for f in model_dir.iterdir():
            if f.is_file() and f.name != "points3D.txt":
                shutil.copyfile(f, tmp / f.name)
        drop = set(bad_lines)
        lines = (model_dir / "points3D.txt").read_text().splitlines()
        (tmp / "points3D.txt").write_text("\n".join(ln for k, ln in enumerate(lines, 1) if k not in drop) + "\n")
        if warnings is not None:
            warnings.append(f"dropped {len(drop)} non-finite point(s) from {model_dir / 'points3D.txt'} (line "
                            f"{', '.join(map(str, bad_lines[:5]))}{' ...' if len(bad_lines) > 5 else ''})")
        src = tmp
    try:
        rec = pycolmap.Reconstruction(str(src))
    except Exception as exc:  # pycolmap raises ValueError/RuntimeError with C++ messages
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        msg = re.sub(r"^\[[^\]]*\]\s*", "", msg).replace("Check failed: ", "")
        raise SceneError(f"{model_dir}: pycolmap cannot read this COLMAP model (it rejects: {msg}); "
                         "export the model again from COLMAP") from None
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    return rec


def colmap_frames(root: Path, model_dir: Path, image_dir: Path, warnings: list):
    """FrameSpecs (sorted by image name), SfM points and colours of a COLMAP model.

    Returns:
        ``(frames, points [P,3] or None, colors [P,3] or None, models Counter, rec)``; the
        points' tracks come from :func:`colmap_tracks`.
    """
    rec = read_model(model_dir, warnings)
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
        check_focal(K[0, 0], cam.width, f"{model_dir / ('cameras' + ext)} (camera {im.camera_id})", "focal length")
        try:
            pin = Camera(cam.width, cam.height, K[0, 0], K[1, 1], K[0, 2], K[1, 2], m)
        except ValueError as exc:
            raise SceneError(f"{where}: {exc}") from None
        und = None
        if model not in PINHOLE_MODELS:
            if im.camera_id not in undistorters:
                _check_distortion(pycolmap_cam=cam, model=model, cam_id=im.camera_id,
                                  where=str(model_dir / f"cameras{ext}"))
                undistorters[im.camera_id] = ColmapUndistorter(cam, source=str(model_dir / f"cameras{ext}"))
            und = undistorters[im.camera_id]
        frames.append(FrameSpec(name=im.name, path=image_dir / im.name, camera=pin, group=im.camera_id,
                                undistort=und, source=f"{model_dir / ('cameras' + ext)} camera {im.camera_id}",
                                model=model))
    xyz, rgb, _, bad, far = _usable_points(rec)
    if bad + far + len(xyz) == 0:
        warnings.append(f"{model_dir / ('points3D' + ext)} has no points: initial points are made from the "
                        "known poses instead")
        return frames, None, None, models, rec
    if bad:
        warnings.append(f"dropped {bad} non-finite point(s) from {model_dir / ('points3D' + ext)}")
    if far:
        warnings.append(f"dropped {far} point(s) beyond {MAX_COORD:g} units from "
                        f"{model_dir / ('points3D' + ext)}")
    if len(xyz) == 0:
        warnings.append(f"{model_dir / ('points3D' + ext)} has no usable points: initial points are made from the "
                        "known poses instead")
        return frames, None, None, models, rec
    return frames, xyz, rgb, models, rec


def _usable_points(rec):
    """The points of ``rec`` that :func:`colmap_frames` keeps (finite, within ``MAX_COORD``), in
    its order: ``(xyz [P,3], rgb [P,3] in [0,1], point ids [P], non-finite count, far count)``."""
    items = list(rec.points3D.items())
    ids = np.array([k for k, _ in items], np.int64)
    xyz = np.array([p.xyz for _, p in items], np.float64).reshape(-1, 3)
    rgb = np.array([p.color for _, p in items], np.float64).reshape(-1, 3) / 255.0
    finite = np.all(np.isfinite(xyz), axis=1)
    with np.errstate(invalid="ignore"):
        far = finite & np.any(np.abs(xyz) > MAX_COORD, axis=1)
    ok = finite & ~far
    return xyz[ok], rgb[ok], ids[ok], int((~finite).sum()), int(far.sum())


def colmap_tracks(rec, names):
    """The track table (:mod:`.tracks`) of the points :func:`colmap_frames` returns for ``rec``,
    in the same order, or None when it returns none.

    Each observation's image becomes the index of its name in ``names`` (the scene's
    ``image_names``); observations of images not in ``names`` (unposed, skipped, not loaded)
    are dropped, and an image seeing a point twice counts once (views ascending per point).
    """
    ids = _usable_points(rec)[2]
    if len(ids) == 0:
        return None
    pts = rec.points3D
    return of_pycolmap_points(rec, [pts[pid] for pid in ids.tolist()], {n: i for i, n in enumerate(names)})


def _check_distortion(pycolmap_cam, model, cam_id, where):
    """The distortion parameters of a non-pinhole camera are plausible, and undistorting keeps most of the image."""
    pycolmap = import_pycolmap()
    params = list(pycolmap_cam.params)
    for i in pycolmap_cam.extra_params_idxs():
        if not abs(params[i]) <= MAX_DISTORTION:
            raise SceneError(f"{where}: camera {cam_id} ({model}) has distortion parameter {params[i]:g} (parameter "
                             f"{i + 1} of {len(params)}), implausible for a real lens (|k| <= {MAX_DISTORTION:g}); "
                             "fix the calibration")
    try:
        ucam = pycolmap.undistort_camera(pycolmap.UndistortCameraOptions(), pycolmap_cam)
    except Exception as exc:
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise SceneError(f"{where}: camera {cam_id} ({model}) cannot be undistorted to a pinhole camera ({msg}); "
                         "use a perspective camera model") from None
    w, h = pycolmap_cam.width, pycolmap_cam.height
    if ucam.width * 4 < w or ucam.height * 4 < h:
        extra = [float(params[i]) for i in pycolmap_cam.extra_params_idxs()]
        raise SceneError(f"{where}: camera {cam_id} ({model}): its distortion parameters {extra} "
                         f"leave a {ucam.width}x{ucam.height} undistorted image of {w}x{h}; fix the calibration")
