"""Image file reading, alpha compositing and resizing.

All images handed to the trainer are float32 ``[H, W, 3]`` RGB arrays in
``[0, 1]``.  Reading uses OpenCV (8- and 16-bit, grey, RGB and RGBA files).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .errors import SceneError

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp", ".exr")


def _cv2():
    try:
        import cv2  # noqa: PLC0415
    except ImportError:  # pragma: no cover - dependency missing
        raise SceneError("OpenCV is missing: install it with `pip install opencv-python-headless`") from None
    return cv2


def list_images(folder: Path) -> list[str]:
    """Sorted names of the image files directly inside ``folder``."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    names = [p.name for p in folder.iterdir()
             if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS and not p.name.startswith(".")]
    return sorted(names)  # plain sort: the order the paper's code (and LLFF) uses


def read_image_size(path: Path) -> tuple[int, int]:
    """(width, height) of an image file without decoding more than needed."""
    try:
        from PIL import Image  # noqa: PLC0415
        with Image.open(path) as im:
            return int(im.size[0]), int(im.size[1])
    except Exception:
        arr = read_image_raw(path)
        return arr.shape[1], arr.shape[0]


def read_image_raw(path: Path) -> np.ndarray:
    """Read an image file as float32 ``[H, W, C]`` in [0, 1], C in {3, 4} (RGB / RGBA).

    Raises:
        SceneError: the file is missing, empty, corrupt or in a format OpenCV cannot decode.
    """
    cv2 = _cv2()
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"{path}: image file not found; restore it or remove it from the model")
    if path.stat().st_size == 0:
        raise SceneError(f"{path}: image file is empty; replace it with the original photo")
    if not os.access(path, os.R_OK):
        raise SceneError(f"{path}: image file is not readable; fix its permissions")
    data = np.fromfile(str(path), dtype=np.uint8)
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if img is None or img.size == 0:
        raise SceneError(f"{path}: image file is corrupt or not a supported image; replace it or delete it")
    if img.dtype == np.uint8:
        out = img.astype(np.float32) / 255.0
    elif img.dtype == np.uint16:
        out = img.astype(np.float32) / 65535.0
    else:
        out = np.clip(img.astype(np.float32), 0.0, None)
    if out.ndim == 2:
        out = np.repeat(out[:, :, None], 3, axis=2)
    elif out.shape[2] == 1:
        out = np.repeat(out, 3, axis=2)
    elif out.shape[2] == 3:
        out = out[:, :, ::-1]
    elif out.shape[2] == 4:
        out = out[:, :, [2, 1, 0, 3]]
    else:
        raise SceneError(f"{path}: unsupported number of channels {out.shape[2]}; save it as RGB")
    return np.ascontiguousarray(out)


def composite(img: np.ndarray, background) -> np.ndarray:
    """Drop alpha by compositing on ``background`` (RGB triple in [0,1]); RGB images pass through."""
    if img.shape[2] == 3:
        return np.ascontiguousarray(img, dtype=np.float32)
    bg = np.zeros(3, np.float32) if background is None else np.asarray(background, np.float32)
    a = img[:, :, 3:4]
    return np.ascontiguousarray(img[:, :, :3] * a + bg * (1.0 - a), dtype=np.float32)


def resize_area(img: np.ndarray, width: int, height: int) -> np.ndarray:
    """Resize with area averaging (downscale) or bilinear (upscale)."""
    if img.shape[1] == width and img.shape[0] == height:
        return img
    cv2 = _cv2()
    interp = cv2.INTER_AREA if width <= img.shape[1] else cv2.INTER_LINEAR
    return np.ascontiguousarray(cv2.resize(img, (int(width), int(height)), interpolation=interp))


def write_image(path: Path, img: np.ndarray) -> None:
    """Write a float RGB [0,1] image as 8-bit (format from the extension)."""
    cv2 = _cv2()
    arr = np.clip(np.asarray(img)[:, :, :3] * 255.0 + 0.5, 0, 255).astype(np.uint8)[:, :, ::-1]
    ok, buf = cv2.imencode(Path(path).suffix or ".png", arr)
    if not ok:  # pragma: no cover
        raise SceneError(f"{path}: could not encode image")
    Path(path).write_bytes(buf.tobytes())
