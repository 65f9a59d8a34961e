"""``load_scene``: detect a capture's format and load it into a :class:`Scene`."""

from __future__ import annotations

import re
from collections import Counter
from dataclasses import replace
from functools import partial
from pathlib import Path

import numpy as np

from .errors import SceneError
from .images import list_images
from .plausible import check_train_size
from .posed_points import initial_points, most_points
from .scene import Scene, downscaled_size, load_frames, make_split, select_frames
from .tracks import subset

FORMATS = ("colmap", "transforms", "nerf-synthetic", "llff", "photos", "video", "procedural")


def _parse_background(background, default):
    if background is None:
        return tuple(float(v) for v in default)
    if isinstance(background, str):
        named = {"white": (1.0, 1.0, 1.0), "black": (0.0, 0.0, 0.0), "grey": (0.5, 0.5, 0.5),
                 "gray": (0.5, 0.5, 0.5)}
        if background.lower() in named:
            return named[background.lower()]
        try:
            parts = [float(x) for x in background.replace(",", " ").split()]
        except ValueError:
            raise SceneError(f"background {background!r}: expected 'white', 'black' or three numbers in [0, 1]") from None
        background = parts
    arr = np.atleast_1d(np.asarray(background, np.float64))
    if arr.size == 1:
        arr = np.repeat(arr, 3)
    if arr.size != 3 or not np.all(np.isfinite(arr)) or arr.min() < 0 or arr.max() > 1:
        raise SceneError(f"background {background!r}: expected three numbers in [0, 1]")
    return tuple(float(v) for v in arr)


def _image_folders(root: Path) -> dict:
    """``{N: folder}`` of the scene's image folders that hold images: 1 for ``images/``, N for ``images_N/``."""
    out = {}
    if list_images(root / "images"):
        out[1] = root / "images"
    for d in sorted(root.iterdir()) if root.is_dir() else ():
        m = re.fullmatch(r"images_(\d+)", d.name)
        if m and int(m.group(1)) >= 1 and d.is_dir() and list_images(d):
            out.setdefault(int(m.group(1)), d)
    return out


def _image_dir(root: Path, images, downscale):
    """``(folder, downscale still to apply, why this folder)``: ``--images`` when given; else
    ``images_N`` when ``downscale`` is N and it exists; else ``images/``; else (only ``images_N/``
    folders) the one with the largest N not above ``downscale``, or the largest images."""
    downscale = float(downscale)
    if images is not None:
        d = Path(images) if Path(images).is_absolute() else root / images
        if not d.is_dir():
            raise SceneError(f"{d}: image folder not found; pass an existing folder name with --images")
        return d, downscale, "as --images asks"
    folders = _image_folders(root)
    if downscale > 1 and downscale.is_integer() and int(downscale) in folders:
        n = int(downscale)
        return folders[n], 1.0, f"holds the images at 1/{n} size, as --downscale {n} asks"
    if 1 in folders or not folders:
        return root / "images", downscale, ""
    gone = "images/ is missing" + (" its images" if (root / "images").is_dir() else "")
    fit = [n for n in folders if n <= downscale]
    if fit:
        n = max(fit)
        rest = downscale / n
        return folders[n], rest, (f"{gone}; images_{n} holds the images at 1/{n} size"
                                  + (f", shrunk {rest:g}x more for --downscale {downscale:g}" if rest != 1 else ""))
    n = min(folders)
    return folders[n], 1.0, (f"{gone}; images_{n} is the largest available (1/{n} size)"
                             + (f", smaller than --downscale {downscale:g} asks" if downscale != 1 else ""))


def _folder_factor(image_dir: Path) -> float:
    m = re.fullmatch(r"images_(\d+)", Path(image_dir).name)
    return float(m.group(1)) if m else 1.0


def detect_format(path) -> str:
    """Name the format of a scene folder (see :data:`FORMATS`) without loading it."""
    from .colmap import find_model_dir  # noqa: PLC0415
    from .transforms import find_transforms  # noqa: PLC0415
    from .video import is_frames_folder, is_video  # noqa: PLC0415
    if path is None or str(path).split(":")[0] == "procedural":
        return "procedural"
    root = Path(path)
    if root.is_file() and is_video(root):
        return "video"
    if root.is_file():
        root = root.parent
    if find_model_dir(root) is not None:
        return "colmap"
    files, variant = find_transforms(root)
    if files:
        return variant
    if (root / "poses_bounds.npy").is_file():
        return "llff"
    if _has_photos(root / "images") or _has_photos(root):
        return "video" if is_frames_folder(root / "images" if list_images(root / "images") else root) else "photos"
    raise _no_scene(root)


def load_scene(path=None, images=None, downscale=1, background=None, split="auto", *,
               frames=None, points="auto", on_bad_image="skip", cache_dir=None, progress=False,
               max_points=None, seed=0) -> Scene:
    """Load a scene, detecting its format.

    Args:
        path: scene folder (or its ``transforms.json`` / ``poses_bounds.npy``), a video (:mod:`.video`); ``None`` or
            ``"procedural"`` (optionally ``"procedural:tiny|small|demo"``) for the built-in scene.
        images: image folder name inside the scene (default ``images``, or ``images_N`` when
            ``downscale`` is N and that folder exists, or when ``images/`` is missing: see the summary).
        downscale: shrink images (and intrinsics) by this factor (>= 1).
        background: RGB in [0,1] (or ``"white"``/``"black"``) that alpha is composited on;
            default white for NeRF-synthetic (the evaluation protocol), black otherwise.
        split: ``"auto"``, ``"none"`` or ``"everyK"`` (see :func:`~tsplus_wgpu.data.scene.make_split`).
        frames: optional subset (indices in the format's order, or image names) to load;
            the split is computed on the full scene first, so held-out images stay held out.
        points: ``"auto"`` (SfM points, else triangulation from known poses, else frusta),
            ``"most"`` (the SfM points or the triangulated ones, whichever are more),
            ``"triangulate"``, ``"frusta"`` or ``"none"``.
        on_bad_image: ``"skip"`` (warn and skip missing/unreadable images) or ``"error"``.
        cache_dir: where SfM / triangulation results are cached (default ``$TSPLUS_CACHE``, else
            ``$XDG_CACHE_HOME/tsplus_wgpu``, default ``~/.cache/tsplus_wgpu``; never the scene folder).
        progress: show progress bars for long steps (SfM, triangulation, many images).
        max_points: randomly subsample the initial points to at most this many.
        seed: seed of the random choices (frusta points, subsampling).

    Returns:
        :class:`~tsplus_wgpu.data.scene.Scene`.

    Raises:
        SceneError: any problem with the user's data, as one line naming the file and the fix.
    """
    downscale = _check_options(points, on_bad_image, downscale)
    if path is None or str(path).split(":")[0] == "procedural":
        from .procedural import load_procedural  # noqa: PLC0415
        size = str(path).split(":", 1)[1] if path is not None and ":" in str(path) else "small"
        sc = load_procedural(size=size, seed=seed, split=split)
        if downscale != 1 or background is not None:
            sc.warnings.append("downscale/background are ignored for the procedural scene; pick a size instead")
        return sc

    warnings: list = []
    root = _scene_root(path, cache_dir, progress, warnings)
    fmt, frame_specs, rest, pts, cols, bounds, (image_dir, why), rec = _read_format(root, images, downscale,
                                                                                   cache_dir, progress, warnings)
    bg = _parse_background(background, (1.0, 1.0, 1.0) if fmt == "nerf-synthetic" else (0.0, 0.0, 0.0))
    is_test = [f.is_test for f in frame_specs]
    train_all, test_all, rule = make_split(len(frame_specs), split, is_test if fmt == "nerf-synthetic" else None)
    sel = select_frames(frame_specs, frames)
    chosen = [frame_specs[i] for i in sel]
    total = rest * (_folder_factor(image_dir) if image_dir is not None and images is None else 1.0)
    if chosen and downscale > 1:   # what the user asked, before reading any image
        c0 = chosen[0].camera
        check_train_size(*downscaled_size(c0.width, c0.height, downscale), (c0.width, c0.height), downscale,
                         chosen[0].source or str(chosen[0].path))
    cameras, imgs, kept, skipped = load_frames(chosen, rest, bg, on_bad_image, warnings, progress=progress)
    orig = [sel[k] for k in kept]
    train_set, test_set = set(train_all), set(test_all)
    train_idx = [j for j, o in enumerate(orig) if o in train_set]
    test_idx = [j for j, o in enumerate(orig) if o in test_set]
    names, models = [chosen[k].name for k in kept], dict(Counter(chosen[k].model for k in kept))
    left_out, held_off = [], []     # training / held-out views whose pose disagrees with their matches
    full = partial(_full_size_specs, fmt, root, images, [chosen[k] for k in kept], image_dir)   # when triangulating
    if points == "none":
        pts, cols, tracks, source = None, None, None, "none"
    elif pts is None or points in ("triangulate", "frusta"):
        pts, cols, source, tracks = initial_points(points, cameras, imgs, full(), bg, train_idx, bounds, cache_dir,
                                                   progress, seed, warnings, left_out, test_idx, held_off)
    else:
        from .colmap import colmap_tracks  # noqa: PLC0415
        tracks, source = colmap_tracks(rec, names), "sfm"
        if points == "most":
            pts, cols, tracks, source = most_points((pts, cols, tracks), full(), bg, train_idx, cache_dir, progress,
                                                    warnings, left_out, test_idx, held_off, reposed=cameras)
    train_idx, test_idx = [j for j in train_idx if j not in left_out], [j for j in test_idx if j not in held_off]
    pts, cols, tracks = _subsample(pts, cols, tracks, max_points, seed)
    return Scene(format=fmt, cameras=cameras, images=imgs, image_names=names, points=pts, point_colors=cols,
                 point_tracks=tracks, points_source=source, train_indices=train_idx, test_indices=test_idx,
                 warnings=warnings, root=str(root), background=bg, skipped=skipped, camera_models=models,
                 split_rule=rule, image_dir=image_dir and str(image_dir), image_dir_reason=why, downscale=total)


def _subsample(pts, cols, tracks, max_points, seed):
    """At most ``max_points`` of the initial points (a random subset, in their order), with their
    colours and tracks."""
    if pts is None or max_points is None or len(pts) <= int(max_points):
        return pts, cols, tracks
    keep = np.sort(np.random.default_rng(seed).choice(len(pts), int(max_points), replace=False))
    return pts[keep], cols[keep], None if tracks is None else subset(tracks, keep)


def _check_options(points, on_bad_image, downscale):
    """Check :func:`load_scene`'s options; returns ``downscale`` as a float."""
    if points not in ("auto", "most", "triangulate", "frusta", "none"):
        raise SceneError(f"points {points!r}: expected 'auto', 'most', 'triangulate', 'frusta' or 'none'")
    if on_bad_image not in ("skip", "error"):
        raise SceneError(f"on_bad_image {on_bad_image!r}: expected 'skip' or 'error'")
    try:
        downscale = float(downscale)
    except (TypeError, ValueError):
        raise SceneError(f"downscale {downscale!r}: expected a number >= 1") from None
    if not np.isfinite(downscale) or downscale < 1:
        raise SceneError(f"downscale {downscale!r}: expected a number >= 1")
    return downscale


def _scene_root(path, cache_dir=None, progress=False, warnings=None) -> Path:
    """The scene folder ``path`` names (a folder, or its transforms .json / poses_bounds.npy; for
    a video file, the folder of its frames in the cache, extracted on the first call)."""
    from .video import is_video, video_frames_dir  # noqa: PLC0415
    root = Path(path).expanduser()
    if not root.exists():
        raise SceneError(f"{root}: no such file or folder; check the path")
    if root.is_file() and is_video(root):
        return video_frames_dir(root, cache=cache_dir, progress=progress, warnings=warnings)
    if root.is_file():
        if root.name.endswith(".json") or root.name == "poses_bounds.npy":
            root = root.parent
        else:
            raise SceneError(f"{root}: not a scene folder or a video; pass the folder holding the images and cameras, "
                             "or a video file (.mp4, .mov, ...)")
    if not root.is_dir():
        raise SceneError(f"{root}: not a folder; pass the scene folder")
    return root


def _no_scene(root: Path) -> SceneError:
    """The error for a folder with no scene in it, pointing at what it does hold: a video, scene
    folders or folders of photos (a phone's ``DCIM/100APPLE``) at most two levels down (200
    folders looked at; unreadable ones skipped)."""
    from .video import is_video  # noqa: PLC0415
    base = (f"{root}: no photos and no camera model in it (expected photos, COLMAP sparse/, transforms.json or "
            "poses_bounds.npy)")
    videos = sorted(p.name for p in _entries(root) if p.is_file() and is_video(p) and not p.name.startswith("."))
    found, budget = [], [200]
    for d in _subfolders(root, budget):
        what = _what_is(d)
        found += [(d, what)] if what else [(q, w) for q in _subfolders(d, budget) for w in [_what_is(q)] if w]
    hints = [f"it holds a video: pass the video file itself ({root / videos[0]})"] if videos else []
    if len(found) == 1:
        hints.append(f"its subfolder {found[0][0].relative_to(root)} holds {found[0][1]}: pass {found[0][0]}")
    elif found:
        listed = ", ".join(f"{d.relative_to(root)} ({w})" for d, w in found[:4]) + (", ..." if len(found) > 4 else "")
        hints.append(f"its subfolders hold {listed}: pass the one of this scene, or put the scene's photos "
                     "into one folder")
    return SceneError(f"{base}; " + ("; or ".join(hints) if hints else "point to a scene folder"))


def _entries(folder: Path) -> list:
    try:
        return list(folder.iterdir())
    except OSError:
        return []


def _subfolders(folder: Path, budget: list) -> list:
    """Visible subfolders of ``folder`` (sorted), while ``budget[0]`` lasts (it counts them down)."""
    out = []
    for p in sorted(_entries(folder), key=lambda q: q.name):
        if budget[0] <= 0:
            break
        try:
            if p.name.startswith(".") or not p.is_dir():
                continue
        except OSError:
            continue
        budget[0] -= 1
        out.append(p)
    return out


def _what_is(folder: Path):
    """What a folder holds for ``_no_scene``: "a scene", "N photos", or None."""
    from .colmap import find_model_dir  # noqa: PLC0415
    from .transforms import find_transforms  # noqa: PLC0415
    try:
        if (find_model_dir(folder) is not None or find_transforms(folder)[0]
                or (folder / "poses_bounds.npy").is_file() or _has_photos(folder / "images")):
            return "a scene"
        n = _count_photos(folder)
    except (OSError, SceneError):
        return None
    return None if not n else f"{n} photo" + ("s" if n > 1 else "")


def _count_photos(folder: Path) -> int:
    from .heif import heif_names  # noqa: PLC0415
    return len(list_images(folder)) + len(heif_names(folder))


def _has_photos(folder: Path) -> bool:
    """Whether ``folder`` holds photos OpenCV reads or HEIC/HEIF photos."""
    return _count_photos(folder) > 0


def _read_format(root, images, downscale, cache_dir, progress, warnings):
    """Detect the format of ``root`` and read its frames: ``(format, frame specs, remaining
    downscale, SfM points or None, their colours, LLFF depth bounds or None, (image folder or
    None, why that folder), the pycolmap Reconstruction of a COLMAP model or None)``; a folder
    of photos runs SfM (cached) first."""
    from .colmap import colmap_frames, find_model_dir  # noqa: PLC0415
    from .llff import llff_frames  # noqa: PLC0415
    from .photos import photo_names, run_photos_sfm  # noqa: PLC0415
    from .transforms import find_transforms, transforms_frames  # noqa: PLC0415
    pts = cols = bounds = image_dir = rec = None
    why = ""
    model_dir = find_model_dir(root)
    t_files, t_variant = find_transforms(root)
    if model_dir is not None:
        fmt = "colmap"
        image_dir, rest, why = _image_dir(root, images, downscale)
        if not image_dir.is_dir():
            raise SceneError(f"{image_dir}: image folder of the COLMAP model not found; put the images there "
                             "or pass --images FOLDER")
        frame_specs, pts, cols, _, rec = colmap_frames(root, model_dir, image_dir, warnings)
    elif t_files:
        fmt = t_variant
        rest = downscale
        frame_specs, _ = transforms_frames(root, t_files, t_variant, warnings)
    elif (root / "poses_bounds.npy").is_file():
        fmt = "llff"
        image_dir, rest, why = _image_dir(root, images, downscale)
        frame_specs, bounds = llff_frames(root, image_dir, warnings)
    else:
        photo_dir = root / images if images is not None else (root / "images" if _has_photos(root / "images") else root)
        from .heif import heif_names, jpeg_folder  # noqa: PLC0415
        shown = photo_dir
        if heif_names(photo_dir):           # HEIC photos (an iPhone's): read from JPEG copies in the cache
            photo_dir = jpeg_folder(photo_dir, cache_dir, progress, warnings)
            why = "HEIC/HEIF photos converted to JPEG in the cache"
        names = photo_names(photo_dir) if photo_dir.is_dir() else []
        if not names:
            if not any(root.iterdir()):
                raise SceneError(f"{root}: the folder is empty; put photos (or a COLMAP / transforms.json / "
                                 "LLFF scene) in it")
            raise _no_scene(root)
        from .video import is_frames_folder, read_manifest  # noqa: PLC0415
        fmt = "video" if is_frames_folder(photo_dir) else "photos"
        image_dir = photo_dir
        if fmt == "video":
            m = read_manifest(photo_dir)
            why = (f"the sharpest frame of each of {len(m.get('frames', names))} windows of the "
                   f"{m.get('frames_decoded', '?')} frames of {Path(m.get('video', '?')).name}")
        model_dir = run_photos_sfm(photo_dir, names, cache=cache_dir, progress=progress, warnings=warnings,
                                   sequential=fmt == "video", shown=shown)
        rest = downscale
        frame_specs, pts, cols, _, rec = colmap_frames(root, model_dir, photo_dir, warnings)
    if why.startswith("images/ is missing"):
        warnings.append(f"{image_dir}: {why}")
    return fmt, frame_specs, rest, pts, cols, bounds, (image_dir, why), rec


def _full_size_specs(fmt, root, images, specs, image_dir):
    """The frames ``specs`` read from the scene's full-size image folder (``images/``, else the
    largest ``images_N/``) instead of the one the downscale picked: initial points do not depend
    on the training downscale."""
    if fmt not in ("colmap", "llff") or image_dir is None:
        return specs
    full_dir, _, _ = _image_dir(root, images, 1.0)
    if full_dir == image_dir:
        return specs
    return [replace(f, path=full_dir / f.name) if (full_dir / f.name).is_file() else f for f in specs]


def frame_sizes(path, images=None, progress=False) -> list:
    """``(width, height)`` of every image of the scene at ``path`` before any ``downscale``,
    without reading pixels (a folder of photos runs its SfM first, cached for the load): the
    cameras' sizes, or with ``images`` (an image folder of the user's choice, which ``downscale``
    shrinks further) the files' own. What plans a downscale (``tsplus train`` on a CPU);
    ``progress``: bars for a video's frames and the SfM."""
    from .images import read_image_size  # noqa: PLC0415
    cameras, files = scene_cameras(path, images, progress)
    if images is None:
        return [(c.width, c.height) for c in cameras]
    return [read_image_size(f) for f in files if f.is_file()]


def scene_cameras(path, images=None, progress=False) -> tuple:
    """``(cameras, image files)`` of every frame of the scene at ``path``, at full size, no pixel
    read (a photo folder's SfM first, cached): for :func:`frame_sizes` and ``export --y-up``."""
    root = _scene_root(path, None, progress, [])
    _, specs, *_ = _read_format(root, images, 1.0, None, progress, [])
    return [f.camera for f in specs], [Path(f.path) for f in specs]


def load_scene_arg(scene_arg, downscale=1, seed=0) -> Scene:
    """The scene a command-line argument names: ``procedural[:tiny|small|demo]`` (default size
    small; None means ``procedural:small``) or a scene folder / file for :func:`load_scene`.

    Raises:
        ValueError: a ``downscale`` other than 1 for the procedural scene.
        FileNotFoundError: the path does not exist.
    """
    from .procedural import load_procedural
    if scene_arg is None or scene_arg.startswith("procedural"):
        size = scene_arg.split(":", 1)[1] if scene_arg and ":" in scene_arg else "small"
        if downscale != 1:
            raise ValueError("--downscale: the procedural scene has fixed sizes; use procedural:tiny|small|demo")
        return load_procedural(size, seed=0)
    if not Path(scene_arg).exists():
        raise FileNotFoundError(f"scene {scene_arg}: no such file or folder")
    return load_scene(scene_arg, downscale=downscale, seed=seed)
