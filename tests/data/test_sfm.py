"""Photos-only input: pycolmap SfM on a small downscaled subset of the cup capture must recover
poses consistent with the given COLMAP model (relative rotation error < 2 degrees), the same
poses and points on every run.

Marked ``slow`` so it can be deselected with ``-m "not slow"``; it runs by default (~5 s here).
"""


import numpy as np
import pytest

import tsplus_wgpu.data.photos as photos_mod
from tsplus_wgpu.data import SceneError, load_scene
from tsplus_wgpu.data.cache import describe
from tsplus_wgpu.data.images import resize_area, write_image



def rotation_angle_deg(R):
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))


@pytest.mark.slow
def test_photos_only_sfm_recovers_cup_poses(tmp_path, cup_near):
    ref, order = cup_near
    chosen = order[:10]                                          # 10 neighbouring photos
    photos = tmp_path / "photos"
    photos.mkdir()
    for i in chosen:
        write_image(photos / ref.image_names[i], resize_area(ref.images[i], 400, 300))
    sc = load_scene(photos, split="none", cache_dir=tmp_path / "cache")
    assert sc.format == "photos" and sc.points_source == "sfm" and len(sc.points) > 300
    assert len(sc.cameras) >= 8
    by_name = {n: c for n, c in zip(ref.image_names, ref.cameras)}
    errs = []
    for a in range(len(sc.cameras)):
        for b in range(a + 1, len(sc.cameras)):
            rel = sc.cameras[a].R @ sc.cameras[b].R.T
            rel_ref = by_name[sc.image_names[a]].R @ by_name[sc.image_names[b]].R.T
            errs.append(rotation_angle_deg(rel @ rel_ref.T))
    print(f"photos-only SfM: {len(sc.cameras)}/10 registered, relative rotation error "
          f"mean {np.mean(errs):.3f} max {np.max(errs):.3f} deg")
    assert max(errs) < 2.0
    entry, = (tmp_path / "cache").glob("sfm_*")       # only what a later load reads is kept
    assert sorted(p.name for p in entry.iterdir()) == ["done.json", "sparse"]
    assert [p.name for p in (entry / "sparse").iterdir()] == ["0"]
    assert describe(entry).source == str(photos) and describe(entry).finished and not describe(entry).spare
    here = load_scene(photos, split="none", cache_dir=tmp_path / "cache")     # this process made it: no "reused"
    assert not any("reused cached SfM model" in w for w in here.warnings)
    photos_mod.MADE_HERE.clear()                                           # as a later process
    again = load_scene(photos, split="none", cache_dir=tmp_path / "cache")
    assert any("reused cached SfM model" in w for w in again.warnings)
    assert np.array_equal(again.points, sc.points)
    fresh = load_scene(photos, split="none", cache_dir=tmp_path / "cache2")   # from scratch: the same bits
    assert not any("reused cached SfM model" in w for w in fresh.warnings)
    assert np.array_equal(fresh.points, sc.points) and fresh.image_names == sc.image_names
    assert all(np.array_equal(a.world_to_camera, b.world_to_camera) for a, b in zip(fresh.cameras, sc.cameras))


@pytest.mark.slow
def test_photos_sfm_names_the_photos_it_skips_on_every_load(tmp_path, cup_near, monkeypatch):
    """A photo SfM cannot place is named in a warning: on the first load, and again on every load
    from the cache, `tsplus train`'s included (its plan runs the SfM, its load reuses it)."""
    import json

    from tsplus_wgpu.data.loader import frame_sizes
    ref, order = cup_near
    photos = tmp_path / "photos"
    photos.mkdir()
    for i in order[:6]:
        write_image(photos / ref.image_names[i], resize_area(ref.images[i], 400, 300))
    rng = np.random.default_rng(2)
    write_image(photos / "zz_flat.png", np.full((300, 400, 3), 0.5) + 0.002 * rng.random((300, 400, 3)))
    first = load_scene(photos, split="none", cache_dir=tmp_path / "cache")
    said = [w for w in first.warnings if "SfM registered" in w]
    assert said == [w for w in said if "6 of 7 photos" in w and "zz_flat.png" in w] and len(said) == 1
    assert "zz_flat.png" not in first.image_names
    photos_mod.MADE_HERE.clear()                                    # as a later process
    again = load_scene(photos, split="none", cache_dir=tmp_path / "cache")
    assert said[0] in again.warnings and any("reused cached SfM model" in w for w in again.warnings)
    monkeypatch.setenv("TSPLUS_CACHE", str(tmp_path / "cache2"))     # tsplus train: the plan, then the load
    assert frame_sizes(photos) == [(400, 300)] * 6
    trained = load_scene(photos, split="none").warnings               # the SfM ran in this process: not "reused"
    assert said[0] in trained and not any("reused cached SfM model" in w for w in trained)
    entry, = (tmp_path / "cache").glob("sfm_*")
    done = entry / "done.json"
    rec = json.loads(done.read_text())
    assert rec["warnings"] == said
    del rec["warnings"]                       # an entry written before warnings were recorded
    done.write_text(json.dumps(rec))
    old = load_scene(photos, split="none", cache_dir=tmp_path / "cache")
    assert any("SfM registered 6 of 7 photos" in w for w in old.warnings)


@pytest.mark.slow
def test_photos_only_sfm_of_a_tiny_unmatchable_set(tmp_path):
    rng = np.random.default_rng(1)
    for i in range(4):
        write_image(tmp_path / f"flat_{i}.png", np.full((90, 120, 3), 0.3 + 0.1 * i) + 0.01 * rng.random((90, 120, 3)))
    with pytest.raises(SceneError, match=r"registered only 0 of 4 photos|SfM failed"):
        load_scene(tmp_path, cache_dir=tmp_path / "cache")
    assert not list((tmp_path / "cache").glob("sfm_*"))     # nothing half made left in the cache


def test_ordered_pairs_follow_the_natural_name_order():
    from tsplus_wgpu.data.photos import natural_key, ordered_pairs
    names = ["IMG_10.jpg", "IMG_9.jpg", "img_11.JPG", "IMG_1.jpg", "IMG_100.jpg"]
    assert sorted(names, key=natural_key) == ["IMG_1.jpg", "IMG_9.jpg", "IMG_10.jpg", "img_11.JPG", "IMG_100.jpg"]
    assert ordered_pairs(names, overlap=1) == [("IMG_1.jpg", "IMG_9.jpg"), ("IMG_9.jpg", "IMG_10.jpg"),
                                               ("IMG_10.jpg", "img_11.JPG"), ("img_11.JPG", "IMG_100.jpg")]
    frames = [f"{i}.jpg" for i in range(100)]
    pairs = ordered_pairs(frames[::-1], overlap=10)
    assert len(pairs) == len(set(pairs)) == 1133               # the count of COLMAP's sequential matching
    gaps = {int(b[:-4]) - int(a[:-4]) for a, b in pairs}
    assert gaps == set(range(1, 11)) | {16, 32, 64}
    small = [f"{i}.jpg" for i in range(11)]                     # 11 photos, overlap 10: every pair
    assert len(ordered_pairs(small, overlap=10)) == 55


@pytest.mark.slow
def test_many_photos_matched_in_name_order_fall_back_to_every_pair(tmp_path, monkeypatch, cup_near):
    """More photos than ORDERED_PHOTOS_MIN are matched in their name order; when that registers
    too few of them (here: one pair matched), every pair is matched as well and all register."""
    from tsplus_wgpu.data import photos
    ref, order = cup_near
    near = order[:10]
    folder = tmp_path / "photos"
    folder.mkdir()
    for i in near:
        write_image(folder / ref.image_names[i], resize_area(ref.images[i], 400, 300))
    monkeypatch.setattr(photos, "ORDERED_PHOTOS_MIN", 5)
    real_pairs, asked = photos.ordered_pairs, []
    monkeypatch.setattr(photos, "ordered_pairs", lambda names: asked.append(len(names)) or real_pairs(names)[:1])
    sc = load_scene(folder, split="none", points="none", cache_dir=tmp_path / "cache")
    assert asked and set(asked) == {10} and len(sc.cameras) == 10     # (the progress bar counts the pairs too)
    assert any("name order registered" in w and "every pair matched as well" in w for w in sc.warnings)
    # in name order with their real pairs (10 photos: every pair, as before): no fallback
    n_before = len(asked)
    monkeypatch.setattr(photos, "ordered_pairs", lambda names: asked.append(len(names)) or real_pairs(names))
    again = load_scene(folder, split="none", points="none", cache_dir=tmp_path / "cache2")
    assert len(asked) > n_before and len(again.cameras) == 10
    assert not any("name order" in w for w in again.warnings)


def test_which_matching_a_photo_folder_gets(tmp_path, monkeypatch):
    """Every pair up to ORDERED_PHOTOS_MIN photos; past it, the pairs of the name order, or COLMAP's
    sequential matching when a name holds a space (a pair list cannot); a video's frames: sequential."""
    from tsplus_wgpu.data import photos
    seen = []

    def spy(*a, **k):
        seen.append((k.get("sequential"), None if k.get("pairs") is None else len(k["pairs"])))
        raise RuntimeError("stop here")

    monkeypatch.setattr(photos, "_extract_and_match", spy)
    monkeypatch.setattr(photos, "ORDERED_PHOTOS_MIN", 4)
    for case, names in [("few", [f"p{i}.png" for i in range(4)]), ("many", [f"p{i}.png" for i in range(6)]),
                        ("spaces", [f"photo {i}.png" for i in range(6)])]:
        folder = tmp_path / case
        folder.mkdir()
        for n in names:
            write_image(folder / n, np.full((8, 8, 3), 0.5))
        with pytest.raises(SceneError, match="SfM failed"):
            photos.run_photos_sfm(folder, names, cache=tmp_path / "cache", progress=False)
    with pytest.raises(SceneError, match="SfM failed"):
        photos.run_photos_sfm(tmp_path / "many", [f"p{i}.png" for i in range(6)], cache=tmp_path / "cache",
                              progress=False, sequential=True)
    assert seen == [(False, None), (False, 15), (True, None), (True, None)]


def _exif_photo(path, rgb, focal_mm=None, model="iPhone 12"):
    """A JPEG of ``rgb`` ([H, W, 3] float) with EXIF make, model and focal length when ``focal_mm``."""
    from PIL import Image
    from PIL.TiffImagePlugin import IFDRational
    im = Image.fromarray((np.clip(rgb, 0, 1) * 255 + 0.5).astype(np.uint8))
    ex = im.getexif()
    if focal_mm is not None:
        ex[0x010F], ex[0x0110] = "Apple", model
        sub = ex.get_ifd(0x8769)
        sub[0x920A] = IFDRational(int(round(focal_mm * 100)), 100)
        sub[0xA405] = int(round(26 * focal_mm / 4.2))
    im.save(path, quality=95, exif=ex.tobytes())


def test_camera_groups_by_size_and_exif_lens(tmp_path):
    """Photos group by the camera that took them: size, EXIF make / model / lens / focal length;
    a damaged focal length (zero denominator) reads as none, not as a group of its own per photo."""
    from PIL.TiffImagePlugin import IFDRational
    from tsplus_wgpu.data.photos import camera_groups, camera_key
    rng = np.random.default_rng(0)
    img = rng.random((48, 64, 3))
    specs = {"a1.jpg": 4.2, "a2.jpg": 8.4, "a3.jpg": 4.2, "a4.jpg": None, "a5.jpg": 8.4}
    for n, f in specs.items():
        _exif_photo(tmp_path / n, img, f)
    _exif_photo(tmp_path / "b1.jpg", img[:40], 4.2)                  # another size
    _exif_photo(tmp_path / "c1.jpg", img, 4.2, model="Pixel 7")       # another phone, same focal length
    names = sorted(p.name for p in tmp_path.iterdir())
    assert camera_groups(tmp_path, names) == [["a1.jpg", "a3.jpg"], ["a2.jpg", "a5.jpg"], ["a4.jpg"], ["b1.jpg"],
                                               ["c1.jpg"]]
    assert camera_key(tmp_path / "a2.jpg") == ((64, 48), ("Apple", "iPhone 12", "", 8.4, 52.0))
    assert camera_key(tmp_path / "a4.jpg") == ((64, 48), ("", "", "", 0.0, 0.0))
    from PIL import Image
    im = Image.open(tmp_path / "a1.jpg")
    ex = im.getexif()
    ex.get_ifd(0x8769)[0x920A] = IFDRational(1, 0)
    im.save(tmp_path / "bad1.jpg", exif=ex.tobytes())
    im.save(tmp_path / "bad2.jpg", exif=ex.tobytes())
    assert camera_groups(tmp_path, ["bad1.jpg", "bad2.jpg"]) == [["bad1.jpg", "bad2.jpg"]]
    assert camera_key(tmp_path / "bad1.jpg")[1][3] == 0.0


def test_photos_of_two_lenses_get_a_camera_each(tmp_path, monkeypatch):
    """A phone's photos through two lenses in turn (same size, EXIF 4.2 and 8.4 mm) get a camera
    per lens, with focal lengths a factor 2 apart, instead of one focal length for both; so do two
    phones of one focal length, and photos without EXIF at two sizes (a camera a size, not a
    camera a photo); one lens keeps one camera and the cache key the folder had before."""
    import shutil
    import sqlite3
    from tsplus_wgpu.data import photos
    from tsplus_wgpu.data.sfm import _fingerprint
    real, dbs = photos._extract_and_match, []

    def extract_then_stop(pycolmap, db, *a, **k):
        real(pycolmap, db, *a, **k)
        keep = tmp_path / f"{db.parent.name}.db"       # the failed entry leaves the cache: a copy to read
        shutil.copy(db, keep)
        dbs.append(keep)
        raise RuntimeError("stop here")

    monkeypatch.setattr(photos, "_extract_and_match", extract_then_stop)
    rng = np.random.default_rng(1)
    img = np.kron(rng.random((30, 40, 3)), np.ones((8, 8, 1)))          # 320x240, blocky texture
    cases = {"lenses": lambda i, im: _exif_photo(*im, 4.2 if i % 2 == 0 else 8.4),
             "phones": lambda i, im: _exif_photo(*im, 4.2, model="iPhone 12" if i % 2 == 0 else "Pixel 7"),
             "sizes": lambda i, im: _exif_photo(im[0], im[1][: 240 if i % 2 == 0 else 200]),
             "one": lambda i, im: _exif_photo(*im)}
    names = [f"IMG_{i}.jpg" for i in range(6)]
    for case, make in cases.items():
        folder = tmp_path / case
        folder.mkdir()
        for i, n in enumerate(names):
            make(i, (folder / n, np.roll(img, 8 * i, axis=1)))
        with pytest.raises(SceneError, match="SfM failed"):
            photos.run_photos_sfm(folder, names, cache=tmp_path / "cache", progress=False)
        with sqlite3.connect(dbs[-1]) as con:
            cams = {cid: np.frombuffer(p)[0] for cid, p in con.execute("select camera_id, params from cameras")}
            by_image = dict(con.execute("select name, camera_id from images"))
        assert len(by_image) == 6, case
        if case == "one":
            assert len(cams) == 1
            assert dbs[-1].stem == f"sfm_{_fingerprint([folder / n for n in names], '')[:16]}"
            continue
        assert len(cams) == 2, case
        even, odd = {by_image[n] for n in names[0::2]}, {by_image[n] for n in names[1::2]}
        assert len(even) == len(odd) == 1 and even != odd, case
        if case == "lenses":
            assert cams[odd.pop()] == pytest.approx(2 * cams[even.pop()], rel=1e-6)


def test_the_sfm_bar_moves_during_a_long_silent_call():
    """Inside ``creep`` (pycolmap's extraction and matching report nothing while they run) a
    weighted bar moves on by itself at the pace of the work before, never ahead of it and never
    past 90 % of the block's share; the block's end adds the rest, an error inside adds nothing,
    and a bar of whole steps does not creep."""
    import time
    from tsplus_wgpu.data.sfm import _Progress
    prog = _Progress(True, 100.0, "test", weighted=True)

    def inside(units, pace, until):
        """(seconds in, bar) samples until the bar passes ``until`` (at most 20 s)."""
        seen, start, t = [], prog.bar.n, time.time()     # the creep's clock starts after t
        with prog.creep(units, tick=0.01):
            while time.time() - t < 20 and prog.bar.n - start < until:
                n = prog.bar.n - start                   # read before the clock: never ahead by a race
                seen.append((time.time() - t, n))
                time.sleep(0.01)
            n = prog.bar.n - start
            seen.append((time.time() - t, n))
        assert all(n <= dt / pace + 1e-9 for dt, n in seen)       # never ahead of the pace
        return max(n for _, n in seen)

    assert inside(10.0, 1.0, 0.3) >= 0.3                           # nothing before: a unit a second
    assert prog.bar.n == pytest.approx(10.0)
    prog.t0 = time.time() - 2.0                                    # 10 units in 2 s: 0.2 s a unit
    assert inside(3.0, 0.2, 2.7 - 1e-9) == pytest.approx(2.7)     # the cap: 90 % of 3
    assert prog.bar.n == pytest.approx(13.0)
    with pytest.raises(RuntimeError):
        with prog.creep(50.0, tick=0.01):
            raise RuntimeError("pycolmap failed")
    assert prog.bar.n < 13.5
    prog.finish()
    assert prog.bar.n == pytest.approx(100.0)
    prog.close()
    steps = _Progress(True, 4, "steps")
    with steps.creep(1.0, tick=0.01):
        time.sleep(0.1)
        assert steps.bar.n == 0
    assert steps.bar.n == 1
    steps.close()


def test_the_mappers_are_tried_in_turn_until_one_registers_every_photo(monkeypatch):
    """With an EXIF focal length: the global mapper holding it, then refining it, then the
    incremental mapper; without (or with ``TSPLUS_SFM_FOCAL=refine``): the last two. The first
    that registers every photo ends the search; otherwise the one that registers the most wins,
    the earlier on a tie; whether the model kept held the focal length is said."""
    from tsplus_wgpu.data import photos
    from tsplus_wgpu.data.sfm import _Progress

    class Rec:
        def __init__(self, n, tag):
            self.n, self.tag = n, tag

        def num_reg_images(self):
            return self.n

    def run(exif, counts):
        calls = []
        monkeypatch.setattr(photos, "_exif_focal", lambda pycolmap, db: exif)

        def fake_global(pycolmap, db, photo_dir, work, prog, count, hold):
            calls.append("held" if hold else "global")
            n = counts[calls[-1]]
            return None if n is None else Rec(n, calls[-1])

        def fake_incremental(pycolmap, db, photo_dir, work, prog):
            calls.append("incremental")
            return Rec(counts["incremental"], "incremental")

        monkeypatch.setattr(photos, "_global_mapping", fake_global)
        monkeypatch.setattr(photos, "_incremental_mapping", fake_incremental)
        best, held = photos._mapping(None, None, None, None, _Progress(False, 1, ""), 10)
        assert held == (best is not None and best.tag == "held")
        return calls, best.tag if best is not None else None

    monkeypatch.delenv("TSPLUS_SFM_FOCAL", raising=False)
    every = dict(held=10, incremental=10, **{"global": 10})
    assert run(True, every) == (["held"], "held")
    assert run(False, every) == (["global"], "global")
    assert run(True, dict(held=8, incremental=10, **{"global": None})) == (["held", "global", "incremental"], "incremental")
    assert run(True, dict(held=8, incremental=9, **{"global": 9})) == (["held", "global", "incremental"], "global")
    assert run(True, dict(held=8, incremental=8, **{"global": 7})) == (["held", "global", "incremental"], "held")
    assert run(False, dict(held=0, incremental=0, **{"global": None})) == (["global", "incremental"], None)
    monkeypatch.setenv("TSPLUS_SFM_FOCAL", "refine")
    assert run(True, every) == (["global"], "global")


@pytest.mark.slow
def test_a_forward_walk_with_exif_is_posed_like_the_dataset(tmp_path, monkeypatch):
    """Lund's 29 photos walking down a street, at 600x450 with the EXIF focal length a phone
    writes: every photo registered, within 2 degrees (median per photo) of the dataset's poses.
    The incremental mapper registers 2 of them, and the global mapper refining the focal
    length gives up (docs/measurements.md, "A forward walk: the global mapper")."""
    import os
    from pathlib import Path
    from tsplus_wgpu.bench.exif_copy import exif_copy
    data = Path(os.environ.get("TSPLUS_DATA", Path(__file__).resolve().parents[3] / "shared" / "data"))
    if not (data / "lund").is_dir():
        pytest.skip(f"shared data scene {data / 'lund'} not found (set TSPLUS_DATA)")
    monkeypatch.delenv("TSPLUS_SFM_THREADS", raising=False)      # one thread: the same poses on every run
    monkeypatch.delenv("TSPLUS_SFM_FOCAL", raising=False)
    folder = tmp_path / "walk"      # EXIF 35 mm equivalent 34 mm: COLMAP's prior 589 px (the model's 583)
    exif_copy(data / "lund" / "images", folder, 34, width=600)
    sc = load_scene(folder, split="none", cache_dir=tmp_path / "cache")
    ref = load_scene(data / "lund", downscale=8, split="none", points="none")
    R = {n: c.R for n, c in zip(ref.image_names, ref.cameras)}
    got = {n: c.R for n, c in zip(sc.image_names, sc.cameras) if n != "20.jpg"}   # the dataset's 20.jpg is wrong
    per = [np.median([rotation_angle_deg((got[a] @ got[b].T) @ (R[a] @ R[b].T).T) for b in got if b != a])
           for a in got]
    print(f"forward walk: {len(sc.cameras)}/29 registered, focal {sc.cameras[0].fx:.1f} px, per-photo relative "
          f"rotation error median {np.median(per):.2f} max {np.max(per):.2f} deg")
    assert len(sc.cameras) == 29
    assert np.median(per) < 2.0
    said = [w for w in sc.warnings if "SfM held the focal length the photos' EXIF gives (589 px)" in w]
    assert len(said) == 1 and "TSPLUS_SFM_FOCAL=refine" in said[0]


@pytest.mark.slow
def test_a_wrong_exif_focal_length_is_held_and_said_and_refine_recovers(tmp_path, cup_near, monkeypatch):
    """Cup photos given an EXIF focal length 25 % short (as a photo cropped after shooting keeps
    it): held by default, and said in a warning naming ``TSPLUS_SFM_FOCAL=refine``; with that
    variable the mapper refines it back to the dataset's (about 295 px at 400x300) and the
    relative rotations agree with the dataset's within a degree, in a cache entry of its own."""
    from PIL import Image
    ref, order = cup_near
    src, photos = tmp_path / "src", tmp_path / "photos"
    src.mkdir()
    for i in order[:10]:
        write_image(src / ref.image_names[i], resize_area(ref.images[i], 400, 300))
    photos.mkdir()
    for p in sorted(src.iterdir()):
        with Image.open(p) as im:
            rgb = im.convert("RGB")
        ex = rgb.getexif()
        ex[0x010F], ex[0x0110] = "Apple", "iPhone"
        ex.get_ifd(0x8769)[0xA405] = 19                  # COLMAP's prior 220 px
        rgb.save(photos / (p.stem + ".jpg"), quality=95, exif=ex.tobytes())
    monkeypatch.delenv("TSPLUS_SFM_FOCAL", raising=False)
    held = load_scene(photos, split="none", cache_dir=tmp_path / "cache")
    assert held.cameras[0].fx == pytest.approx(219.6, abs=0.5)
    assert any("SfM held the focal length the photos' EXIF gives (220 px)" in w and "TSPLUS_SFM_FOCAL=refine" in w
               for w in held.warnings)
    monkeypatch.setenv("TSPLUS_SFM_FOCAL", "refine")
    sc = load_scene(photos, split="none", cache_dir=tmp_path / "cache")
    assert not any("reused cached SfM model" in w or "SfM held" in w for w in sc.warnings)
    assert sc.cameras[0].fx == pytest.approx(295, rel=0.03)
    by_name = {n: c for n, c in zip(ref.image_names, ref.cameras)}
    errs = [rotation_angle_deg((sc.cameras[a].R @ sc.cameras[b].R.T)
                               @ (by_name[sc.image_names[a]].R @ by_name[sc.image_names[b]].R.T).T)
            for a in range(len(sc.cameras)) for b in range(a + 1, len(sc.cameras))]
    assert len(sc.cameras) == 10 and max(errs) < 1.0
