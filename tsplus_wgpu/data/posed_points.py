"""Initial points of a posed scene: triangulated from its training photos with pycolmap
(:mod:`.sfm`, cached at full size), its SfM points, whichever are more, or points in the camera
frusta (:mod:`.frusta`), for :func:`~.loader.load_scene`.

The triangulation also checks every training photo's pose against its own matches
(:mod:`.posecheck`); the photos whose pose disagrees are named in a warning and added to
``left_out``, which the loader takes out of the training views, unless their matches pose them again
(:mod:`.poserepair`): then their camera in ``reposed`` (the loader's cameras) takes the new pose.
The held-out photos are checked
against their training neighbours (:mod:`.heldout_poses`) and go to ``held_off``, out of the
held-out views.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from .tracks import remap


def triangulation_key(specs, background) -> str:
    """Cache key of a triangulation: the image files (names and bytes, :func:`~.sfm.file_digest`),
    their cameras and lens distortion, the background, and the loader's version of the recipe."""
    from .sfm import RECIPE, file_digest  # noqa: PLC0415
    h = hashlib.sha1(f"tsplus-triangulation-{RECIPE}|".encode())
    for f in specs:
        try:
            h.update(f"{f.name}|{Path(f.path).name}|{file_digest(f.path)}|".encode())
        except OSError:
            h.update(f"{f.name}|missing|".encode())
        c = f.camera
        h.update(np.round(np.array([c.width, c.height, c.fx, c.fy, c.cx, c.cy], np.float64), 6).tobytes())
        h.update(np.round(c.world_to_camera, 9).tobytes())
        und = f.undistort
        if und is not None:
            coeffs = getattr(und, "coeffs", None)
            cam = getattr(und, "camera", None)
            h.update(repr((None if coeffs is None else np.asarray(coeffs).tolist(),
                           None if cam is None else [cam.model_name, list(map(float, cam.params))])).encode())
    h.update(repr(tuple(background)).encode())
    return h.hexdigest()


def initial_points(points, cameras, imgs, specs, background, train_idx, bounds, cache_dir, progress, seed,
                   warnings, left_out, test_idx=(), held_off=None):
    """Initial points without SfM ones (or when asked): triangulated with pycolmap from the
    posed training images at their full size (:func:`triangulated`), else made from the camera
    frusta. ``specs`` are the loaded frames at full size; a training photo the triangulation
    poses again takes its new pose in ``cameras``.
    Returns ``(points, colours, source, track table or None)`` (:mod:`.tracks`; view ids index
    ``cameras``; None for frusta points)."""
    from .frusta import frusta_points  # noqa: PLC0415
    if points != "frusta":
        got = triangulated(specs, background, train_idx, cache_dir, progress, warnings, left_out, test_idx=test_idx,
                           held_off=held_off, reposed=cameras)
        if got is not None:
            return got[0], got[1], "triangulated", got[2]
    pts, cols = frusta_points(cameras, imgs, bounds=bounds, seed=seed)
    if points == "frusta":
        warnings.append("initial points made from the camera frusta (as asked)")
    return pts, cols, "frusta", None


def triangulated(specs, background, train_idx, cache_dir, progress, warnings, left_out,
                 fallback="initial points made from the camera frusta instead", test_idx=(), held_off=None,
                 *, reposed):
    """``(points, colours, track table or None)`` triangulated with pycolmap from the posed
    training images (all images when fewer than 2 are for training) at their full size, cached
    (so every downscale reuses them); None, with the warning ``"<why>: <fallback>"``, when that
    fails or there are not 2 images. ``specs`` are the loaded frames at full size; the track
    table's view ids index them. The held-out photos ``test_idx`` are checked against their poses
    too (:mod:`.heldout_poses`); those that disagree are named and added to ``held_off``. A
    training photo whose pose disagrees and that its matches pose again (:mod:`.poserepair`) is
    named and its camera in ``reposed`` (the scene's cameras, a list by frame index) given the new
    pose."""
    from .scene import full_size_frame  # noqa: PLC0415
    from .sfm import cache_root, triangulate_frames  # noqa: PLC0415
    use = train_idx if len(train_idx) >= 2 else list(range(len(specs)))
    if len(use) < 2:
        return None
    croot, note = cache_root(None, cache_dir)
    if note:
        warnings.append(note)
    sub = [specs[i] for i in use]
    try:
        pts, cols, info = triangulate_frames(lambda i: full_size_frame(sub[i], background), [f.name for f in sub],
                                             triangulation_key(sub, background), croot, progress=progress,
                                             source=Path(sub[0].path).parent)
    except RuntimeError as exc:
        warnings.append(f"{exc}: {fallback}")
        return None
    warnings.append(f"initial points triangulated with pycolmap from {len(use)} posed images at full size "
                    f"(mean reprojection error {info['mean_reprojection_error']:.2f} px"
                    + (", cached" if "cached" in info else "") + ")")
    err = info.get("pose_error")
    for k in map(int, info.get("pose_off", ())):      # photos whose pose disagrees with their matches
        warnings.append(f"{sub[k].name}: its pose disagrees with its matches to the other photos (epipolar error "
                        f"{err[k] * 100:.2f} % of the image diagonal, the median photo's {np.nanmedian(err) * 100:.2f} "
                        "%): left out of training and of the triangulation; correct or remove it in the camera model")
        left_out.append(use[k])
    _name_reposed(sub, use, info, warnings, reposed)
    if held_off is not None and len(test_idx) and len(use) < len(specs):
        _check_held_out(specs, use, list(test_idx), background, info, progress, warnings, held_off)
    tracks = info.get("tracks")
    return pts, cols, None if tracks is None else remap(tracks, np.asarray(use, np.int64))


def _name_reposed(sub, use, info, warnings, reposed):
    """A warning for each photo of ``info`` posed again from its matches (:mod:`.poserepair`),
    and its new pose given to its camera ``reposed[use[k]]``."""
    from .poserepair import moved, with_pose  # noqa: PLC0415
    err = info.get("pose_error")
    typical = np.nanmedian(err) if err is not None and np.any(np.isfinite(err)) else float("nan")
    for j, k in enumerate(map(int, info.get("reposed", ()))):
        w2c = np.asarray(info["reposed_w2c"][j], np.float64)
        dist, turn = moved(sub[k].camera.world_to_camera, w2c)
        inl, m = (int(v) for v in info["reposed_matches"][j])
        warnings.append(f"{sub[k].name}: its pose disagrees with its matches to the other photos (epipolar error "
                        f"{err[k] * 100:.2f} % of the image diagonal, the median photo's {typical * 100:.2f} %): posed "
                        f"again from {inl} of its {m} matches to the triangulated points ({dist:.3g} units and "
                        f"{turn:.0f} degrees from the camera model's pose; epipolar error now "
                        f"{float(info['reposed_error'][j]) * 100:.2f} %) and trained with that pose; correct it in the "
                        "camera model")
        reposed[use[k]] = with_pose(reposed[use[k]], w2c)


def _check_held_out(specs, use, test_idx, background, info, progress, warnings, held_off):
    """:mod:`.heldout_poses` for the held-out photos ``test_idx`` against the training photos'
    typical error in ``info`` (the triangulation's); a failure to check is a warning, never an error."""
    from .heldout_poses import disagreeing_held_out, held_out_errors  # noqa: PLC0415
    err = np.asarray(info.get("pose_error", ()), np.float64)
    off = set(int(k) for k in info.get("pose_off", ())) | set(int(k) for k in info.get("reposed", ()))
    judged = [e for k, e in enumerate(err) if np.isfinite(e) and k not in off]
    if len(judged) < 3:
        return
    typical = float(np.median(judged))
    work = Path(info["work"]) if "work" in info else Path(info["cached"]).parent
    train = [use[k] for k in range(len(use)) if k not in off]
    try:
        errors = held_out_errors(work, specs, train, test_idx, background, triangulation_key, progress)
    except Exception as exc:        # pycolmap, a full disk: a warning (Ctrl-C and signals still stop it)
        why = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        warnings.append(f"the held-out photos' poses could not be checked ({why})")
        return
    for k in disagreeing_held_out(errors, typical):
        warnings.append(f"{specs[test_idx[k]].name}: a held-out photo whose pose disagrees with its matches to the "
                        f"training photos (epipolar error {errors[k] * 100:.2f} % of the image diagonal, the median "
                        f"training photo's {typical * 100:.2f} %): left out of the evaluation; correct or remove it "
                        "in the camera model")
        held_off.append(test_idx[k])


def most_points(sfm, specs, background, train_idx, cache_dir, progress, warnings, left_out, test_idx=(),
                held_off=None, *, reposed):
    """``points="most"``: ``(points, colours, tracks, source)`` of the SfM points ``sfm``
    (``(points, colours, tracks)``) or of :func:`triangulated`'s, whichever are more; a
    warning says which."""
    got = triangulated(specs, background, train_idx, cache_dir, progress, warnings, left_out, "the SfM points kept",
                       test_idx=test_idx, held_off=held_off, reposed=reposed)
    if got is None:
        return (*sfm, "sfm")
    n_sfm, n_tri = len(sfm[0]), len(got[0])
    if n_tri > n_sfm:
        warnings.append(f"initial points: the {n_tri:,} triangulated ones, more than the {n_sfm:,} SfM points")
        return (*got, "triangulated")
    warnings.append(f"initial points: the {n_sfm:,} SfM points, more than the {n_tri:,} triangulated ones")
    return (*sfm, "sfm")
