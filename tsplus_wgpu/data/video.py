"""A video as a scene: its sharpest frames, in time order, as a folder of photos.

* :func:`sharpness`: the variance of the Laplacian of a frame's grey image, in float64 NumPy.
* :func:`choose_frames`: the sharpest frame of each of ``count`` equal windows of the video.
* :func:`extract_frames`: decodes a video twice (the sharpness of every frame, then the chosen
  ones) and writes the chosen frames as JPEG files with a manifest (:data:`MANIFEST`), into a
  temporary folder renamed into place at the end: a killed extraction leaves nothing half-done.
* :func:`video_frames_dir`: the frames of a video in the user cache, keyed by the video's bytes.

A folder with a manifest (made here, or by ``tsplus frames``) is what the photo SfM
(:func:`~tsplus_wgpu.data.photos.run_photos_sfm`) matches in time order: each frame with its
neighbours, not every pair.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
from pathlib import Path

import numpy as np

from .errors import SceneError

#: file name endings read as videos (whatever OpenCV's FFmpeg decodes)
VIDEO_EXTENSIONS = (".mp4", ".mov", ".m4v", ".avi", ".mkv", ".webm", ".mpg", ".mpeg", ".3gp", ".wmv")
#: frames kept of a video when nobody asks for a number (``tsplus frames --count``)
DEFAULT_FRAMES = 100
#: the manifest a frames folder holds: the video, the frames decoded and the ones kept
MANIFEST = "frames.json"
#: the extraction's version in the cache key: frames of an older recipe are not reused
RECIPE = "v1"
JPEG_QUALITY = 95
#: frames are scored on a grey image shrunk by whole blocks to at most this many pixels a side
SCORE_SIZE = 640


def is_video(path) -> bool:
    """Whether ``path`` names a video file by its ending (:data:`VIDEO_EXTENSIONS`)."""
    return Path(path).suffix.lower() in VIDEO_EXTENSIONS


def is_frames_folder(folder) -> bool:
    """Whether ``folder`` holds the frames of a video (its :data:`MANIFEST`): they are in time order."""
    return (Path(folder) / MANIFEST).is_file()


def sharpness(frame: np.ndarray) -> float:
    """How sharp a frame ``[H, W, 3]`` (uint8, BGR as OpenCV decodes) is: the variance of the
    5-point Laplacian (float64 NumPy) of its grey image, shrunk by the whole block size that
    brings its long side to at most :data:`SCORE_SIZE` (block means), so that a blur of the same
    size on screen scores the same at any resolution. The grey image and the block means are
    OpenCV's integer arithmetic (``cvtColor``, ``INTER_AREA`` by a whole factor), the same on
    every machine, and fast: a 4K frame in about 10 ms."""
    cv2 = _cv2()
    grey = cv2.cvtColor(np.ascontiguousarray(frame), cv2.COLOR_BGR2GRAY)
    b = max(1, -(-max(grey.shape) // SCORE_SIZE))
    if b > 1:
        h, w = grey.shape[0] // b * b, grey.shape[1] // b * b
        grey = cv2.resize(grey[:h, :w], (w // b, h // b), interpolation=cv2.INTER_AREA)
    if min(grey.shape) < 3:
        return 0.0
    g = grey.astype(np.float64)
    lap = (g[1:-1, :-2] + g[1:-1, 2:] + g[:-2, 1:-1] + g[2:, 1:-1]) - 4.0 * g[1:-1, 1:-1]
    return float(lap.var())


def choose_frames(scores, count: int) -> list:
    """Indices of the frames kept: the video's frames cut into ``min(count, frames)`` windows of
    (as nearly as possible) equal length, and the sharpest frame of each (the first on a tie)."""
    scores = np.asarray(scores, np.float64)
    n = len(scores)
    k = min(int(count), n)
    if k <= 0:
        return []
    bounds = (np.arange(k + 1) * n) // k
    return [int(a + np.argmax(scores[a:b])) for a, b in zip(bounds[:-1], bounds[1:])]


def _cv2():
    # FFmpeg's own messages (a damaged file's "moov atom not found", ...) would come before the one
    # line that says what to do: only its fatal ones, unless the user asks for more
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "8")
    from .images import _cv2 as load  # noqa: PLC0415
    return load()


def _open(cv2, video: Path):
    cap = cv2.VideoCapture(str(video))
    cap.set(cv2.CAP_PROP_ORIENTATION_AUTO, 1)     # a phone's portrait video comes out upright (the default)
    if not cap.isOpened():
        raise SceneError(f"{video}: cannot be read as a video (an unknown format or a damaged file); convert it to "
                         "MP4 (H.264), or extract its frames into a folder of photos")
    return cap


def _bar(progress: bool, total, desc: str):
    if not progress:
        return None
    from tqdm import tqdm  # noqa: PLC0415
    return tqdm(total=total or None, desc=desc, unit="frame", file=sys.stderr, leave=True)


def _decode(cv2, video: Path, progress: bool, desc: str, total=None):
    """Every frame of ``video`` in order, with a progress bar (``progress``) over ``total`` frames
    (default: the count the container states)."""
    cap = _open(cv2, video)
    bar = _bar(progress, total or int(max(0.0, cap.get(cv2.CAP_PROP_FRAME_COUNT))), desc)
    try:
        while True:
            ok, frame = cap.read()
            if not ok or frame is None:
                return
            if bar is not None:
                bar.update(1)
            yield frame
    finally:
        cap.release()
        if bar is not None:
            bar.close()


def _write_jpeg(cv2, path: Path, frame: np.ndarray):
    ok, buf = cv2.imencode(".jpg", frame, [int(cv2.IMWRITE_JPEG_QUALITY), JPEG_QUALITY])
    if not ok:
        raise SceneError(f"{path}: OpenCV could not encode the frame as JPEG; check the video")
    with open(path, "wb") as f:        # an OSError (disk full, read-only) names the file
        f.write(buf.tobytes())


def extract_frames(video, out_dir, count: int = DEFAULT_FRAMES, progress: bool = False) -> dict:
    """Write the sharpest frame of each of ``count`` windows of ``video`` into ``out_dir`` as
    ``frame_NNNNNN.jpg`` (N: the frame's index in the video, so the names sort in time order) with
    :data:`MANIFEST`; ``out_dir`` must not exist yet. Returns the manifest.

    Raises:
        SceneError: the video cannot be read, holds fewer than 3 frames, or decodes differently
            the second time.
    """
    cv2 = _cv2()
    video, out_dir = Path(video), Path(out_dir)
    if int(count) < 3:
        raise SceneError(f"frame count {count}: SfM needs at least 3 frames; ask for more")
    scores = [sharpness(f) for f in _decode(cv2, video, progress, f"scoring the frames of {video.name}")]
    n = len(scores)
    if n < 3:
        raise SceneError(f"{video}: {n} frame(s) decoded, SfM needs at least 3; give a longer video or a folder of "
                         "photos")
    chosen = choose_frames(scores, count)
    width = max(6, len(str(n - 1)))
    tmp = out_dir.parent / f".{out_dir.name}.part{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    try:
        want, written = set(chosen), []
        for i, frame in enumerate(_decode(cv2, video, progress, f"writing the {len(chosen)} sharpest",
                                           chosen[-1] + 1)):
            if i in want:
                _write_jpeg(cv2, tmp / f"frame_{i:0{width}d}.jpg", frame)
                written.append(i)
            if i == chosen[-1]:
                break
        if written != chosen:
            raise SceneError(f"{video}: decoding stopped at frame {written[-1] if written else 0} the second time "
                             f"(of {n}); the file may be damaged: convert it to MP4 (H.264)")
        manifest = dict(video=str(video.resolve()), frames_decoded=n, count=int(count), recipe=RECIPE,
                        frames=[f"frame_{i:0{width}d}.jpg" for i in chosen], indices=chosen,
                        sharpness=[round(scores[i], 6) for i in chosen])
        (tmp / MANIFEST).write_text(json.dumps(manifest, indent=1))
        os.replace(tmp, out_dir)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return manifest


def video_frames_dir(video, cache=None, count: int = DEFAULT_FRAMES, progress: bool = False, warnings=None) -> Path:
    """The folder of ``video``'s chosen frames (:func:`extract_frames`) in the user cache
    (:func:`~tsplus_wgpu.data.sfm.cache_root`), extracted on the first call and reused while the
    video's bytes, ``count`` and :data:`RECIPE` are unchanged."""
    from .cache import mark_used  # noqa: PLC0415
    from .sfm import cache_root, file_digest  # noqa: PLC0415
    video = Path(video)
    warnings = warnings if warnings is not None else []
    root, note = cache_root(None, cache)
    if note:
        warnings.append(note)
    key = hashlib.sha1(f"{RECIPE}|{int(count)}|{file_digest(video)}".encode()).hexdigest()
    work = root / f"video_{key[:16]}"
    frames = work / "frames"
    if is_frames_folder(frames):
        warnings.append(f"reused cached frames of {video.name}: {frames}")
        mark_used(work)
        return frames
    try:
        work.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SceneError(f"{work}: cannot create the frames' cache folder ({exc.strerror}); set TSPLUS_CACHE or "
                         "XDG_CACHE_HOME to a writable folder") from None
    shutil.rmtree(frames, ignore_errors=True)     # an unfinished folder without its manifest
    try:
        extract_frames(video, frames, count, progress)
    except BaseException:       # unreadable, stopped or the disk full: nothing half made stays in the cache
        shutil.rmtree(work, ignore_errors=True)
        raise
    return frames


def read_manifest(folder) -> dict:
    """The manifest of a frames folder ({} when it has none or it cannot be read)."""
    try:
        return json.loads((Path(folder) / MANIFEST).read_text())
    except (OSError, ValueError):
        return {}
