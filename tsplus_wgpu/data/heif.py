"""HEIC / HEIF photos (what iPhones take by default), converted once to JPEG in the cache.

Neither OpenCV nor COLMAP reads HEIF. A folder of photos that holds ``.heic`` / ``.heif``
files is mirrored into the user cache (:func:`~tsplus_wgpu.data.sfm.cache_root`) by
:func:`jpeg_folder`: each HEIF photo is decoded by pillow-heif, its rotation applied (upright, as
a photo viewer shows it), and written as a JPEG of quality :data:`JPEG_QUALITY` named after the
original with ``.jpg`` appended (``IMG_0001.HEIC.jpg``: no clash with a JPEG of the same stem,
and the same natural name order). The JPEG keeps the photo's EXIF, so make, model, lens and
focal length still tell lenses apart (:func:`~tsplus_wgpu.data.photos.camera_groups`), with the
orientation set to 1 since the pixels are now upright. The folder's other photos are hard-linked
(or copied where links fail), so the mirror outlives the original folder. The mirror is keyed by every photo's name and bytes, written into a
temporary folder and renamed, and reused while the photos are unchanged; SfM, training and
evaluation then read it as the folder of photos.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path

from .errors import SceneError
from .images import IMAGE_EXTENSIONS

HEIF_EXTENSIONS = (".heic", ".heif", ".hif")
JPEG_QUALITY = 95
#: part of the cache key: change it when the conversion changes
RECIPE = "heif-jpeg95-v1"
_ORIENTATION = 0x0112


def heif_names(folder) -> list:
    """Sorted names of the HEIF photos directly inside ``folder`` (hidden files left out)."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    return sorted(p.name for p in folder.iterdir()
                  if p.is_file() and p.suffix.lower() in HEIF_EXTENSIONS and not p.name.startswith("."))


def _opener(first: Path):
    """PIL with pillow-heif's opener registered (a one-line error naming ``first`` without it)."""
    try:
        import pillow_heif  # noqa: PLC0415
        from PIL import Image  # noqa: PLC0415
    except ImportError:
        raise SceneError(f"{first}: HEIC/HEIF photos need the pillow-heif package: pip install pillow-heif "
                         "(or convert the photos to JPEG)") from None
    pillow_heif.register_heif_opener()
    return Image


def convert_heif(src: Path, dst: Path, Image=None) -> None:
    """Write the HEIF photo ``src`` as the JPEG ``dst``: upright, 8-bit RGB, its EXIF kept with the
    orientation set to 1. Raises :class:`SceneError` naming ``src`` when it cannot be decoded."""
    Image = Image or _opener(src)
    try:
        with Image.open(src) as im:
            im.load()
            exif = im.getexif()
            rgb = im.convert("RGB") if im.mode != "RGB" else im.copy()
    except Exception as exc:   # damaged or not HEIF at all: pillow-heif raises several kinds
        raise SceneError(f"{src}: cannot be decoded as a HEIC/HEIF photo ({type(exc).__name__}); replace it "
                         "with the original or convert it to JPEG") from None
    exif[_ORIENTATION] = 1                 # pillow-heif applied the rotation to the pixels
    rgb.save(dst, format="JPEG", quality=JPEG_QUALITY, exif=exif.tobytes())


def _key(photo_dir: Path, names: list) -> str:
    from .sfm import file_digest  # noqa: PLC0415
    h = hashlib.sha1(f"{RECIPE}|".encode())
    for n in names:
        h.update(f"{n}|{file_digest(photo_dir / n)}\n".encode())
    return h.hexdigest()


def _link_or_copy(src: Path, dst: Path) -> None:
    """A hard link (it outlives a moved or deleted original; a symbolic link would not), else a copy."""
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def _complete(out: Path, done: Path) -> bool:
    """Whether the mirror ``out`` holds every photo its record ``done`` lists."""
    try:
        rec = json.loads(done.read_text())
        want = list(rec["others"]) + [f"{n}.jpg" for n in rec["converted"]]
    except (OSError, ValueError, KeyError, TypeError):
        return False
    return out.is_dir() and all((out / n).is_file() for n in want)


def jpeg_folder(photo_dir, cache=None, progress: bool = False, warnings=None) -> Path:
    """The folder of ``photo_dir``'s photos with every HEIF photo as a JPEG (module docstring), in
    the user cache; made on the first call, reused while the photos are unchanged. A HEIF photo
    that cannot be decoded is left out with a warning naming it."""
    from .sfm import cache_root  # noqa: PLC0415
    photo_dir = Path(photo_dir)
    warnings = warnings if warnings is not None else []
    heif = heif_names(photo_dir)
    others = sorted(p.name for p in photo_dir.iterdir()
                    if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS and not p.name.startswith("."))
    root, note = cache_root(None, cache)
    if note:
        warnings.append(note)
    work = root / f"heif_{_key(photo_dir, sorted(heif + others))[:16]}"
    out, done = work / "photos", work / "done.json"
    if done.is_file() and _complete(out, done):
        warnings.extend(json.loads(done.read_text()).get("warnings", []))
        warnings.append(f"reused the JPEG copies of {len(heif)} HEIC/HEIF photos: {out}")
        return out
    Image = _opener(photo_dir / heif[0])
    tmp = work / f"photos.tmp{os.getpid()}"
    try:
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
    except OSError as exc:
        raise SceneError(f"{work}: cannot create the cache folder for the JPEG copies of the HEIC photos "
                         f"({exc.strerror}); set TSPLUS_CACHE or XDG_CACHE_HOME to a writable folder") from None
    skipped, first_error = [], None
    try:
        for n in others:
            _link_or_copy(photo_dir / n, tmp / n)
        for n in _bar(heif, progress):
            try:
                convert_heif(photo_dir / n, tmp / f"{n}.jpg", Image)
            except SceneError as exc:
                first_error = first_error or exc
                skipped.append(f"skipped {exc}")
        if first_error is not None and len(skipped) == len(heif) and not others:
            raise first_error       # nothing readable: the first photo's own error
        shutil.rmtree(out, ignore_errors=True)
        tmp.rename(out)
    except SceneError:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    except OSError as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        raise SceneError(f"{work}: cannot write the JPEG copies of the HEIC photos ({exc.strerror}); free some "
                         "disk space or set TSPLUS_CACHE to another folder") from None
    converted = [n for n in heif if (out / f"{n}.jpg").is_file()]
    done.write_text(json.dumps({"folder": str(photo_dir), "heif": heif, "converted": converted, "others": others,
                                "warnings": skipped}))
    warnings.extend(skipped)
    return out


def _bar(names, progress):
    if not progress or len(names) < 2:
        return names
    try:
        from tqdm import tqdm  # noqa: PLC0415
    except ImportError:  # pragma: no cover
        return names
    # shown after a second: a folder of damaged files fails at once with its one error line
    return tqdm(names, desc="HEIC photos to JPEG", unit="photo", leave=False, delay=1.0)
