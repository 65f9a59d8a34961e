"""Atomic file writes: the data goes to a temp file in the target's folder, is flushed to disk
(fsync) and renamed over the target with :func:`os.replace`. A reader never sees a half-written
file; on any failure the target is untouched and the temp file is removed."""

from __future__ import annotations

import itertools
import json
import os
import threading
from contextlib import contextmanager
from pathlib import Path

import numpy as np

_counter = itertools.count()


def _temp_name(path: Path, keep_suffix: bool) -> Path:
    tag = f"tmp{os.getpid()}-{threading.get_ident()}-{next(_counter)}"
    if keep_suffix:                      # writers that pick the format from the extension
        return path.with_name(f".{path.stem}.{tag}{path.suffix}")
    return path.with_name(f".{path.name}.{tag}")


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
    finally:
        if tmp.exists():
            tmp.unlink()


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
    with atomic_path(path, keep_suffix=True) as tmp:
        iio.imwrite(tmp, data)
