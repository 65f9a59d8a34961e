"""LLFF scenes: ``poses_bounds.npy`` beside ``images/`` (or ``images_N/``).

Each row holds a 3x5 matrix, camera-to-world rotation columns in LLFF's
(down, right, back) axes, the translation, and (height, width, focal) of the
original images, followed by the near and far depth bounds.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..types import Camera
from .errors import SceneError
from .images import list_images
from .plausible import check_focal, check_size
from .scene import FrameSpec, check_pose


def llff_frames(root: Path, image_dir: Path, warnings: list):
    """FrameSpecs (images sorted by name, matched to the rows in order) and the depth bounds [N, 2]."""
    f = root / "poses_bounds.npy"
    try:
        arr = np.load(f, allow_pickle=False)
    except Exception as exc:
        raise SceneError(f"{f}: cannot be read as a NumPy array ({type(exc).__name__}); regenerate it with LLFF's imgs2poses") from None
    if arr.ndim != 2 or arr.shape[1] != 17 or arr.shape[0] == 0:
        raise SceneError(f"{f}: expected shape [N, 17], got {list(arr.shape)}; regenerate it with LLFF's imgs2poses")
    names = list_images(image_dir)
    if not names:
        raise SceneError(f"{image_dir}: no images found for {f.name}; put the photos in images/")
    if len(names) != arr.shape[0]:
        raise SceneError(f"{f}: {arr.shape[0]} poses but {len(names)} images in {image_dir}; "
                         "the folder must hold exactly the images the poses were computed from")
    frames = []
    bounds = arr[:, 15:17].astype(np.float64)
    for i, name in enumerate(names):
        where = f"{f} (row {i}, {name})"
        m = arr[i, :15].reshape(3, 5).astype(np.float64)
        if not np.all(np.isfinite(m)):
            raise SceneError(f"{where}: pose contains non-finite values (NaN or Inf); fix or remove this image")
        h, w, focal = m[:, 4]
        check_size(h, where, "height (hwf column)")
        check_size(w, where, "width (hwf column)")
        check_focal(focal, w, where, "focal (hwf column)")
        # LLFF columns (down, right, back) -> OpenCV (right, down, forward)
        c2w = np.eye(4)
        c2w[:3, 0] = m[:, 1]
        c2w[:3, 1] = m[:, 0]
        c2w[:3, 2] = -m[:, 2]
        c2w[:3, 3] = m[:, 3]
        try:
            w2c = np.linalg.inv(c2w)
        except np.linalg.LinAlgError:
            raise SceneError(f"{where}: singular pose; fix or remove this image") from None
        check_pose(w2c, where)
        try:
            cam = Camera(int(round(w)), int(round(h)), focal, focal, w / 2, h / 2, w2c)
        except ValueError as exc:
            raise SceneError(f"{where}: {exc}; regenerate poses_bounds.npy") from None
        frames.append(FrameSpec(name=name, path=image_dir / name, camera=cam, source=str(f)))
    if not np.all(np.isfinite(bounds)) or np.any(bounds <= 0):
        warnings.append(f"{f.name}: some depth bounds are not positive finite numbers; they are ignored")
        bounds = None
    return frames, bounds
