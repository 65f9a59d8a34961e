"""What the user cache holds, and clearing it (``tsplus cache``).

The cache (:func:`~tsplus_wgpu.data.sfm.cache_root`) holds one folder an entry, named by its
kind and a key of the content it was made from, so that the same photos reuse it:

* ``tri_<key>``: initial points triangulated from posed images (:func:`~.sfm.triangulate_frames`);
  finished when ``points.npz`` is there;
* ``sfm_<key>``: the SfM model of a folder of photos (:func:`~.photos.run_photos_sfm`);
  ``done.json`` and ``sparse/0``;
* ``video_<key>``: the frames of a video (:func:`~.video.video_frames_dir`); ``frames/frames.json``;
* ``heif_<key>``: JPEG copies of HEIC photos (:func:`~.heif.jpeg_folder`); ``done.json`` and ``photos/``.

A finished entry keeps only what a later load reads (:data:`KEEP`, :func:`trim`): pycolmap's
feature database and its intermediate models are removed once the result is written (fox's
triangulation: 5.6 MB kept of 121 MB). Loading from an entry marks it used (:func:`mark_used`),
so "unused for N days" means what it says. An unfinished entry is what a killed or failed job
left; one changed within :data:`BUSY_SECONDS` may be a running job's and is never removed.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

#: kind (the folder name's prefix) -> what the entry holds
KINDS = {
    "tri": "initial points of posed images",
    "sfm": "SfM model of a photo folder",
    "video": "frames of a video",
    "heif": "JPEG copies of HEIC photos",
}
#: kind -> the names a finished entry keeps (everything else is an intermediate file)
KEEP = {
    "tri": ("points.npz", "about.json", "heldout.npz"),
    "sfm": ("done.json", "sparse"),
    "video": ("frames",),
    "heif": ("done.json", "photos"),
}
#: an unfinished entry changed within this many seconds may belong to a running job
BUSY_SECONDS = 3600.0

__all__ = ["BUSY_SECONDS", "KEEP", "KINDS", "Entry", "human_size", "list_entries", "mark_used", "plan_clean",
           "trim"]


@dataclass(frozen=True)
class Entry:
    """One cache entry: its folder, kind (a key of :data:`KINDS`), whether it is finished, its
    size in bytes (what removing it frees: hard links to the user's photos count nothing), when it was last made or used (seconds since the epoch), what it was made
    from (a folder or file, where the entry records it) and the bytes of intermediate files a
    finished entry still holds (made before :func:`trim` existed)."""
    path: Path
    kind: str
    finished: bool
    size: int
    used: float
    source: str | None
    spare: int = 0


def _kind(path: Path) -> str | None:
    prefix = path.name.split("_", 1)[0]
    return prefix if path.is_dir() and "_" in path.name and prefix in KINDS else None


def _finished(path: Path, kind: str) -> bool:
    if kind == "tri":
        return (path / "points.npz").is_file()
    if kind == "sfm":
        return (path / "done.json").is_file() and (path / "sparse" / "0" / "cameras.bin").is_file()
    if kind == "video":
        return (path / "frames" / "frames.json").is_file()
    return (path / "done.json").is_file() and (path / "photos").is_dir()


def _freed(st) -> int:
    """The bytes removing a file of ``lstat`` result ``st`` frees: none for a hard link to a file
    that stays elsewhere (a HEIC mirror links the folder's JPEG photos), a link's own for a link."""
    return st.st_size if st.st_nlink <= 1 else 0


def _bytes(path: Path) -> int:
    """Bytes that removing ``path`` frees (links never followed; :func:`_freed`)."""
    if not path.is_dir() or path.is_symlink():
        try:
            return _freed(path.lstat())
        except OSError:
            return 0
    total = 0
    for folder, _, files in os.walk(path):
        for f in files:
            try:
                total += _freed(os.lstat(os.path.join(folder, f)))
            except OSError:
                pass
    return total


def _json(path: Path) -> dict:
    try:
        got = json.loads(path.read_text())
        return got if isinstance(got, dict) else {}
    except (OSError, ValueError):
        return {}


def _source(path: Path, kind: str) -> str | None:
    rec = {"tri": path / "about.json", "sfm": path / "done.json", "heif": path / "done.json",
           "video": path / "frames" / "frames.json"}[kind]
    got = _json(rec)
    value = got.get("video" if kind == "video" else "source" if kind == "tri" else "folder")
    return str(value) if value else None


def _used(path: Path) -> float:
    """The newest modification time of the entry folder and the files directly in it."""
    times = []
    for p in [path, *path.iterdir()]:
        try:
            times.append(p.lstat().st_mtime)
        except OSError:
            pass
    return max(times) if times else 0.0


def describe(path) -> Entry | None:
    """The :class:`Entry` of the folder ``path``, or None when it is not a cache entry."""
    path = Path(path)
    kind = _kind(path)
    if kind is None:
        return None
    finished = _finished(path, kind)
    spare = sum(_bytes(p) for p in path.iterdir() if p.name not in KEEP[kind]) if finished else 0
    return Entry(path, kind, finished, _bytes(path), _used(path), _source(path, kind), spare)


def list_entries(root) -> list:
    """The cache entries in the folder ``root``, most recently used first (none when it does not
    exist); other files and folders there are not ours and are left out."""
    root = Path(root)
    if not root.is_dir():
        return []
    found = []
    for p in root.iterdir():
        try:
            found.append(describe(p))
        except OSError:         # removed meanwhile (another `tsplus cache --clean`), or unreadable
            pass
    return sorted((e for e in found if e is not None), key=lambda e: (-e.used, e.path.name))


def mark_used(work) -> None:
    """Record that the entry ``work`` was just used (its folder's modification time); a cache on a
    read-only disk is used all the same."""
    try:
        os.utime(work)
    except OSError:
        pass


def trim(work, kind: str) -> None:
    """Remove what a finished entry ``work`` of ``kind`` no longer needs (everything but
    :data:`KEEP`). Best effort: a file that cannot be removed stays, costing only space."""
    for p in Path(work).iterdir():
        if p.name in KEEP[kind]:
            continue
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            try:
                p.unlink()
            except OSError:
                pass


def plan_clean(entries, everything: bool = False, older_than_days: float | None = None, now: float | None = None):
    """``(remove, trim, busy)``: the entries ``tsplus cache --clean`` removes, each with why
    (unfinished, unused for N days, or ``everything``), the finished ones it only trims of
    intermediate files, and the unfinished ones it leaves because a running job may be writing
    them (changed within :data:`BUSY_SECONDS`)."""
    now = time.time() if now is None else now
    remove, trims, busy = [], [], []
    for e in entries:
        idle = now - e.used
        if not e.finished:
            (busy if idle < BUSY_SECONDS else remove).append((e, "unfinished (a stopped or failed job's)"))
        elif everything:
            remove.append((e, "all asked for"))
        elif older_than_days is not None and idle > older_than_days * 86400.0:
            remove.append((e, f"unused for {idle / 86400.0:.0f} days"))
        elif e.spare:
            trims.append(e)
    return remove, trims, busy


def human_size(nbytes: int) -> str:
    """``nbytes`` as a short figure: 812 B, 4.2 kB, 121.0 MB, 3.4 GB (powers of 1000)."""
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if nbytes >= scale:
            return f"{nbytes / scale:.1f} {unit}"
    return f"{int(nbytes)} B"
