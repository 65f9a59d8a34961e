"""Structure from motion for a folder of photos or a video's frames (pycolmap), with a progress bar.

:func:`run_photos_sfm`: SIFT features, matching (every pair; the frames of a video, or more than
:data:`ORDERED_PHOTOS_MIN` photos, in their order) and global mapping (incremental where that
registers more; the photos' EXIF focal length held first). The model is cached in
the user cache (:func:`~tsplus_wgpu.data.sfm.cache_root`) and reused while the photos have not
changed. pycolmap runs on one thread, so it gives the same model on every run.
"""

from __future__ import annotations

import json
import math
import re
import shutil
from pathlib import Path

from .errors import SceneError
from .images import list_images, read_image_size
from .cache import mark_used, trim
from .long_calls import _Progress
from .sfm import SEQUENTIAL_OVERLAP, _extract_and_match, _fingerprint, _pycolmap, cache_root, sfm_focal, sfm_threads

#: a folder of more photos than this is matched in the photos' natural name order like a video's
#: frames (phones name photos in the order they were taken): every pair of 300 photos is 44,850
#: pairs, hours on one thread. When that registers fewer than :data:`ORDERED_MIN_SHARE` of the
#: photos, every other pair is matched as well and the mapping runs again.
ORDERED_PHOTOS_MIN = 100
ORDERED_MIN_SHARE = 0.9
#: about how many seconds a step of the SfM takes on one thread of a 2-core AMD EPYC (office's
#: frames, 960x540: extraction 59 s for 64 images, 62-170 ms a matched pair, mapping 22 s): the
#: units of its progress bar, so that its time left means something from the first stage on
STEP_SECONDS = dict(image=0.9, pair=0.1, register=0.35)
#: the SfM cache entries this process made: a later load in the same process (``tsplus train``'s
#: plan runs the SfM, its load reads it) says nothing of reusing them
MADE_HERE: set = set()


def natural_key(name: str) -> list:
    """Sort key of a file name with its digit runs compared as numbers: ``2.jpg`` before ``10.jpg``."""
    return [int(t) if k % 2 else t.lower() for k, t in enumerate(re.split(r"(\d+)", str(name)))]


def ordered_pairs(names: list, overlap: int = SEQUENTIAL_OVERLAP) -> list:
    """Image pairs of ``names`` taken in their natural order (:func:`natural_key`): each with the
    next ``overlap`` and with those ``2 ** k`` further on for ``k < overlap``, as COLMAP's
    sequential matching pairs the frames of a video."""
    order = sorted(names, key=natural_key)
    n = len(order)
    pairs = []
    for i in range(n):
        ahead = set(range(i + 1, min(n, i + overlap + 1))) | {i + (1 << k) for k in range(overlap) if i + (1 << k) < n}
        pairs += [(order[i], order[j]) for j in sorted(ahead)]
    return pairs


def run_photos_sfm(photo_dir: Path, names: list, cache=None, progress: bool = True, warnings=None,
                   sequential: bool = False, shown=None):
    """Incremental SfM on the photos ``names`` inside ``photo_dir``.

    ``sequential``: the photos are the frames of a video, in time order (:mod:`.video`), matched
    with their neighbours in time (:data:`SEQUENTIAL_OVERLAP`). Otherwise every pair is matched,
    or for more than :data:`ORDERED_PHOTOS_MIN` photos the pairs of their name order first.

    ``shown``: the folder the errors name instead of ``photo_dir`` (the user's own, when
    ``photo_dir`` is a copy in the cache: :mod:`.heif`).

    Returns:
        the folder of the resulting COLMAP model (``.../sparse/0``), cached and reused while the
        photos (names and bytes) are unchanged.

    Raises:
        SceneError: too few photos, or SfM registers too few of them.
    """
    pycolmap = _pycolmap()
    sfm_threads()   # a bad TSPLUS_SFM_THREADS is an error before any work, never a fallback
    focal = sfm_focal()
    pycolmap.set_random_seed(0)
    warnings = warnings if warnings is not None else []
    photo_dir = Path(photo_dir)
    label = Path(shown) if shown is not None else photo_dir
    if len(names) < 3:
        raise SceneError(f"{label}: {len(names)} photo(s) found, SfM needs at least 3 overlapping photos; add more")
    root, note = cache_root(None, cache)
    if note:
        warnings.append(note)
    ordered = not sequential and len(names) > ORDERED_PHOTOS_MIN
    mode = f"sequential{SEQUENTIAL_OVERLAP}" if sequential else (f"ordered{SEQUENTIAL_OVERLAP}" if ordered else "")
    if focal == "refine":       # TSPLUS_SFM_FOCAL=refine: a model of its own
        mode += "refine"
    groups = camera_groups(photo_dir, names)
    if len(groups) > 1:      # a camera a group (before: one a photo of another size); one group keeps its key
        mode += f"groups{len(groups)}"
    work = root / f"sfm_{_fingerprint([photo_dir / n for n in names], mode)[:16]}"
    model_dir = work / "sparse" / "0"
    if (model_dir / "cameras.bin").is_file() and (work / "done.json").is_file():
        warnings.extend(_recorded_warnings(work / "done.json"))   # what the SfM said: every load says it again
        if str(work) not in MADE_HERE:
            warnings.append(f"reused cached SfM model {model_dir}")
        mark_used(work)
        return model_dir
    if work.exists():
        shutil.rmtree(work, ignore_errors=True)
    try:
        work.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SceneError(f"{work}: cannot create the SfM cache folder ({exc.strerror}); set TSPLUS_CACHE or "
                         "XDG_CACHE_HOME to a writable folder") from None
    said = len(warnings)
    try:
        nreg = _registered(pycolmap, work, photo_dir, names, label, sequential, ordered, groups, progress, warnings)
    except BaseException:       # failed or stopped: nothing half made stays in the cache
        shutil.rmtree(work, ignore_errors=True)
        raise
    (work / "done.json").write_text(json.dumps({"images": list(names), "registered": nreg, "folder": str(label),
                                                "warnings": warnings[said:]}))
    MADE_HERE.add(str(work))
    trim(work, "sfm")           # the feature database and the other models: not read again
    return model_dir


def _registered(pycolmap, work, photo_dir, names, label, sequential, ordered, groups, progress, warnings) -> int:
    """The SfM of :func:`run_photos_sfm` into its cache entry ``work``: the model written to
    ``work/sparse/0``; returns how many photos it registers."""
    model_dir = work / "sparse" / "0"
    prog = _Progress(progress, len(names) * (STEP_SECONDS["image"] + STEP_SECONDS["register"])
                     + _pair_count(names, sequential or ordered) * STEP_SECONDS["pair"],
                     f"SfM on {len(names)} photos", weighted=True)
    try:
        best = _photos_model(pycolmap, work, photo_dir, names, sequential, ordered, prog, warnings,
                             groups if len(groups) > 1 else None)
        prog.finish()
    except SceneError:
        raise
    except Exception as exc:
        raise SceneError(f"{label}: SfM failed ({str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__}); "
                         "take more overlapping, sharp photos") from None
    finally:
        prog.close()
    nreg = best.num_reg_images() if best is not None else 0
    need = max(3, (len(names) + 1) // 2)
    if nreg < need:
        raise SceneError(f"{label}: SfM registered only {nreg} of {len(names)} photos (need {need}); "
                         "take more overlapping, sharp photos with texture, or remove the unrelated ones")
    if nreg < len(names):
        got = {best.images[i].name for i in best.reg_image_ids()}
        warnings.append(skipped_warning(nreg, names, [n for n in names if n not in got]))
    model_dir.mkdir(parents=True, exist_ok=True)
    best.write(str(model_dir))
    return nreg


def skipped_warning(nreg: int, names: list, missing: list) -> str:
    """The warning for photos SfM could not place, naming them (the first 8)."""
    shown = ", ".join(missing[:8]) + (f" and {len(missing) - 8} more" if len(missing) > 8 else "")
    return (f"SfM registered {nreg} of {len(names)} photos; skipped (SfM found no pose for them): {shown}; "
            "more photos overlapping them would let SfM place them")


def _recorded_warnings(done: Path) -> list:
    """The warnings a finished SfM entry's ``done.json`` recorded (entries made before they were
    recorded: the registered count's)."""
    try:
        rec = json.loads(done.read_text())
    except (OSError, ValueError):
        return []
    if isinstance(rec.get("warnings"), list):
        return [str(w) for w in rec["warnings"]]
    images, nreg = rec.get("images"), rec.get("registered")
    if isinstance(images, list) and isinstance(nreg, int) and nreg < len(images):
        return [f"SfM registered {nreg} of {len(images)} photos; the others are skipped"]
    return []


def _pair_count(names, in_order: bool) -> int:
    """How many image pairs are matched: in (name or time) order, or every pair."""
    return len(ordered_pairs(names)) if in_order else len(names) * (len(names) - 1) // 2


def _photos_model(pycolmap, work, photo_dir, names, sequential, ordered, prog, warnings, groups=None):
    """Features, matches and incremental mapping of :func:`run_photos_sfm` on photos taken by
    one camera, or by the cameras of ``groups`` (:func:`camera_groups`; a camera each): the
    reconstruction that registers the most photos (None when there is none)."""
    db = work / "database.db"
    prog.stage("extracting SIFT features", 0)
    small = max(max(read_image_size(photo_dir / n)) for n in names) < 1200
    # one camera for the photos of one device and lens (the usual capture); several: one a group,
    # each group's features extracted in a call of its own (two lenses' photos under one camera
    # would leave one focal length for both; a camera a photo would leave each its own to solve)
    mode = pycolmap.CameraMode.SINGLE
    # a pair list cannot hold names with spaces: COLMAP's own sequential order (by name) for those
    listed = ordered and not any(c.isspace() for n in names for c in n)
    pairs = ordered_pairs(names) if listed else None
    _extract_and_match(pycolmap, db, photo_dir, names, mode, "SIMPLE_RADIAL", progress=prog, small_images=small,
                       sequential=sequential or (ordered and not listed), pairs=pairs,
                       extract_units=len(names) * STEP_SECONDS["image"], groups=groups,
                       match_units=_pair_count(names, sequential or ordered) * STEP_SECONDS["pair"])
    n_pairs = _pair_count(names, sequential or ordered)
    best, held = _mapping(pycolmap, db, photo_dir, work, prog, len(names))
    nreg = best.num_reg_images() if best is not None else 0
    if ordered and nreg < ORDERED_MIN_SHARE * len(names):
        warnings.append(f"SfM of the photos in name order registered {nreg} of {len(names)}: every pair matched "
                        "as well")
        rest = _pair_count(names, False) - n_pairs
        prog.add(rest * STEP_SECONDS["pair"] + nreg * STEP_SECONDS["register"])
        prog.stage("matching every pair", 0)
        mopt = pycolmap.FeatureMatchingOptions()
        mopt.num_threads = sfm_threads()
        with prog.creep(rest * STEP_SECONDS["pair"]):
            pycolmap.match_exhaustive(db, matching_options=mopt, device=pycolmap.Device.cpu)
        for old in ("sparse_all", "sparse_global", "sparse_global_held"):
            shutil.rmtree(work / old, ignore_errors=True)
        best, held = _mapping(pycolmap, db, photo_dir, work, prog, len(names))
    if held:
        focals = sorted({f"{c.focal_length:.0f}" for c in best.cameras.values()})
        warnings.append(f"SfM held the focal length the photos' EXIF gives ({', '.join(focals)} px); if they were "
                        "cropped or zoomed after shooting, set TSPLUS_SFM_FOCAL=refine")
    return best


def _mapping(pycolmap, db, photo_dir, work, prog, count: int):
    """``(model, held)``: the reconstruction of the matched database ``db`` of ``count`` photos
    that registers the most of them (None when there is none), and whether it held the EXIF
    focal length. Tried in turn until one registers every photo, the first kept on a tie:
    COLMAP's global mapper with the focal length the photos' EXIF gives held (only when every
    camera has one, unless ``TSPLUS_SFM_FOCAL=refine``), the global mapper refining the focal
    length, the incremental mapper (docs/measurements.md, "A forward walk: the global mapper")."""
    tries = [True] if sfm_focal() == "exif" and _exif_focal(pycolmap, db) else []
    tries += [False, None]
    best, got, held = None, -1, False
    for k, hold in enumerate(tries):
        if k:
            prog.add(count * STEP_SECONDS["register"])
        if hold is None:
            rec = _incremental_mapping(pycolmap, db, photo_dir, work, prog)
        else:
            rec = _global_mapping(pycolmap, db, photo_dir, work, prog, count, hold)
        n = rec.num_reg_images() if rec is not None else 0
        if n > got:
            best, got, held = rec, n, hold is True
        if got >= count:
            break
    return best, held


def _exif_focal(pycolmap, db) -> bool:
    """Whether every camera of ``db`` has its focal length from the photos' EXIF (COLMAP's prior)."""
    with pycolmap.Database.open(db) as base:
        cams = base.read_all_cameras()
    return bool(cams) and all(c.has_prior_focal_length for c in cams)


def _global_mapping(pycolmap, db, photo_dir, work, prog, count: int, hold: bool):
    """pycolmap's global SfM (GLOMAP) of ``db``: the rotations of every photo averaged from the
    pairs' relative poses, then the positions, then bundle adjustment over all photos at once,
    where the incremental mapper grows the model photo by photo and a walk down a street drifts.
    ``hold``: the focal length is not refined (a forward walk hardly constrains it, and refining
    trades it for the poses); the distortion is (there is no prior for it, and a lens's
    distortion held at zero costs the views it bends). Runs on a copy of ``db`` (it writes the pairs'
    decomposed poses into it); returns the model that registers the most photos, or None (also
    when the mapper gives up)."""
    prog.stage("global mapping" + (" (EXIF focal length)" if hold else ""), 0)
    tag = "_held" if hold else ""
    copy = work / f"database_global{tag}.db"
    shutil.copyfile(db, copy)
    opts = pycolmap.GlobalPipelineOptions()
    opts.num_threads = opts.mapper.num_threads = sfm_threads()
    opts.random_seed = opts.mapper.random_seed = 0
    opts.multiple_models = False
    opts.mapper.bundle_adjustment.refine_focal_length = not hold
    out = work / f"sparse_global{tag}"
    out.mkdir(exist_ok=True)
    with prog.creep(count * STEP_SECONDS["register"]):
        recs = pycolmap.global_mapping(copy, photo_dir, out, options=opts)
    return max(recs.values(), key=lambda r: r.num_reg_images()) if recs else None


def _incremental_mapping(pycolmap, db, photo_dir, work, prog):
    """pycolmap's incremental mapping of the matched database ``db``: the reconstruction that
    registers the most images, or None."""
    prog.stage("incremental mapping", 0)
    opts = pycolmap.IncrementalPipelineOptions()
    opts.num_threads = sfm_threads()
    opts.random_seed = 0
    opts.multiple_models = False
    count = {"n": 0}

    def on_image():
        count["n"] += 1
        prog.stage(f"registered {count['n'] + 1} images", STEP_SECONDS["register"])

    out = work / "sparse_all"
    out.mkdir(exist_ok=True)
    recs = pycolmap.incremental_mapping(db, photo_dir, out, options=opts, next_image_callback=on_image)
    return max(recs.values(), key=lambda r: r.num_reg_images()) if recs else None


def camera_groups(photo_dir: Path, names: list) -> list:
    """``names`` grouped by the camera that took them, in the order of each group's first photo:
    the image size and, where the files carry them, the EXIF make, model, lens and focal length
    (a phone's wide, ultra-wide and tele lenses give photos of one size and different focal
    lengths). Photos without EXIF group by size alone."""
    groups: dict = {}
    for n in names:
        groups.setdefault(camera_key(Path(photo_dir) / n), []).append(n)
    return list(groups.values())


def camera_key(path: Path) -> tuple:
    """``((width, height), (make, model, lens, focal mm, focal 35 mm))`` of a photo file, its
    header only; empty strings and zeros for the EXIF tags it lacks."""
    try:
        from PIL import Image  # noqa: PLC0415
        with Image.open(path) as im:
            size = (int(im.size[0]), int(im.size[1]))
            exif = im.getexif()
            sub = exif.get_ifd(0x8769)           # the Exif sub-IFD: lens and focal lengths
    except Exception:                            # not a format PIL reads: its size, no EXIF
        return read_image_size(path), ()

    def text(tag, ifd):
        v = ifd.get(tag)
        return str(v).strip().strip("\x00").strip() if v is not None else ""

    def number(tag):
        try:
            v = float(sub.get(tag) or 0.0)
        except (TypeError, ValueError, ZeroDivisionError):
            return 0.0
        return round(v, 2) if math.isfinite(v) else 0.0
    return size, (text(0x010F, exif), text(0x0110, exif), text(0xA434, sub), number(0x920A), number(0xA405))


def photo_names(folder: Path) -> list:
    """Image files in a photos-only folder (sorted)."""
    return list_images(folder)
