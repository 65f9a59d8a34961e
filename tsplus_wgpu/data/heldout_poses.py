"""Held-out photos whose given pose disagrees with their matches to the training photos.

:mod:`.posecheck` judges the training photos inside the triangulation, which reads only them. A
held-out photo with a wrong pose is never trained on, but evaluating it compares the model drawn
from a wrong viewpoint with the photo: a low figure that blames the model for the camera file.
So each held-out photo is matched with its :data:`NEIGHBOURS` nearest training photos (SIFT and
COLMAP's verified matches, as the triangulation does, at the same sizes) and its error against
the poses (:func:`~.posecheck.pose_errors`) is judged against the training photos' typical error
by the same rule: over :data:`~.posecheck.RATIO` times it and over :data:`~.posecheck.FLOOR` of
the image diagonal. Such a photo is named in a warning and left out of the held-out views (not
when more than :data:`~.posecheck.MAX_SHARE` of them would go: then the poses as a whole are
off, not a few photos; one photo may always go).

The errors are kept in the triangulation's cache entry (``heldout.npz``), under a key of the
held-out photos and their neighbours (files, cameras), so a scene is checked once.
"""

from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path

import numpy as np

from .posecheck import FLOOR, MAX_SHARE, RATIO, pose_errors

#: each held-out photo is matched with this many nearest training photos
NEIGHBOURS = 6
#: the file a triangulation's cache entry keeps the held-out photos' errors in
RESULT = "heldout.npz"


def neighbours(cameras, train, test, k: int = NEIGHBOURS) -> dict:
    """``{held-out index: [training indices]}``: each held-out camera's ``k`` nearest training
    cameras, as the triangulation pairs its photos (:func:`~.sfm.neighbour_scores`; cameras facing
    apart are never paired)."""
    from .sfm import neighbour_scores  # noqa: PLC0415
    train = list(train)
    if not train:
        return {int(t): [] for t in test}
    score, cos = neighbour_scores(cameras)
    out = {}
    for t in test:
        order = [j for j in np.argsort(score[t, train], kind="stable") if cos[t, train[j]] > 0.0][:k]
        out[int(t)] = [int(train[j]) for j in order]
    return out


def _key(specs, pairs, background, digest) -> str:
    used = sorted({i for t, ns in pairs.items() for i in (t, *ns)})
    h = hashlib.sha1(f"heldout-{NEIGHBOURS}|{digest([specs[i] for i in used], background)}|".encode())
    for t, ns in sorted(pairs.items()):
        h.update(f"{specs[t].name}:{','.join(specs[j].name for j in ns)}|".encode())
    return h.hexdigest()


def held_out_errors(work, specs, train, test, background, digest, progress=False) -> np.ndarray:
    """Per held-out photo ``test[k]``, its pose error (a share of the image diagonal; NaN where
    fewer than 2 of its pairs had enough verified matches), from the frames ``specs`` at full
    size; cached in ``work/heldout.npz`` under a key made with ``digest(frames, background)`` (the
    triangulation's, :func:`~.posed_points.triangulation_key`)."""
    from .cache import mark_used  # noqa: PLC0415
    pairs = neighbours([s.camera for s in specs], train, test)
    key = _key(specs, pairs, background, digest)
    result = Path(work) / RESULT
    if result.is_file():
        try:
            with np.load(result) as z:
                if str(z["key"]) == key and len(z["errors"]) == len(test):
                    mark_used(work)
                    return z["errors"].astype(np.float64)
        except Exception:       # a damaged file: check again
            pass
    tmp = Path(work) / f"heldout.tmp{os.getpid()}"
    try:
        errors = _match_and_judge(tmp, specs, pairs, [int(t) for t in test], background, progress)
        part = Path(work) / f"heldout.tmp{os.getpid()}.npz"
        np.savez(part, key=key, errors=errors)
        os.replace(part, result)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return errors


def _match_and_judge(tmp, specs, pairs, test, background, progress):
    """The work of :func:`held_out_errors` in the folder ``tmp``: the photos written, matched
    pair by pair, their errors against the poses."""
    from .scene import full_size_frame  # noqa: PLC0415
    from .sfm import _extract_and_match, _posed_reconstruction, _Progress, _pycolmap, write_image  # noqa: PLC0415
    pycolmap = _pycolmap()
    used = sorted({i for t in test for i in (t, *pairs[t])})
    img_dir = tmp / "images"
    img_dir.mkdir(parents=True, exist_ok=True)
    prog = _Progress(progress, len(used) + 3, f"checking the poses of {len(test)} held-out photos")
    try:
        cameras, safe = {}, {}
        for i in used:
            got = full_size_frame(specs[i], background)
            prog.stage(f"reading {specs[i].name}")
            if got is None:
                continue
            cameras[i], safe[i] = got[0], f"{len(safe):05d}.png"
            write_image(img_dir / safe[i], got[1])
        names = [safe[i] for i in used if i in safe]
        match = [(safe[t], safe[j]) for t in test if t in safe for j in pairs[t] if j in safe]
        errors = np.full(len(test), np.nan)
        if not match:
            return errors
        db = tmp / "database.db"
        first = cameras[next(iter(cameras))]
        prog.stage("extracting SIFT features", 0)
        _extract_and_match(pycolmap, db, img_dir, names, pycolmap.CameraMode.PER_IMAGE, "PINHOLE", pairs=match,
                           small_images=max(first.width, first.height) < 1200, progress=prog)
        rec = _posed_reconstruction(pycolmap, db, [cameras[i] for i in used if i in safe], names)
        got = pose_errors(pycolmap, db, rec)
        prog.finish()
    finally:
        prog.close()
    for k, t in enumerate(test):
        if t in safe:
            errors[k] = got.get(safe[t], (np.nan, 0))[0]
    return errors


def disagreeing_held_out(errors, typical) -> list:
    """Indices into ``errors`` (the held-out photos') whose pose disagrees with their matches by
    :mod:`.posecheck`'s rule against the training photos' ``typical`` error; none when more than
    one photo and over :data:`~.posecheck.MAX_SHARE` of the judged ones would go, or nothing is
    typical."""
    e = np.asarray(errors, np.float64)
    if not np.isfinite(typical):
        return []
    judged = np.isfinite(e)
    bad = [int(k) for k in np.nonzero(judged & (e > RATIO * typical) & (e > FLOOR))[0]]
    return bad if len(bad) <= max(1.0, MAX_SHARE * judged.sum()) else []
