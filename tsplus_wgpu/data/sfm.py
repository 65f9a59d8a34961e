"""Structure from motion with pycolmap, and initial points for scenes that have poses only.

* the photos' SfM (:mod:`.photos`) uses its features and matching (:func:`_extract_and_match`)
  and its cache (:func:`cache_root`), keyed by the photos' bytes (:func:`_fingerprint`).
* :func:`triangulate_known_poses`: features and matches as above, photos whose given pose
  disagrees with their matches left out (:mod:`.posecheck`), then pycolmap's point triangulator
  with the given cameras held fixed; a photo left out is posed again from its matches to those
  points where they agree on one pose (:mod:`.poserepair`), and the points triangulated again
  with it in.

pycolmap runs on one thread (:func:`sfm_threads`), so both give the same result on every run.
The fallback without SfM points, points in the cameras' frusta, is :mod:`.frusta`.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from .cache import mark_used, trim
from .errors import SceneError
from .guided import add_guided_matches
from .images import write_image
from .long_calls import Stopped, _Progress, import_pycolmap  # noqa: F401  (Stopped: re-exported)
from .posecheck import left_out, pose_errors
from .poserepair import reposed_photos, with_pose
from .tracks import check as check_tracks
from .tracks import of_pycolmap_points as tracks_of_points
from .unit_frame import camera_frame, in_frame, pose_to_world, reconstruction_to_world

#: the smallest angle (degrees) between two rays of a triangulated point with known poses
#: (COLMAP's default is 1.5), and two-view tracks are triangulated (COLMAP skips them by default): the
#: poses are known, so a point seen in only two training views is still placed where they say,
#: and such points are what covers the surfaces few views share. Lund's 25 training views give
#: 4,804 points this way against 1,452 with the defaults (SfM: 1,549), 3,485 of them two-view;
#: measured in docs/measurements.md ("Real captures: denser initial points").
TRIANGULATION_MIN_ANGLE = 1.0

#: the recipe's version in every cache key: results of an older recipe are not reused
#: (v3: pycolmap on one thread, deterministic; v4: matches guided by the known poses added;
#: v5: guided over 12 nearest cameras instead of 6; v7: photos whose pose disagrees posed again
#: from their matches, :mod:`.poserepair`; v6 was an experiment's, not committed, so never reused;
#: v8: in the cameras' own frame, :mod:`.unit_frame`)
RECIPE = "v8"
#: the photo folder's SfM recipe (unchanged by v4, which only adds matches for posed images;
#: v5: the global mapper first, the EXIF focal length held, :mod:`.photos`; v4 was an
#: experiment's, reverted, so its cache entries must not be read as this recipe's)
SFM_RECIPE = "v5"
#: the frames of a video (:mod:`.video`) are matched in time order: each with the next this many,
#: and with the frames 16, 32, ... 512 further on (COLMAP's sequential matching with its quadratic
#: overlap: 2 ** k for k below this), instead of every pair: 100 frames give 1,133 pairs, not 4,950
SEQUENTIAL_OVERLAP = 10

#: each posed image is also matched along the known epipolar lines (:mod:`.guided`) with this many
#: of its nearest cameras (12 against 6: 2-18 % more points; lund +0.65 dB, cup +0.15, fox +0.06, office -0.09;
#: docs/measurements.md, "Initial points: 12 guided neighbours")
GUIDED_NEIGHBOURS = 12


def sfm_focal() -> str:
    """What a photo folder's SfM does with the focal length the photos' EXIF gives:
    ``TSPLUS_SFM_FOCAL=exif`` (the default) holds it while every photo has one (a forward walk
    hardly constrains the focal length: docs/data.md), ``refine`` lets the mapper refine it, for
    photos cropped or zoomed after shooting, whose EXIF no longer fits them."""
    raw = os.environ.get("TSPLUS_SFM_FOCAL", "exif").strip().lower()
    if raw not in ("exif", "refine"):
        raise SceneError(f"TSPLUS_SFM_FOCAL={raw!r}: expected exif (hold the focal length the photos' EXIF gives) "
                         "or refine (for photos cropped after shooting)")
    return raw


def sfm_threads() -> int:
    """pycolmap's threads for feature extraction, matching, mapping and triangulation: 1 unless
    ``TSPLUS_SFM_THREADS`` says otherwise (``-1``: all cores).

    With more than one, pycolmap's results depend on the thread schedule (probably: the image
    and camera ids follow the order the extraction threads finish in, and the matches' geometric
    verification and the mapper draw their random samples per thread). Lund's triangulation gave
    4,811 to 4,830 points over four runs on 2 cores, its photos' SfM 2 or 21 registered photos
    from one database; on one thread the same points to the last bit, 73 s against 41 s on 2
    cores (once per scene: the result is cached). A faster, varying result:
    ``TSPLUS_SFM_THREADS=-1``."""
    raw = os.environ.get("TSPLUS_SFM_THREADS", "1").strip()
    try:
        n = int(raw)
    except ValueError:
        raise SceneError(f"TSPLUS_SFM_THREADS={raw!r}: expected a whole number of threads (1: deterministic, "
                         "-1: all cores)") from None
    if n == 0 or n < -1:
        raise SceneError(f"TSPLUS_SFM_THREADS={raw!r}: expected 1 or more, or -1 for all cores")
    return n


def _pycolmap():
    pycolmap = import_pycolmap()
    try:  # COLMAP's own INFO log is far too chatty for a command line tool
        if os.environ.get("TSPLUS_COLMAP_LOG") is None:
            pycolmap.logging.minloglevel = 3
    except AttributeError:  # pragma: no cover
        pass
    return pycolmap


def cache_root(scene_dir=None, override=None) -> tuple[Path, str | None]:
    """Folder for cached SfM and triangulation results: ``override`` (asked for), else
    ``$TSPLUS_CACHE``, else ``$XDG_CACHE_HOME/tsplus_wgpu`` (default ``~/.cache/tsplus_wgpu``);
    never the scene folder unless asked.  Entries inside are keyed by the scene's content.
    When the user cache cannot be written, a folder under the system temp folder is used.

    Returns ``(folder, note)`` where note explains a fallback.
    """
    if override is not None:
        return Path(override), None
    env = os.environ.get("TSPLUS_CACHE")
    if env:
        return Path(env), None
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "tsplus_wgpu"
    try:
        base.mkdir(parents=True, exist_ok=True)
        probe = base / f".write_test{os.getpid()}"
        probe.write_text("")
        probe.unlink()
        return base, None
    except OSError:
        tmp = Path(tempfile.gettempdir()) / f"tsplus_wgpu-cache-{os.getuid() if hasattr(os, 'getuid') else 0}"
        return tmp, f"{base} is not writable: cache kept in {tmp} (set XDG_CACHE_HOME or TSPLUS_CACHE)"


def file_digest(path) -> str:
    """SHA-1 of a file's bytes: what the caches' keys hold of an image, so that copying, moving or
    touching the photos keeps their cache (keys of modification times missed on every fresh copy
    of the same photos; hashing fox's 24 MB of images takes 0.07 s)."""
    h = hashlib.sha1()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _fingerprint(paths, mode: str = "") -> str:
    """Content key of image files: their names and bytes (:func:`file_digest`), the recipe and the
    matching ``mode`` (``""``: every pair)."""
    h = hashlib.sha1(f"{SFM_RECIPE}|{mode + '|' if mode else ''}".encode())
    for p in paths:
        h.update(f"{Path(p).name}|{file_digest(p)}\n".encode())
    return h.hexdigest()


def _extract_and_match(pycolmap, db: Path, img_dir: Path, names, camera_mode, camera_model: str,
                       pairs=None, max_image_size: int = 1600, progress: _Progress | None = None,
                       small_images: bool = False, sequential: bool = False, extract_units: float = 1,
                       groups=None, match_units: float = 0):
    """SIFT features of the images ``names`` into the database ``db`` (``groups``: lists of them
    extracted one call each, so that ``CameraMode.SINGLE`` gives each group its own camera),
    then matches: ``pairs``, COLMAP's ``sequential`` order, or every pair. ``progress`` moves on
    by ``extract_units`` over the extraction and ``match_units`` over the matching
    (:meth:`_Progress.creep`)."""
    ext = pycolmap.FeatureExtractionOptions()
    ext.max_image_size = int(max_image_size)
    ext.num_threads = sfm_threads()
    if small_images:
        # small photos give few SIFT peaks at COLMAP's default threshold: lower it
        ext.sift.peak_threshold = 0.002
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = camera_model
    with progress.creep(extract_units) if progress else contextlib.nullcontext():
        for part in groups or [names]:
            pycolmap.extract_features(db, img_dir, image_names=list(part), camera_mode=camera_mode,
                                      reader_options=reader, extraction_options=ext, device=pycolmap.Device.cpu)
    if progress:
        progress.stage("matching", 0)
    with progress.creep(match_units) if progress and match_units else contextlib.nullcontext():
        _match(pycolmap, db, sequential, pairs)


def _match(pycolmap, db, sequential, pairs):
    """pycolmap's matching of the features in ``db``: COLMAP's ``sequential`` order, the image
    ``pairs`` given, or every pair."""
    mopt = pycolmap.FeatureMatchingOptions()
    mopt.num_threads = sfm_threads()
    if sequential:
        popt = pycolmap.SequentialPairingOptions()
        popt.overlap = SEQUENTIAL_OVERLAP
        popt.quadratic_overlap = True
        popt.loop_detection = False            # needs a vocabulary tree, which nothing may download
        pycolmap.match_sequential(db, matching_options=mopt, pairing_options=popt, device=pycolmap.Device.cpu)
    elif pairs is None:
        pycolmap.match_exhaustive(db, matching_options=mopt, device=pycolmap.Device.cpu)
    else:
        pair_file = Path(db).with_suffix(".pairs.txt")
        pair_file.write_text("".join(f"{a} {b}\n" for a, b in pairs))
        popt = pycolmap.ImportedPairingOptions()
        popt.match_list_path = pair_file
        pycolmap.match_image_pairs(db, matching_options=mopt, pairing_options=popt, device=pycolmap.Device.cpu)


def neighbour_scores(cameras: list):
    """``(score, cos)`` ``[N, N]``: how near two known cameras are for matching (their distance over
    the cameras' median spacing plus twice one minus the cosine between their viewing directions;
    lower is nearer) and that cosine (pairs facing apart, ``cos <= 0``, are never matched)."""
    C = np.stack([c.center for c in cameras])
    D = np.stack([c.R[2] for c in cameras])  # viewing directions
    dist = np.linalg.norm(C[:, None] - C[None], axis=2)
    scale = np.median(dist[dist > 0]) if np.any(dist > 0) else 1.0
    cosang = np.clip(D @ D.T, -1, 1)
    return dist / scale + 2.0 * (1 - cosang), cosang


def _neighbour_pairs(cameras: list, names: list, k: int = 12):
    """Image pairs for matching with known poses: each image with its k nearest cameras
    (:func:`neighbour_scores`)."""
    score, cosang = neighbour_scores(cameras)
    np.fill_diagonal(score, np.inf)
    pairs = set()
    for i in range(len(cameras)):
        for j in np.argsort(score[i])[:k]:
            if np.isfinite(score[i, j]) and cosang[i, j] > 0.0:
                pairs.add((min(i, int(j)), max(i, int(j))))
    return [(names[a], names[b]) for a, b in sorted(pairs)]


def _posed_key(cameras, images, names):
    """Cache key of a triangulation: the names, cameras and a sparse sample of the pixels."""
    h = hashlib.sha1(f"{RECIPE}|".encode())
    for cam, img, n in zip(cameras, images, names):
        h.update(n.encode())
        h.update(np.round(np.array([cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy]), 4).tobytes())
        h.update(np.round(cam.world_to_camera, 6).tobytes())
        h.update(np.ascontiguousarray(img[::17, ::13]).tobytes())
    return h.hexdigest()[:16]


def _posed_reconstruction(pycolmap, db, cameras, safe, skip=()):
    """A pycolmap Reconstruction of the images in the database ``db`` (file names ``safe``, but
    those in ``skip``) with the known cameras and poses fixed and their keypoints, no points yet."""
    rec = pycolmap.Reconstruction()
    with pycolmap.Database.open(db) as database:
        db_images = {im.name: im for im in database.read_all_images()}
        for i, s in enumerate(safe):
            if s not in db_images or s in skip:
                continue
            dbim = db_images[s]
            cam = cameras[i]
            dbcam = database.read_camera(dbim.camera_id)
            # the database camera may be at a reduced size (max_image_size) -> use the file size
            pc = pycolmap.Camera.create_from_model_name(dbim.camera_id, "PINHOLE", cam.fx, cam.width, cam.height)
            pc.params = [cam.fx, cam.fy, cam.cx, cam.cy]
            if (dbcam.width, dbcam.height) != (cam.width, cam.height):
                pc.rescale(int(dbcam.width), int(dbcam.height))
            database.update_camera(pc)
            rec.add_camera_with_trivial_rig(pc)
            im = pycolmap.Image(name=s, camera_id=dbim.camera_id, image_id=dbim.image_id)
            im.points2D = pycolmap.Point2DList(
                [pycolmap.Point2D(xy) for xy in database.read_keypoints(dbim.image_id)[:, :2]])
            rec.add_image_with_trivial_frame(im, pycolmap.Rigid3d(cam.world_to_camera[:3, :4]))
    return rec


def triangulate_known_poses(cameras: list, images: list, names: list, cache_dir: Path,
                            progress: bool = True, max_image_size: int = 1600, exhaustive_max: int = 30):
    """Triangulate points from the loaded (pinhole, undistorted) images and fixed known poses.

    Args:
        cameras, images, names: the scene's loaded cameras and float images.
        cache_dir: cache folder; the result ``points.npz`` is cached there keyed on cameras and images.

    Returns:
        ``(points [P,3], colors [P,3], info dict)``; ``info["tracks"]``: the points' track table
        (:mod:`.tracks`), ids indexing ``cameras``.

    Raises:
        RuntimeError: pycolmap failed or produced too few points (the caller falls back to frusta).
    """
    key = _posed_key(cameras, images, names) + f"_{max_image_size}_{exhaustive_max}"
    return triangulate_frames(lambda i: (cameras[i], images[i]), names, key, cache_dir, progress=progress,
                              max_image_size=max_image_size, exhaustive_max=exhaustive_max)


def triangulate_frames(load_one, names: list, key: str, cache_dir: Path, progress: bool = True,
                       max_image_size: int = 1600, exhaustive_max: int = 30, source=None):
    """Triangulate points with fixed known poses from images loaded one at a time.

    Args:
        load_one: ``i -> (pinhole Camera, float image)`` for image ``i`` (None to leave it out);
            called only when the result is not cached, and one image is held at a time.
        names: the images' names (for the progress display).
        key: cache key naming the images' content, cameras and parameters.
        cache_dir: cache folder; the result is ``cache_dir/tri_<key>/points.npz`` (a cached file
            without the tracks, from an older version, is computed again), alone (:func:`~.cache.trim`).
        source: the images' folder, recorded for ``tsplus cache``.

    Returns / Raises: as :func:`triangulate_known_poses`; ``info["tracks"]`` is the points' track
    table (:mod:`.tracks`) whose ids index ``names``; ``info["pose_error"]`` each image's error
    against its pose (:func:`~.posecheck.pose_errors`, NaN where not judged) and
    ``info["pose_off"]`` the indices of those left out (:func:`~.posecheck.left_out`: no match,
    point or track of theirs is used); of the photos it judged off, ``info["reposed"]`` the indices
    of those posed again from their matches (:mod:`.poserepair`), ``info["reposed_w2c"]`` their
    new world-to-camera poses [K,3,4], ``info["reposed_error"]`` their epipolar error with it and
    ``info["reposed_matches"]`` [K,2] the correspondences that agree with it and all of them (they
    are in the triangulation with the new pose).
    """
    pycolmap = _pycolmap()
    sfm_threads()   # a bad TSPLUS_SFM_THREADS is an error before any work, never a fallback
    pycolmap.set_random_seed(0)
    recipe = f"{key}|min_angle={TRIANGULATION_MIN_ANGLE}|two_view=1"   # a new recipe never reads an old result
    work = Path(cache_dir) / f"tri_{hashlib.sha1(recipe.encode()).hexdigest()[:16]}"
    result = work / "points.npz"
    if result.is_file():
        try:
            with np.load(result) as z:
                if {"track_offsets", "track_frames", "pose_error", "reposed"} <= set(z.files):   # else stale
                    tracks = (z["track_offsets"].astype(np.int64), z["track_frames"].astype(np.int32))
                    check_tracks(tracks, len(z["xyz"]), len(names))
                    pose_error, pose_off = z["pose_error"].astype(np.float64), z["pose_off"].astype(np.int64)
                    reposed = {k: z[k] for k in ("reposed", "reposed_w2c", "reposed_error", "reposed_matches")}
                    idx = reposed["reposed"].astype(np.int64)
                    if (len(pose_error) != len(names) or np.any((pose_off < 0) | (pose_off >= len(names)))
                            or np.any((idx < 0) | (idx >= len(names)))
                            or reposed["reposed_w2c"].shape != (len(idx), 3, 4)
                            or not np.all(np.isfinite(reposed["reposed_w2c"]))):
                        raise ValueError("pose check of other images")
                    mark_used(work)
                    return z["xyz"], z["rgb"], {"cached": str(result), "mean_reprojection_error": float(z["err"]),
                                                "tracks": tracks, "pose_error": pose_error, "pose_off": pose_off,
                                                **reposed}
        except Exception:  # a damaged cache entry: compute again
            pass
    if work.exists():
        shutil.rmtree(work, ignore_errors=True)
    img_dir = work / "images"
    try:
        img_dir.mkdir(parents=True, exist_ok=True)
        (work / "about.json").write_text(json.dumps({"source": source and str(source), "images": len(names)}))
    except OSError as exc:
        raise RuntimeError(f"cache folder {work} cannot be written ({exc.strerror})") from None
    try:
        return _triangulated_points(pycolmap, work, load_one, names, progress, max_image_size, exhaustive_max)
    except BaseException:       # failed, stopped or the disk full: nothing half made stays in the cache
        shutil.rmtree(work, ignore_errors=True)
        raise


def _triangulated_points(pycolmap, work, load_one, names, progress, max_image_size, exhaustive_max):
    """The work of :func:`triangulate_frames` once its cache entry ``work`` is made: the images
    written, triangulated, the result saved as ``work/points.npz`` and the rest removed."""
    img_dir, result = work / "images", work / "points.npz"
    cameras, safe, frame_of = [], [], []   # frame_of[k]: the index into names of safe[k]
    for i in range(len(names)):
        got = load_one(i)
        if got is None:
            continue
        cam, img = got
        cameras.append(cam)
        frame_of.append(i)
        safe.append(f"{len(safe):05d}.png")
        write_image(img_dir / safe[-1], img)
        del img
    if len(safe) < 2:
        raise RuntimeError(f"only {len(safe)} image(s) could be read for triangulation")
    unit = camera_frame(cameras)        # pycolmap works in the cameras' own frame: any world units give one result
    rec, errors, off, fixed = _triangulate(pycolmap, work, [in_frame(c, unit) for c in cameras], safe, progress,
                                           max_image_size, exhaustive_max)
    reconstruction_to_world(pycolmap, rec, unit)
    for repose in fixed.values():
        repose["cam_from_world"] = pose_to_world(repose["cam_from_world"], unit)
    frame = dict(zip(safe, frame_of))
    pose_error = np.full(len(names), np.nan)
    for s, (e, _) in errors.items():
        pose_error[frame[s]] = e
    pose_off = np.array([frame[s] for s in off], np.int64)
    reposed = {"reposed": np.array([frame[s] for s in fixed], np.int64),
               "reposed_w2c": np.array([fixed[s]["cam_from_world"] for s in fixed], np.float64).reshape(-1, 3, 4),
               "reposed_error": np.array([fixed[s]["error"] for s in fixed], np.float64),
               "reposed_matches": np.array([[fixed[s]["inliers"], fixed[s]["matches"]] for s in fixed],
                                           np.int64).reshape(-1, 2)}
    pts = list(rec.points3D.values())
    if len(pts) < 50:
        raise RuntimeError(f"pycolmap triangulated only {len(pts)} points")
    xyz = np.array([p.xyz for p in pts], np.float64)
    rgb = np.array([p.color for p in pts], np.float64) / 255.0
    err = float(rec.compute_mean_reprojection_error())
    tracks = tracks_of_points(rec, pts, frame)
    tmp = work / f"points.tmp{os.getpid()}.npz"
    np.savez(tmp, xyz=xyz, rgb=rgb, err=err, track_offsets=tracks[0], track_frames=tracks[1], pose_error=pose_error,
             pose_off=pose_off, **reposed)
    os.replace(tmp, result)
    trim(work, "tri")
    return xyz, rgb, {"mean_reprojection_error": err, "reconstruction": rec, "work": str(work), "tracks": tracks,
                      "pose_error": pose_error, "pose_off": pose_off, **reposed}


def _triangulate(pycolmap, work, cameras, safe, progress, max_image_size, exhaustive_max):
    """Features, matches and pycolmap's point triangulator on the PNGs ``work/images/<safe>``."""
    img_dir = work / "images"
    db = work / "database.db"
    prog = _Progress(progress, 4, f"triangulating points from {len(safe)} posed images")
    try:
        pairs = None if len(safe) <= exhaustive_max else _neighbour_pairs(cameras, safe)
        prog.stage("extracting SIFT features", 0)
        _extract_and_match(pycolmap, db, img_dir, safe, pycolmap.CameraMode.PER_IMAGE, "PINHOLE",
                           pairs=pairs, max_image_size=max_image_size, progress=prog,
                           small_images=max(cameras[0].width, cameras[0].height) < 1200)
        posed = _posed_reconstruction(pycolmap, db, cameras, safe)
        errors = pose_errors(pycolmap, db, posed)      # each photo's matches against its pose
        off = left_out(errors)
        # a wrong pose: out of the reconstruction, so none of its matches makes a point
        rec = _posed_reconstruction(pycolmap, db, cameras, safe, skip=set(off)) if off else posed
        prog.stage("matching along the known epipolar lines")
        guided = [p for p in _neighbour_pairs(cameras, safe, k=GUIDED_NEIGHBOURS) if not set(p) & set(off)]
        add_guided_matches(pycolmap, db, rec, guided,
                           on_pair=lambda k, n: prog.note(f"matching along the known epipolar lines: pair {k}/{n}"))
        prog.stage("triangulating")
        rec = _triangulate_posed(pycolmap, rec, db, img_dir, work / "sparse")
        if off:
            prog.note(f"posing {len(off)} photo(s) again from their matches")
        fixed = reposed_photos(pycolmap, db, rec, posed, cameras, safe, off, errors, _posed_reconstruction) if off else {}
        if fixed:   # posed again from their matches: triangulated again with them in
            prog.note(f"triangulating again with {len(fixed)} photo(s) posed again")
            cameras = [with_pose(c, fixed[s]["cam_from_world"]) if s in fixed else c for c, s in zip(cameras, safe)]
            off = [s for s in off if s not in fixed]
            rec = _posed_reconstruction(pycolmap, db, cameras, safe, skip=set(off))
            add_guided_matches(pycolmap, db, rec, [p for p in _neighbour_pairs(cameras, safe, k=GUIDED_NEIGHBOURS)
                                                   if set(p) & set(fixed) and not set(p) & set(off)])
            rec = _triangulate_posed(pycolmap, rec, db, img_dir, work / "sparse2")
        prog.stage("done")
    except Exception as exc:
        raise RuntimeError(f"pycolmap triangulation failed: {str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__}") from None
    finally:
        prog.close()
    return rec, errors, off, fixed


def _triangulate_posed(pycolmap, rec, db, img_dir, out):
    """pycolmap's point triangulator on the posed reconstruction ``rec`` (poses held fixed)."""
    out.mkdir(exist_ok=True)
    opts = pycolmap.IncrementalPipelineOptions()
    opts.num_threads = sfm_threads()
    opts.triangulation.min_angle = TRIANGULATION_MIN_ANGLE
    opts.mapper.filter_min_tri_angle = TRIANGULATION_MIN_ANGLE
    opts.triangulation.ignore_two_view_tracks = False
    return pycolmap.triangulate_points(rec, db, img_dir, out, options=opts)


def reprojection_errors(rec, cameras: list, names: list | None = None) -> np.ndarray:
    """Pixel distances between each observation of a pycolmap reconstruction and the projection
    of its 3D point with our :class:`Camera` objects.

    Args:
        rec: ``pycolmap.Reconstruction``.
        cameras: cameras matched to the reconstruction's images by ``names`` (image names), or by
            the ``NNNNN.png`` index names that :func:`triangulate_known_poses` uses when None.
    """
    errs = []
    lookup = {n: i for i, n in enumerate(names)} if names is not None else None
    for im in rec.images.values():
        i = lookup.get(im.name) if lookup is not None else int(Path(im.name).stem)
        if i is None:
            continue
        cam = cameras[i]
        obs = [(p.xy, rec.points3D[p.point3D_id].xyz) for p in im.points2D if p.has_point3D()]
        if not obs:
            continue
        xy = np.array([o[0] for o in obs])
        X = np.array([o[1] for o in obs])
        xc = X @ cam.R.T + cam.t
        uv = np.stack([cam.fx * xc[:, 0] / xc[:, 2] + cam.cx, cam.fy * xc[:, 1] / xc[:, 2] + cam.cy], 1)
        errs.append(np.linalg.norm(uv - xy, axis=1))
    return np.concatenate(errs) if errs else np.zeros(0)
