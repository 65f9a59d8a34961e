"""The user cache (tsplus_wgpu/data/cache.py, ``tsplus cache``): a finished entry keeps only what
a later load reads, a failed one leaves nothing, using an entry marks it used, and ``--clean``
removes what stopped jobs left and what the user asks for, never a running job's entry or a
folder that is not ours."""

import os
import time

import numpy as np
import pytest

from tsplus_wgpu.cli.main import main
from tsplus_wgpu.data import sfm
from tsplus_wgpu.data.cache import BUSY_SECONDS, describe, list_entries, plan_clean
from tsplus_wgpu.data.procedural import load_procedural


@pytest.fixture(scope="module")
def small():
    return load_procedural("small", seed=0)


def test_a_triangulation_keeps_its_points_only_and_is_marked_used(small, tmp_path):
    """About 1 s of pycolmap on the small procedural scene. Without the trim the entry keeps
    pycolmap's database and model (most of its size on a real scene: 121 MB of fox's 127)."""
    args = (small.cameras, small.images, small.image_names, tmp_path)
    pts, _, _ = sfm.triangulate_known_poses(*args, progress=False)
    entry, = tmp_path.glob("tri_*")
    assert sorted(p.name for p in entry.iterdir()) == ["about.json", "points.npz"]
    e = describe(entry)
    assert e.kind == "tri" and e.finished and e.spare == 0 and e.size == sum(p.stat().st_size for p in entry.iterdir())
    old = time.time() - 40 * 86400
    for p in [entry, *entry.iterdir()]:
        os.utime(p, (old, old))
    assert abs(describe(entry).used - old) < 1
    pts2, _, info = sfm.triangulate_known_poses(*args, progress=False)
    assert "cached" in info and np.array_equal(pts2, pts)
    assert time.time() - describe(entry).used < 60        # loaded: used now, so not "unused for 40 days"


@pytest.mark.parametrize("error", [RuntimeError("pycolmap triangulated only 3 points"), KeyboardInterrupt()])
def test_a_failed_or_stopped_triangulation_leaves_nothing(small, tmp_path, monkeypatch, error):
    def fail(pycolmap, work, *a):
        (work / "database.db").write_bytes(b"x" * 1000)    # what pycolmap had written by then
        raise error
    monkeypatch.setattr(sfm, "_triangulate", fail)
    with pytest.raises(type(error)):
        sfm.triangulate_known_poses(small.cameras, small.images, small.image_names, tmp_path, progress=False)
    assert not list(tmp_path.iterdir())


def make(root, name, files, age_days=0.0):
    """A cache entry folder ``root/name`` holding ``files`` ({relative path: bytes}), last
    changed ``age_days`` ago."""
    d = root / name
    d.mkdir(parents=True)
    for rel, size in files.items():
        (d / rel).parent.mkdir(parents=True, exist_ok=True)
        (d / rel).write_bytes(b"x" * size)
    t = time.time() - age_days * 86400
    for folder, dirs, names in os.walk(d):
        for n in names + dirs:
            os.utime(os.path.join(folder, n), (t, t))
    os.utime(d, (t, t))
    return d


@pytest.fixture
def cache(tmp_path):
    root = tmp_path / "cache"
    make(root, "tri_aaaa", {"points.npz": 100, "about.json": 10, "database.db": 5000, "sparse/images.bin": 700}, 2)
    make(root, "tri_bbbb", {"database.db": 3000}, 1)                         # a killed job's
    make(root, "tri_cccc", {"database.db": 2000}, 0.5 * BUSY_SECONDS / 86400)  # a running job's
    make(root, "sfm_dddd", {"done.json": 10, "sparse/0/cameras.bin": 50}, 40)
    make(root, "video_eeee", {"frames/frames.json": 10, "frames/frame_000001.jpg": 300}, 3)
    make(root, "heif_ffff", {"photos/a.jpg": 30}, 3)                          # no done.json: unfinished
    (tmp_path / "IMG_1.jpg").write_bytes(b"x" * 4000)                         # the user's photo, and its
    os.link(tmp_path / "IMG_1.jpg", root / "heif_ffff" / "photos" / "IMG_1.jpg")   # link in the mirror: frees nothing
    for d in (root / "heif_ffff" / "photos", root / "heif_ffff"):
        os.utime(d, (time.time() - 3 * 86400,) * 2)
    make(root, "notes", {"mine.txt": 5}, 100)                                 # not ours
    (root / "tri_file").write_bytes(b"x")                                     # not a folder: not ours
    return root


def test_entries_and_what_clean_removes(cache):
    es = {e.path.name: e for e in list_entries(cache)}
    assert sorted(es) == ["heif_ffff", "sfm_dddd", "tri_aaaa", "tri_bbbb", "tri_cccc", "video_eeee"]
    assert [n for n, e in sorted(es.items()) if e.finished] == ["sfm_dddd", "tri_aaaa", "video_eeee"]
    assert es["tri_aaaa"].size == 5810 and es["tri_aaaa"].spare == 5700 and es["sfm_dddd"].spare == 0
    assert es["video_eeee"].size == 310 and es["heif_ffff"].size == 30
    names = lambda pairs: sorted(e.path.name for e, _ in pairs)   # noqa: E731
    remove, trims, busy = plan_clean(es.values())
    assert names(remove) == ["heif_ffff", "tri_bbbb"] and names(busy) == ["tri_cccc"]
    assert [e.path.name for e in trims] == ["tri_aaaa"]
    remove, trims, busy = plan_clean(es.values(), older_than_days=30)
    assert names(remove) == ["heif_ffff", "sfm_dddd", "tri_bbbb"] and names(busy) == ["tri_cccc"]
    remove, trims, busy = plan_clean(es.values(), everything=True)
    assert names(remove) == ["heif_ffff", "sfm_dddd", "tri_aaaa", "tri_bbbb", "video_eeee"] and not trims
    assert names(busy) == ["tri_cccc"]


def test_the_cache_command(cache, monkeypatch, capsys):
    monkeypatch.setenv("TSPLUS_CACHE", str(cache))
    assert main(["cache"]) == 0
    out = capsys.readouterr().out
    assert f"cache: {cache} (6 entries" in out and "tri_aaaa" in out and "notes" not in out
    assert "frees 8.7 kB" in out                       # tri_bbbb, heif_ffff and tri_aaaa's spare files
    assert main(["cache", "--clean", "--dry-run"]) == 0
    assert "would free 8.7 kB" in capsys.readouterr().out and (cache / "tri_bbbb").is_dir()
    assert main(["cache", "--clean"]) == 0
    out = capsys.readouterr().out
    assert "removed tri_bbbb" in out and "kept tri_cccc" in out and "trimmed tri_aaaa" in out
    assert sorted(p.name for p in cache.iterdir()) == ["notes", "sfm_dddd", "tri_aaaa", "tri_cccc", "tri_file",
                                                       "video_eeee"]
    assert sorted(p.name for p in (cache / "tri_aaaa").iterdir()) == ["about.json", "points.npz"]
    assert main(["cache", "--clean", "--older-than", "30"]) == 0
    assert not (cache / "sfm_dddd").exists() and (cache / "video_eeee").is_dir()
    assert main(["cache", "--clean", "--all"]) == 0
    assert sorted(p.name for p in cache.iterdir()) == ["notes", "tri_cccc", "tri_file"]


@pytest.mark.parametrize("argv, words", [
    (["cache", "--all"], "--older-than, --all and --dry-run go with --clean"),
    (["cache", "--clean", "--older-than", "-2"], "--older-than -2.0: give a number of days"),
    (["cache", "--clean", "--older-than", "nan"], "--older-than nan: give a number of days"),
])
def test_cache_command_errors_are_one_line(argv, words, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("TSPLUS_CACHE", str(tmp_path))
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1


@pytest.mark.parametrize("sig", ["SIGTERM", "SIGHUP"])
def test_a_signal_during_sfm_is_one_line_and_leaves_no_entry(sig, tmp_path, cup_near):
    """``tsplus inspect`` of 12 photos (SfM: about 8 s on 2 cores), stopped during the SfM. Before
    the handlers around pycolmap's calls, SIGTERM printed COLMAP's crash report (a C++ stack of 20
    lines) and left a 22 MB unfinished entry; SIGHUP left the entry silently."""
    import signal
    import subprocess
    import sys
    from tsplus_wgpu.data.images import resize_area, write_image
    if signal.getsignal(getattr(signal, sig)) == signal.SIG_IGN:     # e.g. under nohup: the command inherits it
        pytest.skip(f"{sig} is ignored in this process, so the command keeps ignoring it")
    ref, order = cup_near
    photos, cache = tmp_path / "photos", tmp_path / "cache"
    photos.mkdir()
    for i in order[:12]:
        write_image(photos / ref.image_names[i], resize_area(ref.images[i], 400, 300))
    env = dict(os.environ, TSPLUS_CACHE=str(cache))
    p = subprocess.Popen([sys.executable, "-m", "tsplus_wgpu.cli", "inspect", str(photos)], env=env,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 60
    while not list(cache.glob("sfm_*/database.db")) and p.poll() is None and time.time() < deadline:
        time.sleep(0.02)             # the feature extraction has begun
    time.sleep(0.5)
    p.send_signal(getattr(signal, sig))
    _, err = p.communicate(timeout=120)
    if p.returncode == 0:            # pragma: no cover - a machine fast enough to finish first
        pytest.skip("the SfM finished before the signal arrived")
    assert p.returncode == 128 + getattr(signal, sig), err
    assert err.strip().splitlines()[-1] == f"tsplus: stopped by {sig}" and "***" not in err and "@" not in err
    assert not list(cache.iterdir())
