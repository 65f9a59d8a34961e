"""Checks of a COLMAP model's files before pycolmap reads them.

pycolmap trusts the counts in a binary model (a truncated ``points3D.bin`` makes it allocate
gigabytes before failing) and reports malformed text files as ``Check failed: ...`` without
naming the file or line.  These readers walk the files themselves, without allocating per
record, and raise a one-line :class:`SceneError` naming the file (and the line, or the
record) and what is wrong.

Binary layout (COLMAP, little endian): every file starts with its record count (uint64).

* ``cameras.bin``: ``camera_id u32, model_id i32, width u64, height u64, params f64 x n(model)``.
* ``images.bin``: ``image_id u32, qvec f64 x4, tvec f64 x3, camera_id u32, name (NUL-terminated),
  num_points2D u64, (x f64, y f64, point3D_id u64) x num_points2D``.
* ``points3D.bin``: ``point3D_id u64, xyz f64 x3, rgb u8 x3, error f64, track_length u64,
  (image_id u32, point2D_idx u32) x track_length``.
"""

from __future__ import annotations

import math
import struct
from pathlib import Path

from .errors import SceneError
from .plausible import MAX_COORD, MAX_DISTORTION, MAX_IMAGE_SIDE

MODEL_FILES = ("cameras", "images", "points3D")
# models that are no perspective projection: no pinhole image can be made from them
NON_PERSPECTIVE = {"EQUIRECTANGULAR"}
_CAM_HEAD = struct.Struct("<IiQQ")
_IMG_HEAD = struct.Struct("<I7dI")
_PT_HEAD = struct.Struct("<Q3d3BdQ")


def model_table() -> dict:
    """Every COLMAP camera model pycolmap knows: ``name -> (model id, number of parameters,
    indices of the distortion parameters)``."""
    from .long_calls import import_pycolmap  # noqa: PLC0415
    pycolmap = import_pycolmap()
    table = {}
    for name, mid in pycolmap.CameraModelId.__members__.items():
        if name == "INVALID":
            continue
        try:
            cam = pycolmap.Camera.create_from_model_name(1, name, 1.0, 2, 2)
        except Exception:  # pragma: no cover - a model pycolmap lists but cannot build
            continue
        extra = () if name in NON_PERSPECTIVE else tuple(int(i) for i in cam.extra_params_idxs())
        table[name] = (int(mid), len(cam.params), extra)
    return table


def _model_error(path, where, model, cam_id):
    if model in NON_PERSPECTIVE:
        return SceneError(f"{path}{where}: camera {cam_id} uses the {model} model, which is not a perspective camera "
                          "and cannot be turned into pinhole images; convert the panoramas to perspective views "
                          "(e.g. cube-map faces) and run COLMAP on those")
    return None


def _check_camera_values(path, where, cam_id, model, width, height, params, extra=()):
    bad = _model_error(path, where, model, cam_id)
    if bad is not None:
        raise bad
    for name, v in (("width", width), ("height", height)):
        if not 1 <= v <= MAX_IMAGE_SIDE:
            raise SceneError(f"{path}{where}: camera {cam_id} has {name} {v}, expected 1..{MAX_IMAGE_SIDE} pixels; "
                             "fix the camera")
    if not all(math.isfinite(p) for p in params):
        raise SceneError(f"{path}{where}: camera {cam_id} ({model}) has non-finite parameters {list(params)}; "
                         "fix the camera")
    for i in extra:
        if abs(params[i]) > MAX_DISTORTION:
            raise SceneError(f"{path}{where}: camera {cam_id} ({model}) has distortion parameter {params[i]:g} "
                             f"(parameter {i + 1} of {len(params)}), implausible for a real lens "
                             f"(|k| <= {MAX_DISTORTION:g}); fix the calibration")


def _check_pose_values(path, where, name, q, t):
    if not all(math.isfinite(v) for v in (*q, *t)):
        raise SceneError(f"{path}{where} (image {name!r}): pose contains non-finite values (NaN or Inf); "
                         "fix or remove this image from the model")
    if math.sqrt(sum(v * v for v in q)) < 1e-12:
        raise SceneError(f"{path}{where} (image {name!r}): the rotation quaternion is all zeros (no rotation); "
                         "fix or remove this image from the model")
    if max(abs(v) for v in t) > MAX_COORD:
        raise SceneError(f"{path}{where} (image {name!r}): translation {list(t)} is implausibly large "
                         f"(> {MAX_COORD:g}); fix or remove this image from the model")


def check_model(model_dir: Path) -> tuple:
    """Check the three files of the model in ``model_dir``.

    Returns:
        ``(extension, lines)``: ``.bin`` or ``.txt``, and the lines of ``points3D.txt`` whose
        coordinates are not finite (to leave out).
    """
    model_dir = Path(model_dir)
    ext = ".bin" if (model_dir / "cameras.bin").is_file() else ".txt"
    for stem in MODEL_FILES:
        f = model_dir / f"{stem}{ext}"
        if not f.is_file():
            raise SceneError(f"{f}: missing from the COLMAP model; export the complete model "
                             "(cameras, images, points3D) again")
    table = model_table()
    if ext == ".bin":
        cams = check_cameras_bin(model_dir / "cameras.bin", table)
        images = check_images_bin(model_dir / "images.bin", cams)
        _no_images(model_dir / "images.bin", images)
        check_points3d_bin(model_dir / "points3D.bin", images)
        return ext, []
    cams = check_cameras_txt(model_dir / "cameras.txt", table)
    images = check_images_txt(model_dir / "images.txt", cams)
    _no_images(model_dir / "images.txt", images)
    return ext, check_points3d_txt(model_dir / "points3D.txt", images)


def _no_images(path, images):
    if not images:
        raise SceneError(f"{path}: the model has no registered images; re-run COLMAP mapping "
                         "(or give the photos alone to run SfM here)")


# --------------------------------------------------------------------------- binary
def _read_count(path: Path, what: str):
    data = path.read_bytes()
    if len(data) < 8:
        raise SceneError(f"{path}: {len(data)} bytes, too short to hold the {what} count; the file is truncated, "
                         "export the model again")
    return data, struct.unpack_from("<Q", data, 0)[0]


def _truncated(path, n, what, k, size):
    return SceneError(f"{path}: declares {n} {what} but the file ends inside {what[:-1]} {k + 1} "
                      f"({size} bytes); the file is truncated or corrupt, export the model again")


def _trailing(path, n, what, pos, size):
    if pos != size:
        raise SceneError(f"{path}: {size - pos} unexpected bytes after the {n} {what} it declares; the file is "
                         "corrupt, export the model again")


def check_cameras_bin(path: Path, table: dict) -> dict:
    """Walk ``cameras.bin``; returns ``camera_id -> model name``."""
    data, n = _read_count(path, "camera")
    names = {mid: (name, k, extra) for name, (mid, k, extra) in table.items()}
    pos, cams = 8, {}
    for k in range(n):
        if pos + _CAM_HEAD.size > len(data):
            raise _truncated(path, n, "cameras", k, len(data))
        cam_id, model_id, width, height = _CAM_HEAD.unpack_from(data, pos)
        if model_id not in names:
            raise SceneError(f"{path}: camera {cam_id} has unknown camera model id {model_id}; re-export the model "
                             "with a current COLMAP")
        model, npar, extra = names[model_id]
        pos += _CAM_HEAD.size
        if pos + 8 * npar > len(data):
            raise _truncated(path, n, "cameras", k, len(data))
        params = struct.unpack_from(f"<{npar}d", data, pos)
        pos += 8 * npar
        _check_camera_values(path, "", cam_id, model, width, height, params, extra)
        cams[cam_id] = model
    _trailing(path, n, "cameras", pos, len(data))
    return cams


def check_images_bin(path: Path, cams: dict) -> dict:
    """Walk ``images.bin`` (counts, poses, camera ids); returns ``image id -> number of 2D points``."""
    data, n = _read_count(path, "images")
    pos, size, ids = 8, len(data), {}
    for k in range(n):
        if pos + _IMG_HEAD.size > size:
            raise _truncated(path, n, "images", k, size)
        vals = _IMG_HEAD.unpack_from(data, pos)
        image_id, q, t, cam_id = vals[0], vals[1:5], vals[5:8], vals[8]
        pos += _IMG_HEAD.size
        end = data.find(b"\0", pos)
        if end < 0:
            raise _truncated(path, n, "images", k, size)
        name = data[pos:end].decode("utf-8", "replace")
        pos = end + 1
        if pos + 8 > size:
            raise _truncated(path, n, "images", k, size)
        npts = struct.unpack_from("<Q", data, pos)[0]
        pos += 8
        if npts > (size - pos) // 24:
            raise SceneError(f"{path}: image {image_id} ({name!r}) declares {npts} 2D points but only "
                             f"{size - pos} bytes remain; the file is truncated or corrupt, export the model again")
        pos += 24 * npts
        _check_pose_values(path, "", name, q, t)
        if cam_id not in cams:
            raise SceneError(f"{path}: image {image_id} ({name!r}) refers to camera {cam_id}, which cameras.bin "
                             "does not define; export the model again")
        ids[image_id] = npts
    _trailing(path, n, "images", pos, size)
    return ids


def check_points3d_bin(path: Path, images: dict) -> int:
    """Walk ``points3D.bin`` (counts, track lengths, the images the tracks name); returns the number of points."""
    data, n = _read_count(path, "points")
    pos, size, head = 8, len(data), _PT_HEAD.size
    unpack = struct.Struct("<Q").unpack_from
    if n > (size - 8) // head:
        raise SceneError(f"{path}: declares {n} points but its {size} bytes hold at most {(size - 8) // head}; "
                         "the file is truncated or corrupt, export the model again")
    starts, lengths = [], []
    for k in range(n):
        if pos + head > size:
            raise _truncated(path, n, "points", k, size)
        track = unpack(data, pos + head - 8)[0]
        pos += head
        if track > (size - pos) // 8:
            pid = unpack(data, pos - head)[0]
            raise SceneError(f"{path}: point {pid} declares a track of {track} observations but only "
                             f"{size - pos} bytes remain; the file is truncated or corrupt, export the model again")
        starts.append(pos)
        lengths.append(track)
        pos += 8 * track
    _trailing(path, n, "points", pos, size)
    _check_track_images_bin(path, data, starts, lengths, images)
    return n


def _check_track_images_bin(path, data, starts, lengths, images):
    """Every (image_id, point2D_idx) of every track names an image of images.bin."""
    import numpy as np  # noqa: PLC0415
    lengths = np.asarray(lengths, np.int64)
    total = int(lengths.sum())
    if total == 0:
        return
    first = np.repeat(np.asarray(starts, np.int64) - 8 * (np.cumsum(lengths) - lengths), lengths)
    offs = first + 8 * np.arange(total, dtype=np.int64)
    raw = np.frombuffer(data, np.uint8)

    def u32(o):
        return (raw[o].astype(np.int64) | raw[o + 1].astype(np.int64) << 8 | raw[o + 2].astype(np.int64) << 16
                | raw[o + 3].astype(np.int64) << 24)
    ids, idx = u32(offs), u32(offs + 4)
    known = np.array(sorted(images), np.int64)
    npts = np.array([images[i] for i in sorted(images)], np.int64)
    where = np.clip(np.searchsorted(known, ids), 0, len(known) - 1)
    bad = (known[where] != ids) | (idx >= npts[where])
    if np.any(bad):
        g = int(np.argmax(bad))
        k = int(np.searchsorted(np.cumsum(lengths), g, side="right"))
        img, i = int(ids[g]), int(idx[g])
        what = ("which images.bin does not define" if img not in images
                else f"2D point {i}, but that image has {images[img]} 2D points")
        raise SceneError(f"{path}: point {k + 1} of the file observes image {img}, {what}; export the model again")


# --------------------------------------------------------------------------- text
def _data_lines(path: Path):
    """``(line number, fields)`` of the lines that are not empty or comments."""
    try:
        text = path.read_text(errors="strict")
    except UnicodeDecodeError:
        raise SceneError(f"{path}: not a text file; export the model again (as text or binary)") from None
    for ln, line in enumerate(text.splitlines(), 1):
        s = line.strip()
        if s and not s.startswith("#"):
            yield ln, s.split()


def _nums(path, ln, fields, kinds, what):
    out = []
    for f, kind in zip(fields, kinds):
        try:
            v = int(f) if kind == "i" else float(f)
        except ValueError:
            v = None
        if v is None or not math.isfinite(v):
            raise SceneError(f"{path}:{ln}: {f!r} is not a finite number; expected {what}")
        out.append(v)
    return out


def check_cameras_txt(path: Path, table: dict) -> dict:
    """Check ``cameras.txt`` line by line; returns ``camera_id -> model name``."""
    cams = {}
    what = "'CAMERA_ID MODEL WIDTH HEIGHT PARAMS...'"
    for ln, parts in _data_lines(path):
        if len(parts) < 4:
            raise SceneError(f"{path}:{ln}: malformed camera line; expected {what}")
        model = parts[1]
        if model not in table:
            raise SceneError(f"{path}:{ln}: unknown camera model {model!r}; use one of {', '.join(sorted(table))}")
        cam_id, width, height = _nums(path, ln, [parts[0], parts[2], parts[3]], "iii", what)
        _, npar, extra = table[model]
        if len(parts) - 4 != npar:
            raise SceneError(f"{path}:{ln}: camera {cam_id} ({model}) has {len(parts) - 4} parameters, the model "
                             f"takes {npar}; fix the line")
        params = _nums(path, ln, parts[4:], "f" * npar, what)
        _check_camera_values(path, f":{ln}", cam_id, model, width, height, params, extra)
        cams[cam_id] = model
    return cams


def check_images_txt(path: Path, cams: dict) -> dict:
    """Check ``images.txt``: each image line (pose, camera id) and its POINTS2D line; returns
    ``image id -> number of 2D points``."""
    what = "'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME'"
    lines = list(_raw_lines(path))
    k, ids = 0, {}
    while k < len(lines):
        ln, s = lines[k]
        if not s or s.startswith("#"):
            k += 1
            continue
        parts = s.split()
        name = parts[9] if len(parts) > 9 else "?"
        if len(parts) < 10:
            raise SceneError(f"{path}:{ln} (image {name!r}): malformed image line with {len(parts)} fields; "
                             f"expected {what}")
        try:
            vals = [float(v) for v in parts[1:8]]
            image_id = int(parts[0])
            cam_id = int(parts[8])
        except ValueError:
            raise SceneError(f"{path}:{ln} (image {name!r}): malformed pose; expected {what}") from None
        _check_pose_values(path, f":{ln}", name, vals[:4], vals[4:])
        if cam_id not in cams:
            raise SceneError(f"{path}:{ln} (image {name!r}): camera {cam_id} is not defined in cameras.txt; "
                             "fix the camera id or export the model again")
        pts = []
        if k + 1 < len(lines):
            pln, pts = lines[k + 1][0], lines[k + 1][1].split()
            if len(pts) % 3:
                raise SceneError(f"{path}:{pln} (image {name!r}): the POINTS2D line has {len(pts)} values, "
                                 "expected triples 'X Y POINT3D_ID'; the file is truncated or corrupt")
            _nums(path, pln, pts, "ffi" * (len(pts) // 3), "triples 'X Y POINT3D_ID'")
        k += 2
        ids[image_id] = len(pts) // 3
    return ids


def _raw_lines(path: Path):
    try:
        text = path.read_text(errors="strict")
    except UnicodeDecodeError:
        raise SceneError(f"{path}: not a text file; export the model again (as text or binary)") from None
    for ln, line in enumerate(text.splitlines(), 1):
        yield ln, line.strip()


def check_points3d_txt(path: Path, images: dict) -> list:
    """Check ``points3D.txt`` line by line (field counts, numbers, colours, track pairs naming
    images of images.txt).

    Returns:
        the line numbers of points with non-finite coordinates (pycolmap cannot read them:
        :func:`read_model` leaves them out, with a warning).
    """
    what = "'POINT3D_ID X Y Z R G B ERROR TRACK[] as (IMAGE_ID, POINT2D_IDX)'"
    bad = []
    for ln, parts in _data_lines(path):
        if len(parts) < 8 or (len(parts) - 8) % 2:
            raise SceneError(f"{path}:{ln}: malformed point line with {len(parts)} fields; expected {what}; "
                             "the file is truncated or corrupt")
        try:
            xyz = [float(v) for v in parts[1:4]]
        except ValueError:
            xyz = [0.0]
            _nums(path, ln, parts[1:4], "fff", what)
        if not all(math.isfinite(v) for v in xyz):
            bad.append(ln)
            parts = parts[:1] + ["0", "0", "0"] + parts[4:]
        vals = _nums(path, ln, parts, "ifffiiif" + "i" * (len(parts) - 8), what)
        if not all(0 <= c <= 255 for c in vals[4:7]):
            raise SceneError(f"{path}:{ln}: point {vals[0]} has colour {vals[4:7]}, expected 0..255 per channel")
        for image_id, idx in zip(vals[8::2], vals[9::2]):
            if image_id not in images or not 0 <= idx < images[image_id]:
                what = ("which images.txt does not define" if image_id not in images
                        else f"2D point {idx}, but that image has {images[image_id]} 2D points")
                raise SceneError(f"{path}:{ln}: point {vals[0]} observes image {image_id}, {what}; remove the "
                                 "observation or export the model again")
    return bad
