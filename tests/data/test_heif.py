"""HEIC / HEIF photos (an iPhone's default format): converted once to upright JPEGs in the cache
(``tsplus_wgpu/data/heif.py``), then SfM and training read them as a folder of photos."""

import os

import numpy as np
import pytest

import tsplus_wgpu.data.photos as photos_mod
from tsplus_wgpu.data import SceneError, load_scene
from tsplus_wgpu.data.images import read_image_raw, resize_area

import pillow_heif       # a dependency (pyproject): missing, these tests fail rather than skip
from PIL import Image
from PIL.TiffImagePlugin import IFDRational

pillow_heif.register_heif_opener()


def _heic(path, rgb, orientation=1, focal_mm=4.2, maker_note=b""):
    """Save ``rgb`` ([H, W, 3] float in [0, 1]) as HEIC, with EXIF make, model, focal length and
    ``orientation`` (6: the pixels are stored turned 90 degrees anticlockwise from upright)."""
    im = Image.fromarray((np.clip(rgb, 0, 1) * 255 + 0.5).astype(np.uint8))
    ex = im.getexif()
    ex[0x010F], ex[0x0110], ex[0x0112] = "Apple", "iPhone 12", orientation
    ex.get_ifd(0x8769)[0x920A] = IFDRational(int(focal_mm * 100), 100)
    if maker_note:
        ex.get_ifd(0x8769)[0x927C] = maker_note
    im.save(path, format="HEIF", quality=95, exif=ex.tobytes())


def _psnr(a, b):
    return float(-10 * np.log10(np.mean((np.asarray(a, np.float64) - b) ** 2)))


def test_heif_photo_becomes_an_upright_jpeg_with_its_exif(tmp_path):
    """Stored sideways with EXIF orientation 6, the JPEG holds the upright pixels (close to the
    original turned clockwise, far from it turned the other way), orientation 1 and the focal length."""
    from tsplus_wgpu.data.heif import convert_heif
    from tsplus_wgpu.data.photos import camera_key
    rng = np.random.default_rng(0)
    img = np.kron(rng.random((12, 16, 3)), np.ones((8, 8, 1)))             # 128x96, blocks of 8 px
    _heic(tmp_path / "a.heic", img, orientation=6, focal_mm=8.4)
    convert_heif(tmp_path / "a.heic", tmp_path / "a.heic.jpg")
    out = read_image_raw(tmp_path / "a.heic.jpg")
    assert out.shape == (128, 96, 3)
    cw, ccw = np.rot90(img, k=-1), np.rot90(img, k=1)
    assert _psnr(out, cw) > 20 and _psnr(out, ccw) < _psnr(out, cw) - 10, (_psnr(out, cw), _psnr(out, ccw))
    with Image.open(tmp_path / "a.heic.jpg") as im:
        ex = im.getexif()
        assert ex.get(0x0112) == 1 and float(ex.get_ifd(0x8769)[0x920A]) == pytest.approx(8.4)
    assert camera_key(tmp_path / "a.heic.jpg")[1][:2] == ("Apple", "iPhone 12")
    (tmp_path / "bad.heic").write_bytes(b"\x00\x00\x00\x18ftypheic" + bytes(200))
    with pytest.raises(SceneError, match=r"bad\.heic: cannot be decoded as a HEIC/HEIF photo"):
        convert_heif(tmp_path / "bad.heic", tmp_path / "bad.heic.jpg")
    assert not (tmp_path / "bad.heic.jpg").exists()


@pytest.mark.slow
def test_a_folder_of_heic_photos_is_posed_like_its_jpegs(tmp_path, cup_near):
    """Nine cup photos as HEIC, one as JPEG and a damaged file beside them: the damaged one is
    skipped with a warning naming it, the others registered with poses within 2 degrees of the
    dataset's; the JPEG copies are made once and reused, also once the original folder has moved, and made
    again when one is lost from the cache."""
    ref, order = cup_near
    chosen = order[:10]
    folder = tmp_path / "iphone"
    folder.mkdir()
    stems = {}
    for k, i in enumerate(chosen):
        small = resize_area(ref.images[i], 400, 300)
        if k == 0:           # one photo as JPEG: a folder can mix both
            name = f"IMG_{k}.jpg"
            Image.fromarray((small * 255 + 0.5).astype(np.uint8)).save(folder / name, quality=95)
        else:
            name = f"IMG_{k}.HEIC"
            _heic(folder / name, small)
        stems[name] = ref.image_names[i]
    (folder / "IMG_99.HEIC").write_bytes(b"not a photo")
    sc = load_scene(folder, split="none", points="none", cache_dir=tmp_path / "cache")
    assert sc.format == "photos"
    assert any("IMG_99.HEIC: cannot be decoded" in w for w in sc.warnings)
    assert len(sc.cameras) >= 8 and all(n.endswith(".HEIC.jpg") or n == "IMG_0.jpg" for n in sc.image_names)
    by_name = dict(zip(ref.image_names, ref.cameras))
    orig = [by_name[stems[n[:-4] if n.endswith(".HEIC.jpg") else n]] for n in sc.image_names]
    errs = []
    for a in range(len(sc.cameras)):
        for b in range(a + 1, len(sc.cameras)):
            rel = sc.cameras[a].R @ sc.cameras[b].R.T
            rel_ref = orig[a].R @ orig[b].R.T
            errs.append(np.degrees(np.arccos(np.clip((np.trace(rel @ rel_ref.T) - 1) / 2, -1, 1))))
    assert max(errs) < 2.0
    photos_mod.MADE_HERE.clear()          # as a later process, which says it reused the SfM
    again = load_scene(folder, split="none", points="none", cache_dir=tmp_path / "cache")
    assert any("reused the JPEG copies of 9 HEIC/HEIF photos" in w for w in again.warnings)
    assert any("IMG_99.HEIC: cannot be decoded" in w for w in again.warnings)
    assert any("reused cached SfM model" in w for w in again.warnings)
    moved = tmp_path / "moved"          # the original folder moved away: the copies (hard links) still read
    folder.rename(moved)
    third = load_scene(moved, split="none", points="none", cache_dir=tmp_path / "cache")
    assert any("reused the JPEG copies" in w for w in third.warnings) and third.image_names == sc.image_names
    for f in (tmp_path / "cache").glob("heif_*/photos/IMG_3.HEIC.jpg"):
        f.unlink()                      # a copy lost from the cache: made again, not reused
    fourth = load_scene(moved, split="none", points="none", cache_dir=tmp_path / "cache")
    assert not any("reused the JPEG copies" in w for w in fourth.warnings) and fourth.image_names == sc.image_names


def test_heif_errors_are_one_line_naming_the_file(tmp_path, monkeypatch):
    """Only damaged HEIF photos: the first one's error; without pillow-heif: what to install."""
    folder = tmp_path / "broken"
    folder.mkdir()
    (folder / "a.heic").write_bytes(b"junk")
    (folder / "b.heic").write_bytes(b"junk")
    with pytest.raises(SceneError, match=r"a\.heic: cannot be decoded as a HEIC/HEIF photo"):
        load_scene(folder, cache_dir=tmp_path / "cache")
    import builtins
    real_import = builtins.__import__

    def no_heif(name, *a, **k):
        if name == "pillow_heif":
            raise ImportError(name)
        return real_import(name, *a, **k)

    monkeypatch.setattr(builtins, "__import__", no_heif)
    with pytest.raises(SceneError, match=r"a\.heic: HEIC/HEIF photos need the pillow-heif package"):
        load_scene(folder, cache_dir=tmp_path / "cache2")


def test_the_mirror_never_writes_through_a_photo_and_copies_where_links_fail(tmp_path, monkeypatch):
    """``IMG_1.HEIC`` beside the user's own ``img_1.heic.JPG``: the copy is named ``IMG_1.HEIC.1.jpg``
    and the user's file keeps its bytes; where hard links fail the other photos are copied; an
    EXIF over a JPEG segment keeps the camera's tags; a killed conversion's folder is removed."""
    from tsplus_wgpu.data import heif
    rng = np.random.default_rng(2)
    img = np.kron(rng.random((6, 8, 3)), np.ones((8, 8, 1)))
    folder = tmp_path / "p"
    folder.mkdir()
    _heic(folder / "IMG_1.HEIC", img, maker_note=bytes(rng.integers(0, 256, 70000, dtype=np.uint8)))
    Image.fromarray((img * 255).astype(np.uint8)).save(folder / "img_1.heic.JPG", quality=90)
    mine = (folder / "img_1.heic.JPG").read_bytes()
    _heic(folder / "IMG_2.heic", img)
    assert heif.jpeg_names(["IMG_1.HEIC", "IMG_2.heic"], ["img_1.heic.JPG"]) == {
        "IMG_1.HEIC": "IMG_1.HEIC.1.jpg", "IMG_2.heic": "IMG_2.heic.jpg"}
    real_link = os.link
    monkeypatch.setattr(os, "link", lambda *a: (_ for _ in ()).throw(OSError(18, "cross-device link")))
    warnings = []
    out = heif.jpeg_folder(folder, cache=tmp_path / "cache", warnings=warnings)
    assert sorted(p.name for p in out.iterdir()) == ["IMG_1.HEIC.1.jpg", "IMG_2.heic.jpg", "img_1.heic.JPG"]
    assert (folder / "img_1.heic.JPG").read_bytes() == mine and (out / "img_1.heic.JPG").read_bytes() == mine
    assert os.stat(out / "img_1.heic.JPG").st_ino != os.stat(folder / "img_1.heic.JPG").st_ino   # a copy
    with Image.open(out / "IMG_1.HEIC.1.jpg") as im:      # 70 KB of maker note do not fit: the camera's tags
        ex = im.getexif()
        assert ex.get(0x0110) == "iPhone 12" and float(ex.get_ifd(0x8769)[0x920A]) == pytest.approx(4.2)
        assert 0x927C not in ex.get_ifd(0x8769)
    monkeypatch.setattr(os, "link", real_link)
    orphan = out.parent / (heif._tmp_name().rsplit("-", 1)[0] + "-999999999")   # this machine, no such process
    orphan.mkdir()
    elsewhere = out.parent / "photos.tmp-another-machine-1"                     # another machine's: kept
    elsewhere.mkdir()
    (out / "IMG_2.heic.jpg").unlink()                     # a copy lost: the mirror is made again
    again = heif.jpeg_folder(folder, cache=tmp_path / "cache", warnings=warnings)
    assert again == out and not orphan.exists() and list(out.parent.glob("photos.tmp*")) == [elsewhere]
    assert os.stat(out / "img_1.heic.JPG").st_ino == os.stat(folder / "img_1.heic.JPG").st_ino  # linked
    assert (folder / "img_1.heic.JPG").read_bytes() == mine
