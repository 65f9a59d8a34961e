"""HEIC / HEIF photos (what iPhones take by default), converted once to JPEG in the cache.

Neither OpenCV nor COLMAP reads HEIF. A folder of photos that holds ``.heic`` / ``.heif``
files is mirrored into the user cache (:func:`~tsplus_wgpu.data.sfm.cache_root`) by
:func:`jpeg_folder`: each HEIF photo is decoded by pillow-heif, its rotation applied (upright, as
a photo viewer shows it), and written as a JPEG of quality :data:`JPEG_QUALITY` named after the
original with ``.jpg`` appended (``IMG_0001.HEIC.jpg``: the same natural name order;
:func:`jpeg_names` avoids the folder's own names). The JPEG keeps the photo's colour profile and
EXIF, so make, model, lens and focal length still tell lenses apart
(:func:`~tsplus_wgpu.data.photos.camera_groups`), with the orientation set to 1 since the pixels
are now upright. The folder's other photos are hard-linked (or copied where links fail), so the
mirror outlives the original folder. The mirror is keyed by every photo's name and bytes,
written into a temporary folder and renamed, and reused while the photos are unchanged; SfM,
training and evaluation then read it as the folder of photos.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import socket
from pathlib import Path

from .errors import SceneError
from .images import list_images
from .upright import EXIF_ORIENTATION as _ORIENTATION

HEIF_EXTENSIONS = (".heic", ".heif", ".hif")
JPEG_QUALITY = 95
#: part of the cache key: change it when the conversion changes
RECIPE = "heif-jpeg95-v1"


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
    """Write the HEIF photo ``src`` as the JPEG ``dst``: upright, 8-bit RGB, its colour profile
    and EXIF kept with the orientation set to 1 (EXIF over a JPEG segment's 64 KB: only the
    camera's make, model, lens and focal lengths). Written beside ``dst`` and renamed, so an
    existing ``dst`` is replaced, never written through. Raises :class:`SceneError` naming
    ``src`` when it cannot be decoded."""
    Image = Image or _opener(src)
    try:
        with Image.open(src) as im:
            im.load()
            exif, icc = im.getexif(), im.info.get("icc_profile")
            rgb = im.convert("RGB") if im.mode != "RGB" else im.copy()
    except Exception as exc:   # damaged or not HEIF at all: pillow-heif raises several kinds
        raise SceneError(f"{src}: cannot be decoded as a HEIC/HEIF photo ({type(exc).__name__}); replace it "
                         "with the original or convert it to JPEG") from None
    exif[_ORIENTATION] = 1                 # pillow-heif applied the rotation to the pixels
    part = dst.with_name(dst.name + ".part")
    rgb.save(part, format="JPEG", quality=JPEG_QUALITY, exif=_exif_bytes(exif, Image), icc_profile=icc)
    os.replace(part, dst)


#: the EXIF tags a JPEG copy keeps when the whole EXIF does not fit: make, model, orientation; in
#: the Exif sub-IFD the focal length, its 35 mm equivalent and the lens model
_CAMERA_TAGS, _CAMERA_EXIF_TAGS = (0x010F, 0x0110, _ORIENTATION), (0x920A, 0xA405, 0xA434)


def _exif_bytes(exif, Image) -> bytes:
    """``exif`` as bytes for a JPEG, or only the tags :func:`~.photos.camera_key` reads when the
    whole does not fit the 64 KB of a JPEG segment (a long maker note) or cannot be written."""
    try:
        blob = exif.tobytes()
        if len(blob) < 65000:
            return blob
    except Exception:
        pass
    small = Image.Exif()
    for tag in _CAMERA_TAGS:
        if tag in exif:
            small[tag] = exif[tag]
    sub, small_sub = exif.get_ifd(0x8769), small.get_ifd(0x8769)
    for tag in _CAMERA_EXIF_TAGS:
        if tag in sub:
            small_sub[tag] = sub[tag]
    try:
        return small.tobytes()
    except Exception:
        return b""


def _key(photo_dir: Path, names: list) -> str:
    from .sfm import file_digest  # noqa: PLC0415
    h = hashlib.sha1(f"{RECIPE}|".encode())
    for n in names:
        h.update(f"{n}|{file_digest(photo_dir / n)}\n".encode())
    return h.hexdigest()


def jpeg_names(heif: list, others: list) -> dict:
    """The JPEG name of each HEIF photo: ``NAME.jpg``, or ``NAME.K.jpg`` where a photo of the
    folder already has that name (compared ignoring case, as on a Mac's disk)."""
    taken = {n.lower() for n in others} | {n.lower() for n in heif}
    out = {}
    for n in heif:
        name, k = f"{n}.jpg", 1
        while name.lower() in taken:
            name, k = f"{n}.{k}.jpg", k + 1
        taken.add(name.lower())
        out[n] = name
    return out


def _link_or_copy(src: Path, dst: Path) -> None:
    """A hard link (it outlives a moved or deleted original; a symbolic link would not), else a
    copy (the cache on another disk)."""
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def _holds(out: Path, names) -> bool:
    return out.is_dir() and all((out / n).is_file() for n in names)


def _record(done: Path):
    """The mirror's record (what :func:`jpeg_folder` wrote), or None when it is missing or damaged."""
    try:
        rec = json.loads(done.read_text())
        return rec if isinstance(rec.get("jpeg"), dict) and isinstance(rec.get("others"), list) else None
    except (OSError, ValueError, AttributeError):
        return None


def _tmp_name() -> str:
    """The temporary folder's name: this machine and process (a cache may be shared by machines)."""
    host = "".join(c if c.isalnum() or c in "-_" else "_" for c in socket.gethostname()) or "host"
    return f"photos.tmp-{host}-{os.getpid()}"


def _remove_orphans(work: Path) -> None:
    """Temporary folders of this machine's conversions whose process is gone (killed, or the
    machine stopped); other machines' are left alone."""
    mine = _tmp_name().rsplit("-", 1)[0] + "-"
    for tmp in work.glob(mine + "*"):
        try:
            os.kill(int(tmp.name[len(mine):]), 0)
        except ProcessLookupError:
            shutil.rmtree(tmp, ignore_errors=True)
        except (ValueError, OSError):
            pass


def jpeg_folder(photo_dir, cache=None, progress: bool = False, warnings=None) -> Path:
    """The folder of ``photo_dir``'s photos with every HEIF photo as a JPEG (module docstring), in
    the user cache; made on the first call, reused while the photos are unchanged. A HEIF photo
    that cannot be decoded is left out with a warning naming it; when fewer than 3 photos are
    left, the first such photo's error is raised."""
    from .cache import mark_used  # noqa: PLC0415
    from .sfm import cache_root  # noqa: PLC0415
    photo_dir = Path(photo_dir)
    warnings = warnings if warnings is not None else []
    heif = heif_names(photo_dir)
    others = list_images(photo_dir)
    root, note = cache_root(None, cache)
    if note:
        warnings.append(note)
    work = root / f"heif_{_key(photo_dir, sorted(heif + others))[:16]}"
    out, done = work / "photos", work / "done.json"
    rec = _record(done)
    if rec is not None and _holds(out, rec["others"] + list(rec["jpeg"].values())):
        warnings.extend(rec.get("warnings", []))
        warnings.append(f"reused the JPEG copies of {len(rec['jpeg'])} HEIC/HEIF photos: {out}")
        mark_used(work)
        return out
    Image = _opener(photo_dir / heif[0])
    tmp = work / _tmp_name()
    try:
        work.mkdir(parents=True, exist_ok=True)
        _remove_orphans(work)
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir()
    except OSError as exc:
        raise SceneError(f"{work}: cannot create the cache folder for the JPEG copies of the HEIC photos "
                         f"({exc.strerror}); set TSPLUS_CACHE or XDG_CACHE_HOME to a writable folder") from None
    try:
        jpeg, skipped = _fill(tmp, photo_dir, heif, others, Image, progress)
        want = others + list(jpeg.values())
        if not _holds(out, want):           # another process may have made the same mirror meanwhile
            shutil.rmtree(out, ignore_errors=True)
            try:
                tmp.rename(out)
            except OSError:
                if not _holds(out, want):
                    raise
    except OSError as exc:
        raise SceneError(f"{work}: cannot write the JPEG copies of the HEIC photos ({exc.strerror}); free some "
                         "disk space or set TSPLUS_CACHE to another folder") from None
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    try:
        part = done.with_name(f"done.json.tmp{os.getpid()}")
        part.write_text(json.dumps({"folder": str(photo_dir), "jpeg": jpeg, "others": others, "warnings": skipped}))
        os.replace(part, done)
    except OSError as exc:                  # the mirror is complete; it is only made again next time
        warnings.append(f"{done}: cannot record the JPEG copies ({exc.strerror}); they are made again next time")
    warnings.extend(skipped)
    return out


def _fill(tmp: Path, photo_dir: Path, heif: list, others: list, Image, progress):
    """Link ``others`` and convert ``heif`` into ``tmp``: ``({HEIF name: JPEG name}, warnings of
    the photos skipped)``. Raises the first skipped photo's error when fewer than 3 photos are left."""
    for n in others:
        _link_or_copy(photo_dir / n, tmp / n)
    names, jpeg, skipped, first = jpeg_names(heif, others), {}, [], None
    for n in _bar(heif, progress):
        try:
            convert_heif(photo_dir / n, tmp / names[n], Image)
            jpeg[n] = names[n]
        except SceneError as exc:
            first = first or exc
            skipped.append(f"skipped {exc}")
    if first is not None and len(others) + len(jpeg) < 3:
        raise first                         # too few photos left: the first damaged one's own error
    return jpeg, skipped


def _bar(names, progress):
    if not progress or len(names) < 2:
        return names
    try:
        from tqdm import tqdm  # noqa: PLC0415
    except ImportError:  # pragma: no cover
        return names
    # shown after a second: a folder of damaged files fails at once with its one error line
    return tqdm(names, desc="HEIC photos to JPEG", unit="photo", leave=False, delay=1.0)
