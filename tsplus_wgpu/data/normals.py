"""Normal-map priors for the optional normal loss (``tsplus train --normals DIR``).

Convention: one file per view, named like the view's image (same stem, e.g. ``view_003.npy``
or ``view_003.png`` for ``view_003.jpg``; a path relative to the image folder keeps its
sub-folders), holding the surface normal in the view's **camera space, OpenCV convention**
(x right, y down, z forward, i.e. the camera looks down +z) and **facing the camera** (so a
visible surface has mostly z < 0):

* ``.npy``: float ``[H, W, 3]``, the normal itself;
* ``.png``: 8- or 16-bit RGB(A), ``rgb = (n + 1) / 2``; alpha 0 marks pixels without a prior.

A pixel is used when its decoded normal has length in [0.5, 1.5] (it is then normalised):
zero vectors (grey 128,128,128 in a PNG), black, NaN and alpha-0 pixels are ignored. Maps of
another size are area-resized to the view's (loaded, undistorted, downscaled) size with a
warning; a different aspect ratio is an error. Maps that look like another convention
(mean z > 0: facing away, e.g. OpenGL axes) get a warning. Training views without a map get
no normal loss; an unreadable or malformed file is a one-line :class:`SceneError` naming it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import SceneError

NORMAL_EXTENSIONS = (".npy", ".png")
#: A prior pixel is used when its decoded normal's length is in this range (then normalised):
#: grey (128,128,128) = the zero vector, black = (-1,-1,-1) of length 1.73 and NaN are left out.
PRIOR_MIN_LENGTH = 0.5
PRIOR_MAX_LENGTH = 1.5


def prepare_prior(normals, alpha=None):
    """A raw normal map ``[H, W, 3]`` (decoded to [-1, 1]) -> ``(unit prior [H, W, 3] float32,
    valid [H, W] bool)``: pixels whose length is outside [0.5, 1.5], not finite, or whose
    ``alpha`` (optional ``[H, W]``) is 0 are invalid (prior 0 there)."""
    n = np.asarray(normals, np.float64)
    if n.ndim != 3 or n.shape[2] != 3:
        raise ValueError(f"normal map: expected shape [H, W, 3], got {n.shape}")
    finite = np.all(np.isfinite(n), axis=2)
    n = np.where(finite[..., None], n, 0.0)
    length = np.linalg.norm(n, axis=2)
    valid = finite & (length >= PRIOR_MIN_LENGTH) & (length <= PRIOR_MAX_LENGTH)
    if alpha is not None:
        valid &= np.asarray(alpha) > 0
    unit = np.where(valid[..., None], n / np.where(valid, length, 1.0)[..., None], 0.0)
    return unit.astype(np.float32), valid


@dataclass
class NormalMaps:
    """Normal priors of a scene's views.

    Attributes:
        maps: per view (index into ``scene.images``): ``(prior [H, W, 3] float32 unit normals,
            valid [H, W] bool)`` or None (no map, or not a training view).
        folder: where they were read from.
        missing: names of the training views without a map.
        warnings: resizes, convention hints.
    """

    maps: list
    folder: str = ""
    missing: list = field(default_factory=list)
    warnings: list = field(default_factory=list)

    @property
    def count(self):
        return sum(m is not None for m in self.maps)

    def summary(self, num_train):
        s = f"normal maps: {self.count} of {num_train} training views from {self.folder}"
        if self.missing:
            s += (f"; {len(self.missing)} without a map get no normal loss ("
                  + ", ".join(self.missing[:4]) + (" ..." if len(self.missing) > 4 else "") + ")")
        return s


def decode_png_normals(img):
    """A PNG's RGB(A) in [0, 1] (float) -> ``(normals [H, W, 3] = 2 rgb - 1, alpha or None)``."""
    rgb = np.asarray(img, np.float64)
    alpha = rgb[:, :, 3] if rgb.shape[2] == 4 else None
    return 2.0 * rgb[:, :, :3] - 1.0, alpha


def encode_png_normals(normals, valid=None, bits=16):
    """Normals ``[H, W, 3]`` -> an RGBA ``uint8``/``uint16`` image, ``rgb = (n + 1) / 2``,
    alpha 0 where invalid (``valid`` default: non-zero normals)."""
    n = np.asarray(normals, np.float64)
    if valid is None:
        valid = np.linalg.norm(n, axis=2) > 0
    top = 65535 if bits == 16 else 255
    rgb = np.clip(np.round((n + 1.0) * 0.5 * top), 0, top)
    a = np.where(valid, top, 0)[..., None]
    return np.concatenate([rgb, a], axis=2).astype(np.uint16 if bits == 16 else np.uint8)


def read_normal_file(path):
    """Read one normal map: ``(normals [H, W, 3] float64, alpha [H, W] or None)``.

    Raises:
        SceneError: unreadable, wrong shape or dtype, an 8/16-bit PNG expected.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".npy":
        try:
            arr = np.load(path, allow_pickle=False)
        except Exception as exc:
            raise SceneError(f"{path}: not a readable .npy normal map ({type(exc).__name__}: {exc})") from None
        if arr.ndim != 3 or arr.shape[2] != 3 or min(arr.shape[:2]) < 1:
            raise SceneError(f"{path}: normal map must have shape [H, W, 3], got {list(arr.shape)}")
        if not np.issubdtype(arr.dtype, np.floating):
            raise SceneError(f"{path}: normal map must hold floats (the normal, in [-1, 1]), got dtype {arr.dtype}")
        return arr.astype(np.float64), None
    if suffix == ".png":
        from .images import _cv2
        cv2 = _cv2()
        data = np.fromfile(str(path), dtype=np.uint8) if path.is_file() else np.zeros(0, np.uint8)
        img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
        if img is None or img.size == 0:
            raise SceneError(f"{path}: not a readable PNG normal map")
        if img.dtype not in (np.uint8, np.uint16):
            raise SceneError(f"{path}: normal map PNG must be 8- or 16-bit, got {img.dtype}")
        if img.ndim != 3 or img.shape[2] not in (3, 4):
            raise SceneError(f"{path}: normal map PNG must be RGB or RGBA (rgb = (n + 1) / 2), got "
                             f"{1 if img.ndim == 2 else img.shape[2]} channel(s)")
        top = 65535.0 if img.dtype == np.uint16 else 255.0
        img = img[:, :, [2, 1, 0, 3][:img.shape[2]]].astype(np.float64) / top
        return decode_png_normals(img)
    raise SceneError(f"{path}: normal maps must be .npy or .png")


def _resize_prior(prior, valid, width, height):
    from .images import resize_area
    acc = resize_area((prior * valid[..., None]).astype(np.float32), width, height).astype(np.float64)
    frac = resize_area(valid.astype(np.float32), width, height).astype(np.float64)
    if frac.ndim == 3:
        frac = frac[..., 0]
    length = np.linalg.norm(acc, axis=2)
    ok = (frac >= 0.5) & (length > 0.25 * frac)
    unit = np.where(ok[..., None], acc / np.where(ok, length, 1.0)[..., None], 0.0)
    return unit.astype(np.float32), ok


def find_normal_file(folder, image_name):
    """The map of an image named ``image_name`` in ``folder`` (same relative path with a
    .npy/.png suffix, else the same stem at the folder's top), or None."""
    folder = Path(folder)
    rel = Path(image_name)
    for base in (folder / rel.parent / rel.stem, folder / rel.stem):
        for ext in NORMAL_EXTENSIONS:
            p = base.with_name(base.name + ext)
            if p.is_file():
                return p
    return None


def load_normal_map(path, camera):
    """One view's prior at ``camera``'s size: ``(prior, valid, warnings)``."""
    raw, alpha = read_normal_file(path)
    prior, valid = prepare_prior(raw, alpha)
    warnings = []
    h, w = prior.shape[:2]
    if (w, h) != (camera.width, camera.height):
        sx, sy = camera.width / w, camera.height / h
        if abs(sx - sy) > 0.02 * max(sx, sy) + 1.0 / min(w, h):
            raise SceneError(f"{path}: normal map is {w}x{h} but its view is {camera.width}x{camera.height} "
                             "(different aspect ratio); give maps of the training images")
        prior, valid = _resize_prior(prior, valid, camera.width, camera.height)
        warnings.append(f"{path}: normal map is {w}x{h}, resized (area) to the view's {camera.width}x{camera.height}")
    if valid.any():
        mz = float(prior[valid][:, 2].mean())
        if mz > 0.0:
            warnings.append(f"{path}: normals face away from the camera on average (mean z {mz:+.2f}); expected "
                            "OpenCV camera space (x right, y down, z forward) with normals towards the camera "
                            "(an OpenGL-convention map has y and z negated)")
    return prior, valid, warnings


def load_normal_maps(scene, folder, views=None) -> NormalMaps:
    """The normal priors of ``scene``'s ``views`` (default: its training views) from ``folder``.

    Raises:
        SceneError: ``folder`` is not a folder, or a map is unreadable or malformed.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise SceneError(f"--normals {folder}: no such folder")
    views = list(scene.train_indices if views is None else views)
    out = NormalMaps(maps=[None] * len(scene.images), folder=str(folder))
    resized, away = [], []
    for v in views:
        name = scene.image_names[v]
        path = find_normal_file(folder, name)
        if path is None:
            out.missing.append(name)
            continue
        prior, valid, warns = load_normal_map(path, scene.cameras[v])
        for wmsg in warns:
            (resized if "resized (area)" in wmsg else away if "face away" in wmsg else out.warnings).append(wmsg)
        if not valid.any():
            out.warnings.append(f"{path}: no usable pixel (every normal is zero, black or masked); view skipped")
            out.missing.append(name)
            continue
        out.maps[v] = (prior, valid)
    if resized:
        out.warnings.insert(0, f"{len(resized)} normal map(s) resized (area) to their views' size, e.g. {resized[0]}")
    if away:
        out.warnings.append(f"{len(away)} normal map(s) look like another convention, e.g. {away[0]}")
    return out


def write_normal_maps(folder, scene, maps, fmt="npy"):
    """Write ``maps`` (per view ``[H, W, 3]`` normals, zero = no prior, or None) as
    ``<image stem>.npy`` (float32) or 16-bit RGBA ``.png`` into ``folder``. Returns the paths."""
    from .images import _cv2
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, n in zip(scene.image_names, maps):
        if n is None:
            continue
        rel = Path(name)
        path = folder / rel.parent / (rel.stem + "." + fmt)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.tmp")
        if fmt == "npy":
            with open(tmp, "wb") as f:
                np.save(f, np.asarray(n, np.float32))
        elif fmt == "png":
            img = encode_png_normals(n)
            ok, buf = _cv2().imencode(".png", img[:, :, [2, 1, 0, 3]])
            if not ok:  # pragma: no cover
                raise SceneError(f"{path}: could not encode the normal map")
            tmp.write_bytes(buf.tobytes())
        else:
            raise ValueError(f"format: expected npy or png, got {fmt!r}")
        tmp.replace(path)
        paths.append(path)
    return paths
