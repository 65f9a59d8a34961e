"""Atomic file writes: the data goes to a temp file in the target's folder, is flushed to disk
(fsync) and renamed over the target with :func:`os.replace`. A reader never sees a half-written
file; on any failure the target is untouched and the temp file is removed, and the failure is a
:class:`WriteError` (one line naming the path and the cause: disk full, read-only, permission).
A temp file left by a killed process (``.<name>.tmp<PID>-...``) is removed by
:func:`remove_orphans` when the next run starts in that folder."""

from __future__ import annotations

import errno
import itertools
import json
import os
import re
import threading
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from ..errors import UserError

_counter = itertools.count()
#: the temp names of :func:`_temp_name`: group 1 is the writing process's id
_TEMP = re.compile(r"^\..+\.tmp(\d+)-\d+-\d+(\.[A-Za-z0-9]+)?$")

#: errno -> (cause, what to do) for the write failures a user can fix
_CAUSES = {
    errno.ENOSPC: ("No space left on device (disk full)", "free some space or write elsewhere"),
    errno.EDQUOT: ("disk quota exceeded", "free some space or write elsewhere"),
    errno.EROFS: ("the file system is read-only", "write elsewhere"),
    errno.EACCES: ("permission denied", "write elsewhere or fix the folder's permissions"),
    errno.EPERM: ("operation not permitted", "write elsewhere or fix the folder's permissions"),
    errno.ENOTDIR: ("a part of the path is a file, not a folder", "write elsewhere"),
    errno.ENOENT: ("its folder does not exist", "create the folder or write elsewhere"),
}


class WriteError(UserError, OSError):
    """A file could not be written (disk full, read-only, permission...): one line naming the
    path and the cause. An :class:`OSError` as well, for callers that catch those."""


def describe(exc: OSError):
    """``(cause, what to do)`` in words for an :class:`OSError` of a write."""
    return _CAUSES.get(exc.errno, (exc.strerror or str(exc), "check the folder and the disk"))


def write_error(path, exc: OSError) -> WriteError:
    """The :class:`WriteError` of ``exc`` (an :class:`OSError`) raised while writing ``path``."""
    if isinstance(exc, WriteError):
        return exc
    cause, fix = describe(exc)
    err = WriteError(f"cannot write {path}: {cause}; {fix}")
    err.errno = exc.errno
    return err


def _temp_name(path: Path, keep_suffix: bool) -> Path:
    tag = f"tmp{os.getpid()}-{threading.get_ident()}-{next(_counter)}"
    if keep_suffix:                      # writers that pick the format from the extension
        return path.with_name(f".{path.stem}.{tag}{path.suffix}")
    return path.with_name(f".{path.name}.{tag}")


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:                      # exists, owned by someone else
        return True
    return True


def remove_orphans(folder) -> list:
    """Remove the temp files of :func:`atomic_path` in ``folder`` whose writing process is gone
    (a run killed while writing). Returns the names removed."""
    removed = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for e in entries:
        m = _TEMP.match(e.name)
        if m and e.is_file(follow_symlinks=False) and not _alive(int(m.group(1))):
            try:
                os.unlink(e.path)
                removed.append(e.name)
            except OSError:
                pass
    return removed


def _fsync(path: Path):
    with open(path, "rb") as f:
        os.fsync(f.fileno())


@contextmanager
def atomic_path(path, keep_suffix=False):
    """Yield a temp path next to ``path``; write it by name, and on a clean exit it is fsynced
    and renamed over ``path``. ``keep_suffix`` keeps ``path``'s extension on the temp name
    (for writers that choose the format from it: images, matplotlib)."""
    path = Path(path)
    tmp = _temp_name(path, keep_suffix)
    try:
        yield tmp
        _fsync(tmp)
        os.replace(tmp, path)
    except OSError as exc:
        raise write_error(path, exc) from None
    finally:
        try:
            tmp.unlink()
        except OSError:                  # renamed (the usual case) or never created
            pass


def atomic_write(path, write, mode="wb"):
    """Write ``path`` atomically: ``write(f)`` fills the open temp file ``f`` (opened with ``mode``)."""
    with atomic_path(path) as tmp:
        with open(tmp, mode) as f:
            write(f)


def write_bytes(path, data: bytes):
    atomic_write(path, lambda f: f.write(data))


def write_text(path, text: str):
    atomic_write(path, lambda f: f.write(text), mode="w")


def write_json(path, obj, indent=2, default=None):
    """``json.dumps(obj, indent=indent, default=default)`` and a trailing newline."""
    write_text(path, json.dumps(obj, indent=indent, default=default) + "\n")


def to_uint8(img):
    """[H, W, C] float in [0, 1] -> uint8 (clipped, rounded half up)."""
    return (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)


def write_image(path, img):
    """Write a float image [H, W, C] in [0, 1] (or uint8) as PNG/JPEG/... chosen by the extension."""
    import imageio.v3 as iio
    img = np.asarray(img)
    data = img if img.dtype == np.uint8 else to_uint8(img)
    path = Path(path)
    try:       # encoded in memory: a full disk then fails in our write, not inside the image plugin
        encoded = iio.imwrite("<bytes>", data, extension=path.suffix.lower() or ".png")
    except (TypeError, ValueError, OSError):     # a format that needs a file: written by name
        with atomic_path(path, keep_suffix=True) as tmp:
            iio.imwrite(tmp, data)
        return
    write_bytes(path, encoded)
